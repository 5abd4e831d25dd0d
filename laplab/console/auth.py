"""Who is asking: ``Authorization: Bearer TOKEN`` or the session cookie, and CSRF for cookie writes.

A browser logs in with a token (``/login?token=...`` as Jupyter prints it, or the login form) and
gets a session cookie (HttpOnly, SameSite=Strict). Writes made with the cookie must carry the
header ``X-CSRF-Token`` (pages read it from ``<meta name="csrf-token">``): an HMAC of the session
id under the server's secret key (``$LAPLAB_HOME/console/secret.key``, mode 0600). Bearer requests
need no CSRF token: a browser never adds that header by itself.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
from pathlib import Path

from fastapi import HTTPException, Request

from laplab.jobs.db import User

SESSION_COOKIE = "laplab_session"
CSRF_HEADER = "x-csrf-token"
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")


def load_secret(home: Path) -> bytes:
    """The server's secret key, created on first use (never given to jobs)."""
    path = home / "console" / "secret.key"
    path.parent.mkdir(parents=True, exist_ok=True)
    os.chmod(path.parent, 0o700)
    if not path.exists():
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as out:
            out.write(secrets.token_bytes(32))
    return path.read_bytes()


def csrf_token(secret: bytes, session: str) -> str:
    return hmac.new(secret, session.encode(), hashlib.sha256).hexdigest()


class NotLoggedIn(HTTPException):
    def __init__(self):
        super().__init__(401, "log in first: send `Authorization: Bearer TOKEN` or open /login",
                         headers={"WWW-Authenticate": "Bearer"})


def user_for_token(state, token: str) -> User | None:
    """The user ``token`` logs in (None when it does not); a 429 while its token id is throttled
    (:class:`laplab.console.limits.LoginThrottle`: failed attempts per token id)."""
    from laplab.console.limits import LoginThrottled
    user = state.store.cached_user(token=token)
    if user is not None:
        return user
    token_id = token.split(".", 1)[0][:64] if "." in token else ""
    throttle = state.login_throttle
    try:
        throttle.check(token_id)
    except LoginThrottled as exc:
        raise HTTPException(429, {"message": str(exc)}, headers={"Retry-After": str(exc.retry_after_s)}) from None
    user = state.store.user_for_token(token)
    if user is None:
        throttle.failed(token_id)
    return user


def identify(request: Request) -> tuple[User | None, str | None]:
    """(user, session id when authenticated by cookie)."""
    app = request.app.state
    header = request.headers.get("authorization", "")
    if header.lower().startswith("bearer "):
        return user_for_token(app, header[7:].strip()), None
    session = request.cookies.get(SESSION_COOKIE)
    if session:
        user = app.store.user_for_session(session)
        if user is not None:
            return user, session
    if app.open_access:  # --no-accounts on 127.0.0.1: everyone is the admin
        return app.store.admin(), None
    return None, None


def _identify_from_memory(request: Request) -> tuple[User | None, str | None] | None:
    """:func:`identify` when the store can answer from memory (a token or session seen before), else None."""
    store = request.app.state.store
    header = request.headers.get("authorization", "")
    if header.lower().startswith("bearer "):
        user = store.cached_user(token=header[7:].strip())
        return None if user is None else (user, None)
    session = request.cookies.get(SESSION_COOKIE)
    if session:
        user = store.cached_user(session=session)
        return None if user is None else (user, session)
    return None


async def current_user(request: Request) -> User:
    """The dependency of every protected route: 401 without credentials, 403 on a bad CSRF token.
    Async: a known token or session is checked in the event loop without a thread hop; an unknown
    one (argon2, a database read) is checked in a worker thread."""
    known = _identify_from_memory(request)
    if known is None:
        from fastapi.concurrency import run_in_threadpool
        known = await run_in_threadpool(identify, request)
    return _admit(request, *known)


def require_user(request: Request) -> User:
    """:func:`current_user` for synchronous callers."""
    return _admit(request, *identify(request))


def _admit(request: Request, user: User | None, session: str | None) -> User:
    if user is None:
        raise NotLoggedIn()
    from laplab.console.safety import refuse_unless_admitted
    refuse_unless_admitted(request.app.state, user.is_admin)
    if session is not None and request.method not in SAFE_METHODS:
        sent = request.headers.get(CSRF_HEADER, "")
        if not hmac.compare_digest(sent, csrf_token(request.app.state.secret, session)):
            raise HTTPException(403, "missing or wrong CSRF token: reload the page and try again")
    request.state.user = user
    request.state.session = session
    return user
