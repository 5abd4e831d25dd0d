"""Races, their members and submissions in the console database (tables ``races``,
``race_members``, ``race_submissions``); the rules live in :mod:`laplab.races.rules`.

A submission links a racer's model to the console's evaluate job that drives it under the race's
rules; its result is read from that job's evaluation summary when the board is built.
"""

from __future__ import annotations

import json
import secrets
import time
from dataclasses import dataclass

from laplab.jobs.db import JobStore, User
from laplab.races.rules import RaceError, RaceSettings

_SCHEMA = """
CREATE TABLE IF NOT EXISTS races (
    id INTEGER PRIMARY KEY, owner INTEGER NOT NULL, settings TEXT NOT NULL, code TEXT NOT NULL,
    created REAL NOT NULL, closed INTEGER NOT NULL DEFAULT 0);
CREATE TABLE IF NOT EXISTS race_members (
    race_id INTEGER NOT NULL, user_id INTEGER NOT NULL, joined REAL NOT NULL, PRIMARY KEY (race_id, user_id));
CREATE TABLE IF NOT EXISTS race_submissions (
    id INTEGER PRIMARY KEY, race_id INTEGER NOT NULL, user_id INTEGER NOT NULL, model TEXT NOT NULL,
    job_id INTEGER NOT NULL, created REAL NOT NULL);
CREATE INDEX IF NOT EXISTS race_submissions_race ON race_submissions(race_id);
"""


@dataclass(frozen=True)
class Race:
    id: int
    owner: int
    settings: RaceSettings
    code: str
    created: float
    closed: bool

    def to_dict(self, with_code: bool) -> dict:
        out = {"id": self.id, "owner": self.owner, "created": self.created, "closed": self.closed,
               **self.settings.to_dict()}
        if with_code:
            out["code"] = self.code
        return out


@dataclass(frozen=True)
class Submission:
    id: int
    race_id: int
    user_id: int
    model: str
    job_id: int
    created: float


def new_code() -> str:
    """A private race's join code: 10 characters a class can type (no 0/O, 1/l/I)."""
    alphabet = "23456789ABCDEFGHJKMNPQRSTUVWXYZ"
    return "".join(secrets.choice(alphabet) for _ in range(10))


class RaceStore:
    def __init__(self, store: JobStore):
        self.store = store
        store.apply_schema(_SCHEMA)

    def create(self, owner: User, settings: RaceSettings) -> Race:
        cur = self.store.execute("INSERT INTO races(owner, settings, code, created) VALUES (?,?,?,?)",
                                 (owner.id, json.dumps(settings.to_dict()), new_code(), time.time()))
        return self.race(int(cur.lastrowid))

    def race(self, race_id: int) -> Race | None:
        rows = self.store.select("SELECT * FROM races WHERE id=?", (race_id,))
        return _race(rows[0]) if rows else None

    def races(self) -> list[Race]:
        return [_race(r) for r in self.store.select("SELECT * FROM races ORDER BY id DESC")]

    def by_code(self, code: str) -> Race | None:
        rows = self.store.select("SELECT * FROM races WHERE code=?", ((code or "").strip().upper(),))
        return _race(rows[0]) if rows else None

    def update(self, race_id: int, settings: RaceSettings) -> Race:
        self.store.execute("UPDATE races SET settings=? WHERE id=?", (json.dumps(settings.to_dict()), race_id))
        return self.race(race_id)

    def set_closed(self, race_id: int, closed: bool) -> Race:
        self.store.execute("UPDATE races SET closed=? WHERE id=?", (int(closed), race_id))
        return self.race(race_id)

    def delete(self, race_id: int) -> None:
        with self.store.lock:
            self.store.execute("DELETE FROM race_submissions WHERE race_id=?", (race_id,))
            self.store.execute("DELETE FROM race_members WHERE race_id=?", (race_id,))
            self.store.execute("DELETE FROM races WHERE id=?", (race_id,))

    def join(self, race_id: int, user_id: int) -> None:
        self.store.execute("INSERT OR IGNORE INTO race_members(race_id, user_id, joined) VALUES (?,?,?)",
                           (race_id, user_id, time.time()))

    def is_member(self, race_id: int, user_id: int) -> bool:
        return bool(self.store.select("SELECT 1 FROM race_members WHERE race_id=? AND user_id=?", (race_id, user_id)))

    def memberships(self, user_id: int) -> set[int]:
        return {r["race_id"] for r in self.store.select("SELECT race_id FROM race_members WHERE user_id=?", (user_id,))}

    def add_submission(self, race: Race, user: User, model: str, submit_job, not_counted: int = 0) -> Submission:
        """Record a submission and queue its evaluation in one step under the store's lock: the count
        against ``max_submissions`` is checked there, so two quick clicks cannot both slip through.
        ``submit_job()`` queues the evaluate job and returns it; ``not_counted``: the racer's earlier
        submissions that no longer count (they drove a course the race has left since:
        :func:`laplab.races.results.stale_submissions`)."""
        with self.store.lock:
            count = self.store.select("SELECT COUNT(*) FROM race_submissions WHERE race_id=? AND user_id=?",
                                      (race.id, user.id))[0][0] - max(0, int(not_counted))
            if count >= race.settings.max_submissions:
                raise RaceError(f"max_submissions: you have made {count} submissions to this race, its limit "
                                f"({race.settings.max_submissions})", field="max_submissions")
            job = submit_job()
            cur = self.store.execute("INSERT INTO race_submissions(race_id, user_id, model, job_id, created) "
                                     "VALUES (?,?,?,?,?)", (race.id, user.id, model, job.id, time.time()))
        return self.submission(int(cur.lastrowid))

    def submission(self, submission_id: int) -> Submission | None:
        rows = self.store.select("SELECT * FROM race_submissions WHERE id=?", (submission_id,))
        return Submission(*tuple(rows[0])) if rows else None

    def submissions(self, race_id: int, user_id: int | None = None) -> list[Submission]:
        sql, args = "SELECT * FROM race_submissions WHERE race_id=?", (race_id,)
        if user_id is not None:
            sql, args = sql + " AND user_id=?", (race_id, user_id)
        return [Submission(*tuple(r)) for r in self.store.select(sql + " ORDER BY id", args)]


def _race(row) -> Race:
    return Race(int(row["id"]), int(row["owner"]), RaceSettings.from_dict(json.loads(row["settings"])), row["code"],
                float(row["created"]), bool(row["closed"]))
