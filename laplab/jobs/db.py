"""The console's job store: users, login tokens, sessions (their half: :mod:`laplab.jobs.users`),
model owners and jobs in SQLite.

The database is ``$LAPLAB_HOME/laplab.db`` in WAL mode (readers never block the writer; the server
and ``laplab users add`` share it). Tokens and session ids are stored only hashed: login tokens with
argon2 (``TOKEN_ID.SECRET``: the id finds the row, argon2 checks the secret), session ids (random,
256 bits) with SHA-256. Job workers never open this file (see docs/console.md).
"""

from __future__ import annotations

import json
import os
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from laplab.jobs.users import ROLES, StoreError, User, UserTable  # noqa: F401 (ROLES, StoreError, User: imported from here)
from laplab.settings import current_settings

JOB_KINDS = ("train", "clone", "evaluate", "resume", "export", "duel")  # duel: a head-to-model race
JOB_STATUSES = ("queued", "running", "stopping", "done", "failed", "interrupted")
ACTIVE_STATUSES = ("queued", "running", "stopping")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS users (
    id INTEGER PRIMARY KEY, name TEXT UNIQUE NOT NULL, is_admin INTEGER NOT NULL DEFAULT 0,
    created REAL NOT NULL);
CREATE TABLE IF NOT EXISTS tokens (
    id TEXT PRIMARY KEY, user_id INTEGER NOT NULL REFERENCES users(id), hash TEXT NOT NULL,
    label TEXT NOT NULL, created REAL NOT NULL, expires REAL);
CREATE TABLE IF NOT EXISTS sessions (
    hash TEXT PRIMARY KEY, user_id INTEGER NOT NULL REFERENCES users(id), created REAL NOT NULL,
    expires REAL NOT NULL);
CREATE TABLE IF NOT EXISTS models (
    name TEXT PRIMARY KEY, owner INTEGER NOT NULL REFERENCES users(id), description TEXT NOT NULL DEFAULT '',
    created REAL NOT NULL);
CREATE TABLE IF NOT EXISTS jobs (
    id INTEGER PRIMARY KEY, kind TEXT NOT NULL, model TEXT NOT NULL, owner INTEGER NOT NULL,
    status TEXT NOT NULL, progress REAL NOT NULL DEFAULT 0, params TEXT NOT NULL, created REAL NOT NULL,
    started REAL, finished REAL, pid INTEGER, log_path TEXT, error TEXT, result TEXT);
CREATE INDEX IF NOT EXISTS jobs_model ON jobs(model);
CREATE INDEX IF NOT EXISTS jobs_status ON jobs(status);
"""


@dataclass(frozen=True)
class Job:
    id: int
    kind: str
    model: str
    owner: int
    status: str
    progress: float
    params: dict
    created: float
    started: float | None
    finished: float | None
    pid: int | None
    log_path: str | None
    error: str | None
    result: dict | None

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "kind": self.kind, "model": self.model, "status": self.status,
                "progress": self.progress, "created": self.created, "started": self.started,
                "finished": self.finished, "error": self.error, "result": self.result}


def laplab_home() -> Path:
    """laplab's folder (``$LAPLAB_HOME``, default ``~/.laplab``: laplab/settings.py)."""
    return current_settings().home


def database_path() -> Path:
    return current_settings().database


