"""The pages of races and people: races (list, create / edit, one race with its submissions), the
live race board for a projector, invitations, sign-up through an invitation link, password sign-in,
profile and usage. They call the JSON API (:mod:`laplab.console.api_races`,
:mod:`laplab.console.api_accounts`), which checks every request again.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, Form, HTTPException, Request
from fastapi.responses import HTMLResponse, RedirectResponse

from laplab.console.api_races import manages, refuse_unless_manages, visible_race
from laplab.console.auth import SESSION_COOKIE, current_user
from laplab.console.pages import TEMPLATES, _page
from laplab.console.roles import accounts, inviter, race_runner, races
from laplab.jobs.db import User

router = APIRouter(include_in_schema=False)


@router.get("/races", response_class=HTMLResponse)
def races_page(request: Request, user: User = Depends(current_user)):
    return _page(request, "races.html", user, title="Races")


@router.get("/races/new", response_class=HTMLResponse)
def new_race_page(request: Request, user: User = Depends(race_runner)):
    return _page(request, "race_edit.html", user, title="Create race", race_id=None)


@router.get("/races/join/{code}")
def join_link(code: str, request: Request, user: User = Depends(current_user)):
    """A private race's link: joins it and opens it (a wrong code: 404 naming the rule)."""
    race = races(request).by_code(code)
    if race is None:
        raise HTTPException(404, {"message": "no race has this join code (ask your facilitator for the link)"})
    races(request).join(race.id, user.id)
    return RedirectResponse(f"/races/{race.id}", status_code=303)


@router.get("/races/{race_id}", response_class=HTMLResponse)
def race_page(race_id: int, request: Request, user: User = Depends(current_user)):
    race = visible_race(request, race_id, user)
    return _page(request, "race.html", user, title=race.settings.name, race_id=race.id, manages=manages(race, user))


@router.get("/races/{race_id}/edit", response_class=HTMLResponse)
def edit_race_page(race_id: int, request: Request, user: User = Depends(race_runner)):
    race = refuse_unless_manages(visible_race(request, race_id, user), user)
    return _page(request, "race_edit.html", user, title="Edit race", race_id=race.id)


@router.get("/races/{race_id}/board", response_class=HTMLResponse)
def race_board_page(race_id: int, request: Request, user: User = Depends(current_user)):
    """The live board for a projector: large type, top three highlighted, the newest laps replayed."""
    race = visible_race(request, race_id, user)
    return _page(request, "race_board.html", user, title=f"{race.settings.name} · board", race_id=race.id)


@router.get("/invites", response_class=HTMLResponse)
def invites_page(request: Request, user: User = Depends(inviter)):
    return _page(request, "invites.html", user, title="Invitations")


@router.get("/profile", response_class=HTMLResponse)
def profile_page(request: Request, user: User = Depends(current_user)):
    return _page(request, "profile.html", user, title="Profile")


@router.get("/usage", response_class=HTMLResponse)
def usage_page(request: Request, user: User = Depends(current_user)):
    return _page(request, "usage.html", user, title="Usage")


@router.get("/join/{code}", response_class=HTMLResponse)
def join_page(code: str, request: Request):
    """Sign up through an invitation link (no login: the link is the permission)."""
    from laplab.jobs.accounts import AccountError
    try:
        invite = accounts(request).invite_for(code)
        error = None
    except AccountError as exc:
        invite, error = None, str(exc).removeprefix("invite: ")
    return TEMPLATES.TemplateResponse(request, "signup.html", {"code": code, "invite": invite, "error": error},
                                      status_code=200 if invite else 410)


@router.post("/login/password", response_class=HTMLResponse)
def password_login(request: Request, name: str = Form(""), password: str = Form("")):
    """Sign in with a name and password (accounts made through an invitation); throttled per name."""
    from fastapi.concurrency import run_in_threadpool  # noqa: F401 - the route itself runs in a worker thread
    from laplab.console.limits import LoginThrottled
    from laplab.console.pages import _login_page
    from laplab.console.safety import NO_SANDBOX_REFUSAL, may_admit
    throttle = request.app.state.login_throttle
    key = f"name:{name.strip()[:64]}"
    try:
        throttle.check(key)
    except LoginThrottled as exc:
        return _login_page(request, str(exc), 429)
    user = accounts(request).user_for_password(name.strip(), password) if name.strip() and password else None
    if user is None:
        throttle.failed(key)
        return _login_page(request, "unknown name or wrong password", 401)
    if not may_admit(request.app.state, user.is_admin):
        return _login_page(request, NO_SANDBOX_REFUSAL, 403)
    session = request.app.state.store.new_session(user.id)
    response = RedirectResponse("/races", status_code=303)
    response.set_cookie(SESSION_COOKIE, session, httponly=True, samesite="strict", max_age=7 * 24 * 3600,
                        secure=request.url.scheme == "https")
    return response
