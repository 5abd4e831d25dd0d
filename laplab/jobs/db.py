"""The console's job store: users, login tokens, sessions, model owners and jobs in SQLite.

The database is ``$LAPLAB_HOME/laplab.db`` in WAL mode (readers never block the writer; the server
and ``laplab users add`` share it). Tokens and session ids are stored only hashed: login tokens with
argon2 (``TOKEN_ID.SECRET``: the id finds the row, argon2 checks the secret), session ids (random,
256 bits) with SHA-256. Job workers never open this file (see docs/console.md).
"""

from __future__ import annotations

import hashlib
import json
import os
import secrets
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from laplab.settings import current_settings

JOB_KINDS = ("train", "clone", "evaluate", "resume", "export")
JOB_STATUSES = ("queued", "running", "stopping", "done", "failed", "interrupted")
ACTIVE_STATUSES = ("queued", "running", "stopping")
SESSION_LIFETIME_S = 7 * 24 * 3600.0

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


class StoreError(ValueError):
    """A request the store refuses (unknown user, duplicate name...), with a complete message."""


ROLES = ("admin", "facilitator", "racer")  # DeepRacer on AWS's three (docs/races.md)


@dataclass(frozen=True)
class User:
    """A console account; ``role`` is one of :data:`ROLES` (``is_admin`` is ``role == "admin"``)."""
    id: int
    name: str
    is_admin: bool
    role: str = "racer"

    @property
    def runs_races(self) -> bool:
        """Admins and race facilitators create and run races."""
        return self.role in ("admin", "facilitator")


def _user(row: sqlite3.Row) -> User:
    role = row["role"] if row["role"] in ROLES else ("admin" if row["is_admin"] else "racer")
    return User(int(row["id"]), row["name"], bool(row["is_admin"]), role)


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


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _hasher():
    from argon2 import PasswordHasher
    return PasswordHasher()


