"""A command's outcome as JSON for the program that ran it (the console): when ``LAPLAB_RESULT_FILE``
names a file, ``laplab``'s dispatcher writes ``{"ok": true, "command": ..., **values}`` there after the
command, or ``{"ok": false, "command": ..., "error": message, "field": field}`` after a user error. A
command adds its values with :func:`record`; nobody parses the printed sentences meant for people."""

from __future__ import annotations

import os
from typing import Any

RESULT_FILE_ENV = "LAPLAB_RESULT_FILE"
_values: dict[str, Any] = {}


def record(**values: Any) -> None:
    """Add JSON-able ``values`` to this command's outcome (the file's keys)."""
    _values.update(values)


def write(command: str, error: BaseException | None = None) -> None:
    """Write the outcome to ``$LAPLAB_RESULT_FILE`` (nothing when it is not set)."""
    path = os.environ.get(RESULT_FILE_ENV)
    if not path:
        return
    from laplab.store.atomic import atomic_write_json
    if error is None:
        document = {"ok": True, "command": command, **_values}
    else:
        document = {"ok": False, "command": command, "error": str(error), "field": getattr(error, "field", None)}
    atomic_write_json(path, document)
