"""Who may do what, in one place: FastAPI dependencies over :func:`laplab.console.auth.current_user`
for the three roles (admin, race facilitator, racer) — :func:`require_role` of a purpose of
:data:`PERMISSIONS`, each with its refusal — and the console's account services
(:class:`laplab.jobs.accounts.Accounts`, :class:`laplab.jobs.quotas.Quotas`,
:class:`laplab.races.store.RaceStore`) kept on the app's state."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from fastapi import Depends, HTTPException, Request

from laplab.console.auth import current_user
from laplab.jobs.db import User


@dataclass(frozen=True)
class Permission:
    """Who may do one thing: the ``roles`` allowed, the ``refusal`` the others get (followed by the
    asker's role) and a ``hint`` of what to do instead."""
    roles: tuple[str, ...]
    refusal: str
    hint: str = ""

    def message(self, role: str) -> str:
        return f"{self.refusal} (you are a {role}){': ' + self.hint if self.hint else ''}."


PERMISSIONS = {
    "manage accounts": Permission(("admin",), "Only an admin can manage accounts"),
    "change roles": Permission(("admin",), "Only an admin can change a user's role"),
    "manage quotas": Permission(("admin",), "Only an admin can set quotas"),
    "invite": Permission(("admin", "facilitator"), "Only an admin or a race facilitator can create invitations",
                         "ask your race facilitator for an invitation link"),
    "run races": Permission(("admin", "facilitator"), "Only an admin or a race facilitator can create and run "
                                                      "races"),
}


def refuse_unless_allowed(user: User, purpose: str) -> User:
    """``user`` when their role may do ``purpose`` (a key of :data:`PERMISSIONS`); else a 403 whose
    message names the rule and their role. The console's error handler turns it into JSON for
    ``/api`` routes and into the HTML error page for pages (:mod:`laplab.console.error_pages`)."""
    permission = PERMISSIONS[purpose]
    if user.role not in permission.roles:
        raise HTTPException(403, {"message": permission.message(user.role),
                                  "purpose": purpose})
    return user


def require_role(purpose: str) -> Callable[..., User]:
    """A FastAPI dependency: the signed-in user, when their role may do ``purpose``; 403 otherwise."""
    if purpose not in PERMISSIONS:
        raise KeyError(f"no permission named {purpose!r}; known are {', '.join(PERMISSIONS)}")

    def allowed_user(user: User = Depends(current_user)) -> User:
        return refuse_unless_allowed(user, purpose)
    allowed_user.__name__ = f"may_{purpose.replace(' ', '_')}"
    return allowed_user


admin_user = require_role("manage accounts")  # the admin's account routes and pages
role_admin = require_role("change roles")
quota_admin = require_role("manage quotas")
inviter = require_role("invite")  # admins and race facilitators
race_runner = require_role("run races")  # admins and race facilitators


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