class JobStore(UserTable):
    """Thread-safe access to the console database (one connection, serialised by a lock)."""

    def __init__(self, path: str | os.PathLike | None = None):
        self.path = Path(path) if path is not None else database_path()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.RLock()
        self._db = sqlite3.connect(self.path, check_same_thread=False, timeout=30.0, isolation_level=None)
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.execute("PRAGMA foreign_keys=ON")
        self._db.executescript(_SCHEMA)
        self._migrate_users()
        os.chmod(self.path, 0o600)
        self._data_version = self._db.execute("PRAGMA data_version").fetchone()[0]
        self._verified: dict[str, tuple[int, float | None, str]] = {}  # sha256(token) -> (user id, expiry, token id)
        self._verifying: dict[str, threading.Lock] = {}  # sha256(token) -> the lock of its one argon2 check
        self._verifying_guard = threading.Lock()
        self._sessions: dict[str, tuple[int, float]] = {}  # sha256(session) -> (user id, expiry)
        self._users: dict[int, User] = {}  # enabled users, read on demand; dropped when disabled or removed

    def _migrate_users(self) -> None:
        """Add the columns later versions use to an older database: ``disabled``; ``role`` (existing
        admins stay admins, everyone else becomes a racer); ``password`` (argon2, None: token only)."""
        columns = {r["name"] for r in self._db.execute("PRAGMA table_info(users)")}
        if "disabled" not in columns:
            self._db.execute("ALTER TABLE users ADD COLUMN disabled INTEGER NOT NULL DEFAULT 0")
        if "role" not in columns:
            self._db.execute("ALTER TABLE users ADD COLUMN role TEXT NOT NULL DEFAULT 'racer'")
            self._db.execute("UPDATE users SET role='admin' WHERE is_admin=1")
        if "password" not in columns:
            self._db.execute("ALTER TABLE users ADD COLUMN password TEXT")

    def execute(self, sql: str, args: tuple = ()) -> sqlite3.Cursor:
        """One statement under the store's lock (for the modules that keep their own tables here:
        :mod:`laplab.jobs.accounts`, :mod:`laplab.jobs.quotas`, :mod:`laplab.races.store`)."""
        return self._execute(sql, args)

    def apply_schema(self, script: str) -> None:
        """Run ``script``'s ``;``-separated statements (a module's ``CREATE ... IF NOT EXISTS``) under the lock."""
        with self.lock:
            for statement in script.strip().split(";"):
                if statement.strip():
                    self._execute(statement, ())

    def select(self, sql: str, args: tuple = ()) -> list[sqlite3.Row]:
        return self._rows(sql, args)

    @property
    def lock(self) -> threading.RLock:
        return self._lock

    def credentials_changed(self) -> bool:
        """Drop what memory holds about tokens, sessions and users when another process (``laplab users
        revoke / disable / remove``) changed the database since the last call (cheap: one PRAGMA)."""
        with self._lock:
            version = self._db.execute("PRAGMA data_version").fetchone()[0]
            if version == self._data_version:
                return False
            self._data_version = version
        self.forget_credentials()
        return True

    def forget_credentials(self) -> None:
        """Tokens, sessions and users are checked against the database again from now on (argon2 once more
        per token): a revoked token, a disabled or removed user stop working at once."""
        self._verified.clear()
        self._sessions.clear()
        self._users.clear()

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def _execute(self, sql: str, args: tuple = ()) -> sqlite3.Cursor:
        with self._lock:
            return self._db.execute(sql, args)

    def _rows(self, sql: str, args: tuple = ()) -> list[sqlite3.Row]:
        with self._lock:
            return self._db.execute(sql, args).fetchall()

    def integrity_ok(self) -> bool:
        return self._rows("PRAGMA integrity_check")[0][0] == "ok"

    # -- users and tokens ------------------------------------------------------------------------

    def claim_model(self, name: str, owner: int, description: str = "") -> None:
        """Record ``owner`` of model ``name``; refuses a name already recorded."""
        try:
            self._execute("INSERT INTO models(name, owner, description, created) VALUES (?,?,?,?)",
                          (name, owner, description, time.time()))
        except sqlite3.IntegrityError:
            raise StoreError(f"a model named {name!r} already exists; models are immutable: pick another "
                             f"name or clone it") from None

    def model_records(self) -> dict[str, sqlite3.Row]:
        return {r["name"]: r for r in self._rows("SELECT * FROM models")}

    def forget_model(self, name: str) -> None:
        with self._lock:
            self._execute("DELETE FROM jobs WHERE model=?", (name,))
            self._execute("DELETE FROM models WHERE name=?", (name,))

    # -- jobs ------------------------------------------------------------------------------------

    def add_job(self, kind: str, model: str, owner: int, params: dict) -> Job:
        if kind not in JOB_KINDS:
            raise StoreError(f"unknown job kind {kind!r}")
        cur = self._execute("INSERT INTO jobs(kind, model, owner, status, params, created) VALUES (?,?,?,?,?,?)",
                            (kind, model, owner, "queued", json.dumps(params), time.time()))
        return self.job(int(cur.lastrowid))

    def job(self, job_id: int) -> Job | None:
        rows = self._rows("SELECT * FROM jobs WHERE id=?", (job_id,))
        return _job(rows[0]) if rows else None

    def jobs(self, status: tuple[str, ...] | None = None, model: str | None = None, kind: tuple[str, ...] | None = None) -> list[Job]:
        sql, args = "SELECT * FROM jobs WHERE 1=1", []
        if status:
            sql += f" AND status IN ({','.join('?' * len(status))})"
            args += list(status)
        if kind:
            sql += f" AND kind IN ({','.join('?' * len(kind))})"
            args += list(kind)
        if model is not None:
            sql += " AND model=?"
            args.append(model)
        return [_job(r) for r in self._rows(sql + " ORDER BY id", tuple(args))]

    def update_job(self, job_id: int, **values: Any) -> None:
        allowed = {"status", "progress", "started", "finished", "pid", "log_path", "error", "result"}
        if not values or set(values) - allowed:
            raise StoreError(f"cannot update job fields {sorted(set(values) - allowed)}")
        if "status" in values and values["status"] not in JOB_STATUSES:
            raise StoreError(f"unknown job status {values['status']!r}")
        if "result" in values and values["result"] is not None:
            values["result"] = json.dumps(values["result"])
        columns = ", ".join(f"{k}=?" for k in values)
        self._execute(f"UPDATE jobs SET {columns} WHERE id=?", (*values.values(), job_id))

    def interrupt_running(self) -> list[Job]:
        """At server start: jobs a dead server left running or stopping become ``interrupted``."""
        with self._lock:
            stale = self.jobs(status=("running", "stopping"))
            for job in stale:
                self.update_job(job.id, status="interrupted", finished=time.time(),
                                error="the server stopped while this job ran; resume it to continue")
        return stale


def _job(row: sqlite3.Row) -> Job:
    return Job(int(row["id"]), row["kind"], row["model"], int(row["owner"]), row["status"], float(row["progress"]),
               json.loads(row["params"]), row["created"], row["started"], row["finished"], row["pid"],
               row["log_path"], row["error"], json.loads(row["result"]) if row["result"] else None)
