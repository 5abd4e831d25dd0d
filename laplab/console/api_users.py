"""The admin's account routes (``/api/users``): list, create, disable / enable, revoke tokens,
remove. What ``laplab users`` does, from the console; every route answers 403 to other users.

A user other than the admin is created only where the console may admit one
(:mod:`laplab.console.safety`: jobs sandboxed, or ``laplab serve --no-sandbox``).
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, Request
from pydantic import BaseModel, ConfigDict, Field

from laplab.console.roles import admin_user
from laplab.console.safety import refuse_unless_admitted
from laplab.jobs.db import StoreError, User

router = APIRouter(prefix="/api/users")


class NewUser(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = Field(max_length=64)
    admin: bool = False


def _store_call(request: Request, change):
    try:
        answer = change()
    except StoreError as exc:
        raise HTTPException(404 if str(exc).startswith("no user named") else 409, {"message": str(exc)}) from None
    service = request.app.state.service
    service.models_changed()  # owners and names may have changed
    service.stop_jobs_of_absent_users()
    return answer


@router.get("")
def list_users(request: Request, user: User = Depends(admin_user)) -> list[dict]:
    return request.app.state.store.user_rows()


@router.post("", status_code=201)
def create_user(body: NewUser, request: Request, user: User = Depends(admin_user)) -> dict:
    store = request.app.state.store
    refuse_unless_admitted(request.app.state, body.admin)
    created, token = _store_call(request, lambda: store.add_user(body.name, is_admin=body.admin))
    if not created.is_admin:  # as an invitation's sign-up: the new-user quota
        from laplab.jobs.quotas import Quotas
        Quotas(store).apply_new_user_quota(created.id)
    return {"name": created.name, "admin": created.is_admin, "token": token}


def _not_yourself(user: User, name: str, what: str) -> None:
    if name == user.name:
        raise HTTPException(409, {"message": f"you cannot {what} your own account here (use `laplab users`)"})


@router.post("/{name}/disable")
def disable_user(name: str, request: Request, user: User = Depends(admin_user)) -> dict:
    store = request.app.state.store
    _not_yourself(user, name, "disable")
    _store_call(request, lambda: store.set_disabled(name, True))
    return {"name": name, "disabled": True}


@router.post("/{name}/enable")
def enable_user(name: str, request: Request, user: User = Depends(admin_user)) -> dict:
    store = request.app.state.store
    _store_call(request, lambda: store.set_disabled(name, False))
    return {"name": name, "disabled": False}


@router.post("/{name}/tokens", status_code=201)
def new_token(name: str, request: Request, user: User = Depends(admin_user)) -> dict:
    store = request.app.state.store
    target = store.user_by_name(name)
    if target is None:
        raise HTTPException(404, {"message": f"no user named {name!r}"})
    refuse_unless_admitted(request.app.state, target.is_admin)
    return {"name": name, "token": store.add_token(target.id, "console")}


@router.delete("/{name}/tokens")
def revoke_all(name: str, request: Request, user: User = Depends(admin_user)) -> dict:
    store = request.app.state.store
    return {"name": name, "revoked": _store_call(request, lambda: store.revoke_tokens(name))}


@router.delete("/{name}/tokens/{token_id}")
def revoke_one(name: str, token_id: str, request: Request, user: User = Depends(admin_user)) -> dict:
    store = request.app.state.store
    return {"name": name, "revoked": _store_call(request, lambda: store.revoke_tokens(name, token_id))}


@router.delete("/{name}")
def remove_user(name: str, request: Request, user: User = Depends(admin_user)) -> dict:
    store = request.app.state.store
    _not_yourself(user, name, "remove")
    return {"removed": name, "models_to_admin": _store_call(request, lambda: store.remove_user(name))}
