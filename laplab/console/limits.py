"""Limits a class needs: request bodies refused before they are read past their limit, login
attempts throttled per token id, and the longest training a request may ask for.

- :class:`BodyLimit` (ASGI middleware): a request whose ``Content-Length`` is over its route's limit
  gets 413 before one byte of its body is read; a body sent without a length (chunked) is counted as
  it arrives and refused at the limit. JSON routes take ``json_bytes`` (1 MiB by default), the import
  route ``upload_bytes`` (1 GiB).
- :class:`LoginThrottle`: ``attempts`` failed logins with one token id (the part of a token before its
  dot) within ``window_s`` block that id for the rest of the window (429 with ``Retry-After``); a
  token already verified is not affected (it is answered from memory). This also bounds the argon2
  work a stranger can make the server do per token id.
- :func:`check_max_time`: a training's ``max_time_s`` over the server's cap (``JobLimits.max_time_s``,
  ``laplab serve --max-job-time``, default 24 h as DeepRacer on AWS's 1440 min) is a 400.
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque

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
    """Failed login attempts per token id (in memory: a server restart forgets them)."""

    def __init__(self, attempts: int = 5, window_s: float = 60.0):
        self.attempts, self.window_s = int(attempts), float(window_s)
        self._failures: dict[str, deque] = {}
        self._lock = threading.Lock()

    def check(self, token_id: str) -> None:
        """Raise :class:`LoginThrottled` while ``token_id`` is blocked."""
        now = time.monotonic()
        with self._lock:
            failures = self._failures.get(token_id)
            if not failures:
                return
            while failures and now - failures[0] > self.window_s:
                failures.popleft()
            if len(failures) >= self.attempts:
                raise LoginThrottled(self.window_s - (now - failures[0]))

    def failed(self, token_id: str) -> None:
        with self._lock:
            if len(self._failures) > 100_000:  # a flood of made-up ids: forget the oldest half
                for key in list(self._failures)[:50_000]:
                    del self._failures[key]
            self._failures.setdefault(token_id, deque(maxlen=self.attempts)).append(time.monotonic())


def check_max_time(max_time_s: float | None, cap_s: float) -> str | None:
    """The 400 message for a training longer than the server allows (None when it fits)."""
    if max_time_s is None or max_time_s <= cap_s:
        return None
    return (f"max time {max_time_s:g} s is longer than this console allows ({cap_s:g} s = {cap_s / 60:g} min; "
            "the operator sets it with `laplab serve --max-job-time`): ask for less, and resume the model later "
            "to train it further")
