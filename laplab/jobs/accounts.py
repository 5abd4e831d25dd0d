"""Accounts beyond tokens: roles, one-time invitation links, passwords and racer profiles.

Tables in the console database (:class:`laplab.jobs.db.JobStore`): ``invites`` (the code is stored
only as SHA-256: it is 192 random bits, so no slow hash is needed) and ``profiles`` (alias, country,
avatar colour). Passwords are argon2 hashes in ``users.password``; tokens keep working for scripts.
No e-mail is ever sent: an invitation is a link the admin or facilitator hands out.
"""

from __future__ import annotations

import hashlib
import re
import secrets
import time
from dataclasses import dataclass

from laplab.errors import UserError
from laplab.jobs.db import ROLES, JobStore, StoreError, User

INVITE_LIFETIME_S = 7 * 24 * 3600.0
MIN_PASSWORD_LENGTH = 8
AVATAR_COLOURS = ("#ff9900", "#1e88e5", "#43a047", "#e53935", "#8e24aa", "#00897b", "#f4511e", "#3949ab",
                  "#c0ca33", "#6d4c41")
_COLOUR = re.compile(r"^#[0-9a-fA-F]{6}$")
_COUNTRY = re.compile(r"^[A-Z]{2}$")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS invites (
    id TEXT PRIMARY KEY, hash TEXT UNIQUE NOT NULL, role TEXT NOT NULL, created_by INTEGER NOT NULL,
    created REAL NOT NULL, expires REAL NOT NULL, used_by INTEGER, used REAL);
CREATE TABLE IF NOT EXISTS profiles (
    user_id INTEGER PRIMARY KEY, alias TEXT NOT NULL DEFAULT '', country TEXT NOT NULL DEFAULT '',
    colour TEXT NOT NULL DEFAULT '');
"""


class AccountError(UserError):
    """An invitation, password or profile the console refuses, with the rule it breaks."""


class NotAllowed(AccountError):
    """The asker's role may not do this (a 403, not a bad value)."""


@dataclass(frozen=True)
class Profile:
    """What leaderboards show of a racer: ``alias`` (display name), ``country`` (ISO 3166 alpha-2 or
    empty), the avatar's ``initials`` and ``colour`` (#rrggbb)."""
    name: str
    alias: str
    country: str
    colour: str

    @property
    def initials(self) -> str:
        words = [w for w in re.split(r"[\s_.-]+", self.alias or self.name) if w]
        return ("".join(w[0] for w in words[:2]) or "?").upper()

    def to_dict(self) -> dict:
        return {"name": self.name, "alias": self.alias or self.name, "country": self.country,
                "colour": self.colour, "initials": self.initials}


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


