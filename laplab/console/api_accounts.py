"""The JSON API of people: invitations (``/api/invites``), signing up through one (``/api/signup``,
the only route here without a login), passwords and profiles (``/api/me/...``), roles
(``/api/users/{name}/role``), quotas and usage (``/api/quotas``, ``/api/usage``).

Admins invite any role and manage quotas; race facilitators invite racers; everyone manages their
own password and profile and reads their own usage (an admin reads everyone's).
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, ConfigDict, Field

from laplab.console.auth import current_user
from laplab.console.roles import accounts, inviter, quota_admin, quotas, refusal, role_admin
from laplab.jobs.accounts import AccountError, NotAllowed
from laplab.jobs.db import StoreError, User
from laplab.jobs.quotas import QuotaExceeded

router = APIRouter(prefix="/api", tags=["people"])


class NewInvite(BaseModel):
    model_config = ConfigDict(extra="forbid")
    role: str = Field("racer", description="admin, facilitator or racer")
    expires_in_h: float = Field(72.0, description="hours the link stays valid (one use)")


class SignUp(BaseModel):
    model_config = ConfigDict(extra="forbid")
    invite: str = Field(max_length=200)
    name: str = Field(max_length=64)
    password: str = Field(max_length=256)
    alias: str = Field("", max_length=200)
    country: str = Field("", max_length=8)


class NewPassword(BaseModel):
    model_config = ConfigDict(extra="forbid")
    old_password: str | None = Field(None, max_length=256)
    new_password: str = Field(max_length=256)


class ProfileChange(BaseModel):
    model_config = ConfigDict(extra="forbid")
    alias: str | None = Field(None, max_length=200)
    country: str | None = Field(None, max_length=8)
    colour: str | None = Field(None, max_length=16)


class RoleChange(BaseModel):
    model_config = ConfigDict(extra="forbid")
    role: str


class QuotaSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    global_minutes: float | None = None
    global_models: int | None = None
    new_user_minutes: float | None = None
    new_user_models: int | None = None


class UserQuota(BaseModel):
    model_config = ConfigDict(extra="forbid")
    minutes: float | None = None
    models: int | None = Field(None, ge=0)


@router.post("/invites", status_code=201)
def create_invite(body: NewInvite, request: Request, user: User = Depends(inviter)) -> dict:
    """A one-time invitation link for ``role`` (racers for a facilitator); the code is shown once."""
    try:
        invite = accounts(request).create_invite(user, body.role, body.expires_in_h * 3600.0)
    except AccountError as exc:
        raise refusal(exc, 403 if isinstance(exc, NotAllowed) else 400) from None
    return {**invite, "link": f"{str(request.base_url).rstrip('/')}/join/{invite['code']}"}


@router.get("/invites")
def list_invites(request: Request, user: User = Depends(inviter)) -> list[dict]:
    return accounts(request).invites(user)


@router.delete("/invites/{invite_id}")
def revoke_invite(invite_id: str, request: Request, user: User = Depends(inviter)) -> dict:
    try:
        accounts(request).revoke_invite(user, invite_id)
    except AccountError as exc:
        raise refusal(exc, 404) from None
    return {"revoked": invite_id}


@router.get("/invites/check/{code}")
def check_invite(code: str, request: Request) -> dict:
    """Whether an invitation link is still good (no login: the sign-up page asks), and its role."""
    try:
        invite = accounts(request).invite_for(code)
    except AccountError as exc:
        raise refusal(exc, 410) from None
    return {"role": invite["role"], "expires": invite["expires"]}


@router.post("/signup", status_code=201)
async def sign_up(body: SignUp, request: Request) -> dict:
    """Create an account through an invitation: name, password (argon2) and profile; the invitation
    is used up. Signing in afterwards: ``POST /login/password`` (pages) or a token from an admin."""
    from laplab.console.safety import refuse_unless_admitted
    try:
        role = accounts(request).invite_for(body.invite)["role"]
        refuse_unless_admitted(request.app.state, role == "admin")
        user = await run_in_threadpool(accounts(request).sign_up, body.invite, body.name, body.password,
                                       body.alias, body.country)
    except AccountError as exc:
        raise refusal(exc, 410 if exc.field == "invite" else 400) from None
    return {"name": user.name, "role": user.role}


@router.post("/me/password")
async def change_password(body: NewPassword, request: Request, user: User = Depends(current_user)) -> dict:
    try:
        await run_in_threadpool(accounts(request).set_password, user, body.old_password, body.new_password)
    except AccountError as exc:
        raise refusal(exc) from None
    return {"changed": True}


@router.get("/me/profile")
def my_profile(request: Request, user: User = Depends(current_user)) -> dict:
    return {**accounts(request).profile(user.id).to_dict(), "role": user.role}


@router.put("/me/profile")
def change_profile(body: ProfileChange, request: Request, user: User = Depends(current_user)) -> dict:
    try:
        return accounts(request).update_profile(user, body.alias, body.country, body.colour).to_dict()
    except AccountError as exc:
        raise refusal(exc) from None


@router.post("/users/{name}/role")
def set_role(name: str, body: RoleChange, request: Request, user: User = Depends(role_admin)) -> dict:
    if name == user.name:
        raise HTTPException(409, {"message": "you cannot change your own role here (use another admin's account)"})
    try:
        changed = accounts(request).set_role(name, body.role)
    except AccountError as exc:
        raise refusal(exc) from None
    except StoreError as exc:
        raise refusal(exc, 404) from None
    return {"name": changed.name, "role": changed.role}


@router.get("/quotas")
def get_quotas(request: Request, user: User = Depends(quota_admin)) -> dict:
    return quotas(request).settings()


@router.put("/quotas")
def put_quotas(body: QuotaSettings, request: Request, user: User = Depends(quota_admin)) -> dict:
    try:
        return quotas(request).set_settings(body.model_dump())
    except QuotaExceeded as exc:
        raise refusal(exc) from None


@router.put("/users/{name}/quota")
def put_user_quota(name: str, body: UserQuota, request: Request, user: User = Depends(quota_admin)) -> dict:
    target = request.app.state.store.user_by_name(name)
    if target is None:
        raise HTTPException(404, {"message": f"no user named {name!r}"})
    try:
        quotas(request).set_user_limits(target.id, body.minutes, body.models)
    except QuotaExceeded as exc:
        raise refusal(exc) from None
    return {"name": name, "minutes": body.minutes, "models": body.models}


@router.get("/usage")
async def usage(request: Request, user: User = Depends(current_user)) -> dict:
    """Your compute minutes (used, reserved by queued and running jobs), models and storage against
    your quota; an admin gets every user's and the console's too."""
    from laplab.jobs.runner import models_dir
    ledger, cap = quotas(request), request.app.state.limits.max_time_s

    def build() -> dict:
        out = {"user": user.name, **ledger.usage(user.id, cap, models_dir()).to_dict()}
        if user.is_admin:
            out["console"] = ledger.usage(None, cap, models_dir()).to_dict()
            out["users"] = [{"user": u.name, "role": u.role, **ledger.usage(u.id, cap, models_dir()).to_dict()}
                            for u in request.app.state.store.users()]
        return out
    return await run_in_threadpool(build)
