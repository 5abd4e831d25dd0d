"""Errors shared across laplab's layers (standard library only, importable from anywhere)."""

from __future__ import annotations


class UserError(Exception):
    """An error caused by the user's input; the CLI prints it without a traceback.

    ``field``: what the error is about, when it is one thing the user gave: an option
    (``"--timeout"``), a file (``"model_metadata.json"``), a key in it (``"stack_size"``), an
    environment variable (``"AWS_ENDPOINT_URL"``); None otherwise. The message names it too.
    Every layer's input errors derive from it (TrackError, MetadataError, ActionSpaceError,
    HyperparameterError, ConfigError, JobError, ModelNameError, CorruptFileError,
    RewardFunctionError, ModelFilesError), each with its usual ``default_field``.
    """

    default_field: str | None = None  # a subclass's usual field (TrackError: "track")

    def __init__(self, message: str = "", *, field: str | None = None):
        super().__init__(message)
        self.field = field if field is not None else self.default_field

    def __reduce__(self):
        return (_rebuild, (type(self), str(self), self.field))


def _rebuild(cls, message, field):
    error = cls.__new__(cls)
    UserError.__init__(error, message, field=field)
    return error
