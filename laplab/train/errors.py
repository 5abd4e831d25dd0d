"""Errors of training jobs (importable without torch, so the CLI can name them cheaply)."""


class JobError(ValueError):
    """A job that cannot start: a name clash, a missing model, a clone that does not match."""