class JobStore:
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

    def add_user(self, name: str, is_admin: bool = False, token: str | None = None,
                 token_label: str = "login", role: str | None = None) -> tuple[User, str]:
        """Create user ``name`` with a fresh login token; returns the user and the token (shown once).
        ``role``: one of :data:`ROLES` (default: admin for ``is_admin``, else racer)."""
        role = role or ("admin" if is_admin else "racer")
        if role not in ROLES:
            raise StoreError(f"invalid role {role!r}: one of {', '.join(ROLES)}")
        is_admin = role == "admin"
        if not name or not all(c.isalnum() or c in "-_." for c in name) or len(name) > 64:
            raise StoreError(f"invalid user name {name!r}: 1 to 64 letters, digits, '-', '_' or '.'")
        with self._lock:
            if self._rows("SELECT 1 FROM users WHERE name=?", (name,)):
                raise StoreError(f"a user named {name!r} already exists")
            cur = self._execute("INSERT INTO users(name, is_admin, created, role) VALUES (?,?,?,?)",
                                (name, int(is_admin), time.time(), role))
            user = User(int(cur.lastrowid), name, is_admin, role)
        return user, self.add_token(user.id, token_label, token=token)

    def add_token(self, user_id: int, label: str, token: str | None = None, lifetime_s: float | None = None) -> str:
        """A new token ``ID.SECRET`` for ``user_id``; ``token`` (e.g. LAPLAB_ADMIN_TOKEN) is used as is."""
        token_id = secrets.token_hex(6)
        if token is None:
            token = f"{token_id}.{secrets.token_urlsafe(24)}"
        expires = None if lifetime_s is None else time.time() + lifetime_s
        self._execute("INSERT INTO tokens(id, user_id, hash, label, created, expires) VALUES (?,?,?,?,?,?)",
                      (token_id, user_id, _hasher().hash(token), label, time.time(), expires))
        return token

    def cached_user(self, token: str | None = None, session: str | None = None) -> User | None:
        """The user of a token or session this store has already checked, from memory only (no
        database read, no argon2): None when it has not (ask :meth:`user_for_token` /
        :meth:`user_for_session`, which may block)."""
        if token is not None:
            hit = self._verified.get(_sha256(token)) if 0 < len(token) <= 512 else None
        else:
            hit = self._sessions.get(_sha256(session)) if session and len(session) <= 256 else None
        if hit is None or (hit[1] is not None and hit[1] <= time.time()):
            return None
        return self._users.get(hit[0])

    def user_for_token(self, token: str) -> User | None:
        """The user a token logs in, or None. Verified tokens are remembered in memory (by SHA-256)
        so argon2's deliberate slowness is paid once per token and server run."""
        if not token or len(token) > 512:
            return None
        key = _sha256(token)
        hit = self._verified.get(key)
        if hit is not None and (hit[1] is None or hit[1] > time.time()):
            return self.user_by_id(hit[0])
        with self._verifying_guard:
            lock = self._verifying.setdefault(key, threading.Lock())
        with lock:  # 50 scripts starting with one new token pay for one argon2 check, not 50
            hit = self._verified.get(key)
            if hit is not None and (hit[1] is None or hit[1] > time.time()):
                return self.user_by_id(hit[0])
            user = self._verify_token(token, key)
        with self._verifying_guard:
            self._verifying.pop(key, None)
        return user

    def _verify_token(self, token: str, key: str) -> User | None:
        from argon2.exceptions import InvalidHashError, VerificationError
        head = token.split(".", 1)[0]
        rows = self._rows("SELECT * FROM tokens WHERE id=?", (head,)) if "." in token else []
        rows = rows or self._rows("SELECT * FROM tokens WHERE label='admin-env'")
        hasher = _hasher()
        for row in rows:
            if row["expires"] is not None and row["expires"] < time.time():
                continue
            try:
                hasher.verify(row["hash"], token)
            except (VerificationError, InvalidHashError):
                continue
            user = self.user_by_id(int(row["user_id"]))
            if user is not None:  # None: disabled
                self._verified[key] = (int(row["user_id"]), row["expires"], row["id"])
            return user
        return None

    def user_by_id(self, user_id: int, enabled: bool = True) -> User | None:
        """An enabled user (None when there is none or it is disabled; ``enabled=False``: any user)."""
        user = self._users.get(user_id)
        if user is None and not enabled:
            rows = self._rows("SELECT * FROM users WHERE id=?", (user_id,))
            return _user(rows[0]) if rows else None
        if user is None:
            rows = self._rows("SELECT * FROM users WHERE id=? AND disabled=0", (user_id,))
            if rows:
                user = self._users[user_id] = _user(rows[0])
        return user

    def user_by_name(self, name: str) -> User | None:
        rows = self._rows("SELECT * FROM users WHERE name=?", (name,))
        return _user(rows[0]) if rows else None

    def users(self) -> list[User]:
        return [_user(r) for r in self._rows("SELECT * FROM users ORDER BY id")]

    def user_rows(self) -> list[dict]:
        """Every user with ``disabled`` and their tokens (id, label, created, expires): no secrets."""
        tokens: dict[int, list[dict]] = {}
        for row in self._rows("SELECT id, user_id, label, created, expires FROM tokens ORDER BY created"):
            tokens.setdefault(row["user_id"], []).append({"id": row["id"], "label": row["label"],
                                                          "created": row["created"], "expires": row["expires"]})
        return [{"name": r["name"], "admin": bool(r["is_admin"]), "role": _user(r).role, "disabled": bool(r["disabled"]),
                 "created": r["created"], "tokens": tokens.get(r["id"], [])}
                for r in self._rows("SELECT * FROM users ORDER BY id")]

    def _existing(self, name: str) -> sqlite3.Row:
        rows = self._rows("SELECT * FROM users WHERE name=?", (name,))
        if not rows:
            raise StoreError(f"no user named {name!r} (laplab users list)")
        return rows[0]

    def set_disabled(self, name: str, disabled: bool = True) -> None:
        """Disable (or enable again) ``name``: a disabled user's tokens and sessions stop working; their
        models stay (and stay on the leaderboard)."""
        row = self._existing(name)
        if disabled and row["is_admin"] and len(self._rows("SELECT 1 FROM users WHERE is_admin=1 AND disabled=0")) <= 1:
            raise StoreError(f"{name!r} is the only admin: it cannot be disabled")
        self._execute("UPDATE users SET disabled=? WHERE id=?", (int(disabled), row["id"]))
        self.forget_credentials()

    def revoke_tokens(self, name: str, token_id: str | None = None) -> int:
        """Revoke ``name``'s token ``token_id`` (all of them when None) and end their sessions; returns
        how many tokens were revoked."""
        row = self._existing(name)
        with self._lock:
            if token_id is None:
                count = self._execute("DELETE FROM tokens WHERE user_id=?", (row["id"],)).rowcount
                self._execute("DELETE FROM sessions WHERE user_id=?", (row["id"],))
            else:
                count = self._execute("DELETE FROM tokens WHERE user_id=? AND id=?", (row["id"], token_id)).rowcount
                if not count:
                    raise StoreError(f"{name!r} has no token {token_id!r} (laplab users list --tokens)")
        self.forget_credentials()
        return count

    def remove_user(self, name: str) -> int:
        """Remove ``name``: their tokens and sessions end, their models pass to the (first other) admin;
        nothing is deleted (their jobs keep their owner id: the console stops those still active).
        Returns how many models passed."""
        row = self._existing(name)
        heirs = self._rows("SELECT id FROM users WHERE is_admin=1 AND id!=? ORDER BY disabled, id LIMIT 1", (row["id"],))
        if not heirs:
            raise StoreError(f"{name!r} is the only admin: it cannot be removed")
        with self._lock:
            self._execute("DELETE FROM tokens WHERE user_id=?", (row["id"],))
            self._execute("DELETE FROM sessions WHERE user_id=?", (row["id"],))
            moved = self._execute("UPDATE models SET owner=? WHERE owner=?", (heirs[0]["id"], row["id"])).rowcount
            self._execute("DELETE FROM users WHERE id=?", (row["id"],))
        self.forget_credentials()
        return moved

    def admin(self) -> User | None:
        rows = self._rows("SELECT * FROM users WHERE is_admin=1 AND disabled=0 ORDER BY id LIMIT 1")
        return _user(rows[0]) if rows else None

    # -- sessions --------------------------------------------------------------------------------

    def new_session(self, user_id: int) -> str:
        session = secrets.token_urlsafe(32)
        now = time.time()
        self._execute("INSERT INTO sessions(hash, user_id, created, expires) VALUES (?,?,?,?)",
                      (_sha256(session), user_id, now, now + SESSION_LIFETIME_S))
        return session

    def user_for_session(self, session: str) -> User | None:
        if not session or len(session) > 256:
            return None
        key = _sha256(session)
        rows = self._rows("SELECT user_id, expires FROM sessions WHERE hash=?", (key,))
        if not rows or rows[0]["expires"] < time.time() or self.user_by_id(int(rows[0]["user_id"])) is None:
            return None
        self._sessions[key] = (int(rows[0]["user_id"]), float(rows[0]["expires"]))
        return self.user_by_id(int(rows[0]["user_id"]))

    def end_session(self, session: str) -> None:
        key = _sha256(session)
        self._sessions.pop(key, None)
        self._execute("DELETE FROM sessions WHERE hash=?", (key,))

    # -- model owners ------------------------------------------------------------------------------

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
