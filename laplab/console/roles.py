"""Who may do what, in one place: FastAPI dependencies over :func:`laplab.console.auth.current_user`
for the three roles (admin, race facilitator, racer), and the console's account services
(:class:`laplab.jobs.accounts.Accounts`, :class:`laplab.jobs.quotas.Quotas`,
:class:`laplab.races.store.RaceStore`) kept on the app's state."""

from __future__ import annotations

from fastapi import Depends, HTTPException, Request

from laplab.console.auth import current_user
from laplab.jobs.db import User


def admin_user(user: User = Depends(current_user)) -> User:
    """403 unless an admin asks."""
    if not user.is_admin:
        raise HTTPException(403, {"message": f"only an admin may do this (you are a {user.role})"})
    return user


def race_runner(user: User = Depends(current_user)) -> User:
    """403 unless an admin or race facilitator asks."""
    if not user.runs_races:
        raise HTTPException(403, {"message": "only race facilitators and admins create and run races (you are a "
                                             f"{user.role})"})
    return user


def refusal(exc: Exception, status: int = 400) -> HTTPException:
    """A laplab UserError as the API's error body: its message and field."""
    detail = {"message": str(exc)}
    field = getattr(exc, "field", None)
    if field:
        detail["field"] = field
    return HTTPException(status, detail)


def accounts(request: Request):
    """The app's :class:`laplab.jobs.accounts.Accounts` (made by ``create_app``)."""
    return request.app.state.accounts


def quotas(request: Request):
    """The app's :class:`laplab.jobs.quotas.Quotas`."""
    return request.app.state.quotas


def races(request: Request):
    """The app's :class:`laplab.races.store.RaceStore`."""
    return request.app.state.races


def check_quota(request: Request, user: User, kind: str, params: dict) -> None:
    """403 naming the quota when ``kind`` (train, clone, resume, evaluate) with ``params`` would take
    ``user`` or the console over its compute minutes or model count (:mod:`laplab.jobs.quotas`)."""
    from laplab.jobs.quotas import QuotaExceeded
    try:
        quotas(request).check_job(user.id, kind, params, request.app.state.limits.max_time_s)
    except QuotaExceeded as exc:
        raise refusal(exc, 403) from None
