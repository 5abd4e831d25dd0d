"""One settings object: where laplab keeps its models, tracks, caches and the console's database.

Every reader (the CLI, the console, the Python API, the model layout, the track registry, the
race-line cache) asks :func:`current_settings`; nothing else reads ``LAPLAB_HOME``. One precedence:

    home        ``$LAPLAB_HOME`` when set and not empty, else ``~/.laplab``; ``~`` is expanded and a
                relative path is taken from the current folder (made absolute once, here)
    models_dir  ``$LAPLAB_MODELS`` when set and not empty, else ``home/models``
    tracks_dir  ``home/tracks``        imported and fetched tracks
    cache_dir   ``home/cache``         race lines; ``cache/store``: the ``--store`` commands' local copies
    database    ``home/laplab.db``     the console's users and jobs
    jobs_dir    ``home/jobs``          console_dir ``home/console``       sandbox_dir ``home/sandbox``

``home`` is checked when it is read: a file, or a folder laplab cannot write, is a one-paragraph
:class:`~laplab.errors.UserError` naming ``LAPLAB_HOME``. A command that keeps its models elsewhere
(``--store``: a private local copy of a bucket's models) does not touch ``os.environ``: it runs its
work inside :func:`use_settings` (a context variable: this thread and what it calls, a forked child
included), and a child process started with ``exec`` gets its variables from
:meth:`Settings.to_env`. Standard library only (plus laplab.errors): any layer may import it.
"""

from __future__ import annotations

import contextvars
import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from laplab.errors import UserError

HOME_ENV = "LAPLAB_HOME"
MODELS_ENV = "LAPLAB_MODELS"
DEFAULT_HOME = "~/.laplab"

__all__ = ["DEFAULT_HOME", "HOME_ENV", "MODELS_ENV", "Settings", "current_settings", "use_settings"]


def _absolute(text: str | os.PathLike) -> Path:
    """``text`` with ``~`` expanded, absolute against the current folder, ``..`` folded."""
    return Path(os.path.abspath(os.path.expanduser(os.fspath(text))))


@dataclass(frozen=True)
class Settings:
    """Where laplab's files live (absolute paths). ``home``: laplab's folder; ``models_dir``: the
    model folders (``home/models`` unless a command works on another copy). Build one with
    :meth:`from_env` or :meth:`at`; the other folders follow from ``home``."""

    home: Path
    models_dir: Path

    @classmethod
    def at(cls, home: str | os.PathLike, models_dir: str | os.PathLike | None = None) -> Settings:
        """Settings for laplab's folder ``home`` (models in ``models_dir``, default ``home/models``)."""
        home = _absolute(home)
        return cls(home, home / "models" if models_dir is None else _absolute(models_dir))

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> Settings:
        """The settings ``environ`` (default ``os.environ``) names, checked (see the module's table)."""
        environ = os.environ if environ is None else environ
        home_text = environ.get(HOME_ENV) or DEFAULT_HOME
        check_folder(_absolute(home_text), HOME_ENV, home_text, unset=not environ.get(HOME_ENV))
        models_text = environ.get(MODELS_ENV) or None
        if models_text:
            check_folder(_absolute(models_text), MODELS_ENV, models_text)
        return cls.at(home_text, models_text)

    @property
    def tracks_dir(self) -> Path:
        return self.home / "tracks"

    @property
    def cache_dir(self) -> Path:
        return self.home / "cache"

    @property
    def database(self) -> Path:
        return self.home / "laplab.db"

    @property
    def jobs_dir(self) -> Path:
        return self.home / "jobs"

    @property
    def console_dir(self) -> Path:
        return self.home / "console"

    @property
    def sandbox_dir(self) -> Path:
        return self.home / "sandbox"

    def with_models_dir(self, models_dir: str | os.PathLike) -> Settings:
        """These settings with the model folders in ``models_dir`` (a ``--store`` command's copy)."""
        return Settings(self.home, _absolute(models_dir))

    def to_env(self) -> dict[str, str]:
        """The variables that give a child process these settings (``LAPLAB_MODELS`` only when the
        models are not in ``home/models``)."""
        env = {HOME_ENV: str(self.home)}
        if self.models_dir != self.home / "models":
            env[MODELS_ENV] = str(self.models_dir)
        return env

    def child_environment(self, base: Mapping[str, str] | None = None) -> dict[str, str]:
        """``base`` (default ``os.environ``) with these settings' variables in place of its own."""
        env = {k: v for k, v in (os.environ if base is None else base).items() if k not in (HOME_ENV, MODELS_ENV)}
        env.update(self.to_env())
        return env


def check_folder(path: Path, variable: str, given: str, unset: bool = False) -> None:
    """A UserError naming ``variable`` when ``path`` cannot be laplab's folder: it, or a folder above
    it, is a file, or it (or, before it exists, the folder it would be made in) is not writable."""
    what = (f"laplab's folder {given} ({variable} is not set)" if unset
            else f"{variable}={given}" + (f" ({path})" if str(path) != given else ""))
    fix = (f"Set {variable} to a folder you can write to" + (" (or unset it for ~/.laplab)." if variable == HOME_ENV
                                                             else " (or unset it)."))
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        where = "is a file" if existing == path else f"lies below {existing}, which is a file"
        raise UserError(f"{what} {where}, not a folder: laplab keeps its models, tracks, caches and database "
                        f"there. {fix}", field=variable)
    if not os.access(existing, os.W_OK | os.X_OK):
        where = "is not writable" if existing == path else f"cannot be made: {existing} is not writable"
        raise UserError(f"{what} {where} by this user: laplab keeps its models, tracks, caches and database "
                        f"there. {fix}", field=variable)


_override: contextvars.ContextVar[Settings | None] = contextvars.ContextVar("laplab_settings", default=None)


def current_settings() -> Settings:
    """The settings in force: those of the innermost :func:`use_settings`, else :meth:`Settings.from_env`
    (read again on each call, so a changed environment is seen)."""
    return _override.get() or Settings.from_env()


@contextmanager
def use_settings(settings: Settings) -> Iterator[Settings]:
    """Run the block with ``settings`` in force (this thread and what it calls; ``os.environ`` untouched)."""
    token = _override.set(settings)
    try:
        yield settings
    finally:
        _override.reset(token)
