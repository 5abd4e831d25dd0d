"""Limits a class needs: request bodies refused before they are read past their limit, login
attempts throttled per token id, and the longest training a request may ask for.

- :class:`BodyLimit` (ASGI middleware): a request whose ``Content-Length`` is over its route's limit
  gets 413 before one byte of its body is read; a body sent without a length (chunked) is counted as
  it arrives and refused at the limit. JSON routes take ``json_bytes`` (1 MiB by default), the import
  route ``upload_bytes`` (1 GiB).
- :class:`LoginThrottle`: ``attempts`` failed logins with one token id (the part of a token before its
  dot) within ``window_s`` block that id for the rest of the window (429 with ``Retry-After``), also
  after a restart of the server (the failures are rows of the console's database); a
  token already verified is not affected (it is answered from memory). This also bounds the argon2
  work a stranger can make the server do per token id.
- :func:`check_max_time`: a training's ``max_time_s`` over the server's cap (``JobLimits.max_time_s``,
  ``laplab serve --max-job-time``, default 24 h as DeepRacer on AWS's 1440 min) is a 400.
"""

from __future__ import annotations

import json
import threading
import time

MIB = 1 << 20
UPLOAD_PATHS = ("/api/models/import",)


def _size(value: int) -> str:
    return f"{value / (1 << 30):g} GiB" if value >= 1 << 30 else f"{value / MIB:g} MiB"


class BodyLimit:
    """ASGI middleware: 413 for a request body over its limit, never read past it."""

    def __init__(self, app, json_bytes: int = MIB, upload_bytes: int = 1 << 30):
        self.app, self.json_bytes, self.upload_bytes = app, int(json_bytes), int(upload_bytes)

    def limit_for(self, path: str) -> int:
        return self.upload_bytes if path in UPLOAD_PATHS else self.json_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        limit = self.limit_for(scope.get("path", ""))
        length = dict(scope.get("headers") or ()).get(b"content-length")
        if length is not None:
            try:
                declared = int(length)
            except ValueError:
                return await _answer(send, 400, "the request's Content-Length is not a number")
            if declared > limit:
                return await _answer(send, 413, _too_large(limit))
        received, answered = 0, False

        async def counted_receive():
            nonlocal received, answered
            if answered:
                return {"type": "http.disconnect"}
            message = await receive()
            if message.get("type") == "http.request":
                received += len(message.get("body", b""))
                if received > limit:  # answer now; the app sees the client go away and its answer is dropped
                    answered = True
                    await _answer(send, 413, _too_large(limit))
                    return {"type": "http.disconnect"}
            return message

        async def watched_send(message):
            if not answered:
                await send(message)

        await self.app(scope, counted_receive, watched_send)


def _too_large(limit: int) -> str:
    return (f"the request body is larger than this console accepts here ({_size(limit)}); it was not read. "
            "Send less (a reward function is at most 100,000 characters; an archive to import at most the "
            "upload limit of `laplab serve --max-upload`).")


async def _answer(send, status: int, message: str) -> None:
    body = json.dumps({"detail": {"message": message}}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


class LoginThrottled(Exception):
    """Too many failed logins with one token id: ``retry_after_s`` until the next attempt counts."""

    def __init__(self, retry_after_s: float):
        self.retry_after_s = max(1, int(retry_after_s + 0.999))
        super().__init__(f"too many failed logins with this token: try again in {self.retry_after_s} s")


class LoginThrottle:
    """Failed login attempts per key (a token id; a user name for password logins), kept in a table of
    the console's SQLite database, so a restart of the server does not forget them (``database`` None:
    in memory, for tests). Times are wall-clock seconds, which survive the restart."""

    MAX_ROWS = 100_000  # a flood of made-up keys: the oldest half is forgotten

    def __init__(self, database=None, attempts: int = 5, window_s: float = 60.0):
        import sqlite3
        self.attempts, self.window_s = int(attempts), float(window_s)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(str(database) if database is not None else ":memory:", check_same_thread=False,
                                   timeout=30.0, isolation_level=None)
        self._db.execute("CREATE TABLE IF NOT EXISTS login_failures (key TEXT NOT NULL, at REAL NOT NULL)")
        self._db.execute("CREATE INDEX IF NOT EXISTS login_failures_key ON login_failures (key, at)")

    def check(self, key: str) -> None:
        """Raise :class:`LoginThrottled` while ``key`` is blocked."""
        now = time.time()
        with self._lock:
            count, first = self._db.execute(
                "SELECT COUNT(*), MIN(at) FROM (SELECT at FROM login_failures WHERE key = ? AND at > ? "
                "ORDER BY at DESC LIMIT ?)", (key, now - self.window_s, self.attempts)).fetchone()
        if count >= self.attempts:
            raise LoginThrottled(self.window_s - (now - first))

    def failed(self, key: str) -> None:
        now = time.time()
        with self._lock:
            self._db.execute("INSERT INTO login_failures (key, at) VALUES (?, ?)", (key, now))
            self._db.execute("DELETE FROM login_failures WHERE key = ? AND at <= ?", (key, now - self.window_s))
            (rows,) = self._db.execute("SELECT COUNT(*) FROM login_failures").fetchone()
            if rows > self.MAX_ROWS:
                self._db.execute("DELETE FROM login_failures WHERE at <= ?", (now - self.window_s,))
                self._db.execute("DELETE FROM login_failures WHERE rowid IN (SELECT rowid FROM login_failures "
                                 "ORDER BY at LIMIT ?)", (rows // 2,))

    def close(self) -> None:
        self._db.close()


def check_max_time(max_time_s: float | None, cap_s: float) -> str | None:
    """The 400 message for a training longer than the server allows (None when it fits)."""
    if max_time_s is None or max_time_s <= cap_s:
        return None
    return (f"max time {max_time_s:g} s is longer than this console allows ({cap_s:g} s = {cap_s / 60:g} min; "
            "the operator sets it with `laplab serve --max-job-time`): ask for less, and resume the model later "
            "to train it further")
