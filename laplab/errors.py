"""Errors shared across laplab's layers (standard library only, importable from anywhere)."""


class UserError(Exception):
    """An error caused by the user's input; the CLI prints it without a traceback."""