class Accounts:
    """Invitations, passwords, profiles and roles over a :class:`JobStore`."""

    def __init__(self, store: JobStore):
        self.store = store
        store.apply_schema(_SCHEMA)

    # -- invitations -------------------------------------------------------------------------------

    def create_invite(self, creator: User, role: str, lifetime_s: float = INVITE_LIFETIME_S) -> dict:
        """A one-time invitation to sign up as ``role``; returns its row with ``code`` (shown once).
        Admins invite any role; race facilitators invite racers only."""
        if role not in ROLES:
            raise AccountError(f"role: {role!r} is not a role; pick one of {', '.join(ROLES)}", field="role")
        if creator.role == "racer" or (creator.role == "facilitator" and role != "racer"):
            raise NotAllowed(f"role: a {creator.role} cannot invite a {role} (admins invite any role, race "
                               "facilitators invite racers)", field="role")
        if not (60.0 <= float(lifetime_s) <= 90 * 24 * 3600.0):
            raise AccountError("expires_in_h: an invitation lasts from 1 minute to 90 days", field="expires_in_h")
        code, invite_id, now = secrets.token_urlsafe(24), secrets.token_hex(6), time.time()
        self.store.execute("INSERT INTO invites(id, hash, role, created_by, created, expires) VALUES (?,?,?,?,?,?)",
                           (invite_id, _sha256(code), role, creator.id, now, now + float(lifetime_s)))
        return {**self._row(self.store.select("SELECT * FROM invites WHERE id=?", (invite_id,))[0]), "code": code}

    def invites(self, viewer: User) -> list[dict]:
        """The invitations ``viewer`` made (all of them for an admin), newest first."""
        sql, args = "SELECT * FROM invites", ()
        if not viewer.is_admin:
            sql, args = sql + " WHERE created_by=?", (viewer.id,)
        return [self._row(r) for r in self.store.select(sql + " ORDER BY created DESC", args)]

    def revoke_invite(self, viewer: User, invite_id: str) -> None:
        rows = self.store.select("SELECT * FROM invites WHERE id=?", (invite_id,))
        if not rows or (not viewer.is_admin and rows[0]["created_by"] != viewer.id):
            raise AccountError(f"no invitation {invite_id!r} among yours", field="id")
        self.store.execute("DELETE FROM invites WHERE id=? AND used_by IS NULL", (invite_id,))

    def invite_for(self, code: str) -> dict:
        """The unused, unexpired invitation of ``code``; an AccountError saying why not."""
        rows = self.store.select("SELECT * FROM invites WHERE hash=?", (_sha256(code or ""),)) if code else []
        if not rows:
            raise AccountError("invite: this invitation link is not valid (mistyped or revoked); ask for a new one",
                               field="invite")
        row = rows[0]
        if row["used_by"] is not None:
            raise AccountError("invite: this invitation link has already been used; an invitation signs up one "
                               "person: ask for a new one", field="invite")
        if row["expires"] < time.time():
            raise AccountError("invite: this invitation link has expired; ask for a new one", field="invite")
        return self._row(row)

    def sign_up(self, code: str, name: str, password: str, alias: str = "", country: str = "") -> User:
        """Create the account an invitation offers: nothing is written unless every check passes, and
        the invitation is used up in the same transaction as the account is made."""
        check_password(password)
        profile = _checked_profile(name, alias, country, "")
        with self.store.lock:
            invite = self.invite_for(code)
            try:
                user, _ = self.store.add_user(name, role=invite["role"], token_label="signup")
            except StoreError as exc:
                raise AccountError(f"name: {exc}", field="name") from None
            self.store.execute("UPDATE invites SET used_by=?, used=? WHERE id=?", (user.id, time.time(), invite["id"]))
            self.store.execute("UPDATE users SET password=? WHERE id=?", (_hasher().hash(password), user.id))
            self._write_profile(user.id, profile)
        from laplab.jobs.quotas import Quotas
        Quotas(self.store).apply_new_user_quota(user.id)
        return user

    @staticmethod
    def _row(row) -> dict:
        status = "used" if row["used_by"] is not None else ("expired" if row["expires"] < time.time() else "open")
        return {"id": row["id"], "role": row["role"], "created": row["created"], "expires": row["expires"],
                "status": status}

    # -- passwords ---------------------------------------------------------------------------------

    def set_password(self, user: User, old: str | None, new: str) -> None:
        """Change ``user``'s password; ``old`` must match when one is set."""
        check_password(new)
        rows = self.store.select("SELECT password FROM users WHERE id=?", (user.id,))
        current = rows[0]["password"] if rows else None
        if current and not _verify(current, old or ""):
            raise AccountError("old_password: the current password is wrong", field="old_password")
        self.store.execute("UPDATE users SET password=? WHERE id=?", (_hasher().hash(new), user.id))

    def user_for_password(self, name: str, password: str) -> User | None:
        """The enabled user ``name`` when ``password`` is theirs (argon2), else None."""
        rows = self.store.select("SELECT id, password FROM users WHERE name=? AND disabled=0", (name,))
        if not rows or not rows[0]["password"] or not _verify(rows[0]["password"], password):
            return None
        return self.store.user_by_id(int(rows[0]["id"]))

    # -- roles and profiles ------------------------------------------------------------------------

    def set_role(self, name: str, role: str) -> User:
        if role not in ROLES:
            raise AccountError(f"role: {role!r} is not a role; pick one of {', '.join(ROLES)}", field="role")
        target = self.store.user_by_name(name)
        if target is None:
            raise StoreError(f"no user named {name!r}")
        if target.is_admin and role != "admin" and len(self.store.select(
                "SELECT 1 FROM users WHERE is_admin=1 AND disabled=0")) <= 1:
            raise AccountError(f"role: {name!r} is the only admin and stays one", field="role")
        self.store.execute("UPDATE users SET role=?, is_admin=? WHERE id=?", (role, int(role == "admin"), target.id))
        self.store.forget_credentials()
        return self.store.user_by_name(name)

    def profile(self, user_id: int) -> Profile:
        return self.profiles().get(user_id) or Profile("?", "", "", AVATAR_COLOURS[0])

    def profiles(self) -> dict[int, Profile]:
        """Every user's profile by id (an account without one shows its name and a colour of its own)."""
        saved = {r["user_id"]: r for r in self.store.select("SELECT * FROM profiles")}
        out = {}
        for row in self.store.select("SELECT id, name FROM users"):
            p = saved.get(row["id"])
            colour = (p["colour"] if p is not None and p["colour"] else
                      AVATAR_COLOURS[int(_sha256(row["name"])[:8], 16) % len(AVATAR_COLOURS)])
            out[row["id"]] = Profile(row["name"], p["alias"] if p is not None else "",
                                     p["country"] if p is not None else "", colour)
        return out

    def update_profile(self, user: User, alias: str | None, country: str | None, colour: str | None) -> Profile:
        now = self.profile(user.id)
        checked = _checked_profile(user.name, now.alias if alias is None else alias,
                                   now.country if country is None else country, now.colour if colour is None else colour)
        self._write_profile(user.id, checked)
        return self.profile(user.id)

    def _write_profile(self, user_id: int, values: tuple[str, str, str]) -> None:
        self.store.execute("INSERT INTO profiles(user_id, alias, country, colour) VALUES (?,?,?,?) ON CONFLICT(user_id)"
                           " DO UPDATE SET alias=excluded.alias, country=excluded.country, colour=excluded.colour",
                           (user_id, *values))


def check_password(password: str) -> None:
    if not isinstance(password, str) or len(password) < MIN_PASSWORD_LENGTH or len(password) > 256:
        raise AccountError(f"password: at least {MIN_PASSWORD_LENGTH} characters (at most 256)", field="password")


def _checked_profile(name: str, alias: str, country: str, colour: str) -> tuple[str, str, str]:
    alias = (alias or "").strip()
    if len(alias) > 40 or any(ord(c) < 32 for c in alias):
        raise AccountError("alias: at most 40 printable characters", field="alias")
    country = (country or "").strip().upper()
    if country and not _COUNTRY.match(country):
        raise AccountError("country: a two-letter country code (ISO 3166-1, e.g. DE, US, JP) or empty",
                           field="country")
    if colour and not _COLOUR.match(colour):
        raise AccountError("colour: a colour as #rrggbb", field="colour")
    return alias, country, colour


def _hasher():
    from argon2 import PasswordHasher
    return PasswordHasher()


def _verify(hashed: str, password: str) -> bool:
    from argon2.exceptions import InvalidHashError, VerificationError
    try:
        return _hasher().verify(hashed, password)
    except (VerificationError, InvalidHashError):
        return False
