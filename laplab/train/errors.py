"""Errors of training jobs (importable without torch, so the CLI can name them cheaply)."""

from laplab.errors import UserError


class JobError(UserError, ValueError):
    """A job that cannot start: a name clash, a missing model, a clone that does not match."""
