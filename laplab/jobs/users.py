"""The console's accounts in its database: users and their roles, login tokens (argon2) and sessions
(SHA-256). :class:`UserTable` is the part of :class:`laplab.jobs.db.JobStore` that keeps them; it uses
the store's connection and lock (``_execute``, ``_rows``, ``_lock``)."""

from __future__ import annotations

import hashlib
import secrets
import sqlite3
import threading
import time
from dataclasses import dataclass

SESSION_LIFETIME_S = 7 * 24 * 3600.0


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


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _hasher():
    from argon2 import PasswordHasher
    return PasswordHasher()


class UserTable:
    """Users, tokens and sessions (mixed into :class:`laplab.jobs.db.JobStore`)."""

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
