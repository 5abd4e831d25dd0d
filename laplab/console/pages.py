"""The console's HTML pages (Jinja2) and its static files; the pages call the JSON API.

Every page needs a user (a Bearer token or the session cookie), except the login page.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from fastapi import APIRouter, Depends, Form, HTTPException, Request
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse
from fastapi.templating import Jinja2Templates

from laplab.console.auth import SESSION_COOKIE, NotLoggedIn, csrf_token, current_user, identify, require_user
from laplab.console.roles import admin_user
from laplab.jobs.db import User

TEMPLATES = Jinja2Templates(directory=str(Path(__file__).parent / "templates"))
STATIC_DIR = Path(__file__).parent / "static"
router = APIRouter(include_in_schema=False)


def _page(request: Request, template: str, user: User, **context) -> HTMLResponse:
    session = getattr(request.state, "session", None)
    token = csrf_token(request.app.state.secret, session) if session else ""
    from laplab.console.safety import banner
    return TEMPLATES.TemplateResponse(request, template, {"user": user, "csrf": token,
                                                          "banner": banner(request.app.state), **context})


def _defaults() -> dict:
    from laplab.agents.hyperparameters import Hyperparameters
    from laplab.env.metadata import ALGORITHMS, NETWORKS, SENSOR_CHOICES, ModelMetadata
    from laplab.train.request import TrainRequest
    return {"metadata": ModelMetadata().to_dict(), "hyperparameters": Hyperparameters().to_dict(),
            "sensors": ["+".join(choice) for choice in SENSOR_CHOICES], "networks": NETWORKS,
            "algorithms": ALGORITHMS, "max_time_min": f"{TrainRequest().max_time_s / 60:g}"}


def _model_key(request: Request, name: str, user: User) -> str:
    """The key of the model ``user`` calls ``name`` (names are per user); 404 when they have none."""
    key = request.app.state.service.resolve(user, name)
    if key is None:
        raise HTTPException(404, f"no model named {name!r} among your models")
    return key


@router.get("/login", response_class=HTMLResponse)
def login_page(request: Request, token: str | None = None):
    if token:
        return _login(request, token)
    return _login_page(request, None)


def _login_page(request: Request, error: str | None, status_code: int = 200):
    from laplab.console.safety import banner
    return TEMPLATES.TemplateResponse(request, "login.html", {"error": error, "banner": banner(request.app.state)},
                                      status_code=status_code)


@router.post("/login", response_class=HTMLResponse)
def login_form(request: Request, token: str = Form("")):
    return _login(request, token.strip())


def _login(request: Request, token: str):
    from laplab.console.auth import user_for_token
    from laplab.console.safety import NO_SANDBOX_REFUSAL, may_admit
    try:
        user = user_for_token(request.app.state, token)
    except HTTPException as exc:  # throttled
        return _login_page(request, exc.detail["message"], exc.status_code)
    if user is None:
        return _login_page(request, "unknown or expired token", 401)
    if not may_admit(request.app.state, user.is_admin):
        return _login_page(request, NO_SANDBOX_REFUSAL, 403)
    session = request.app.state.store.new_session(user.id)
    response = RedirectResponse("/", status_code=303)
    response.set_cookie(SESSION_COOKIE, session, httponly=True, samesite="strict", max_age=7 * 24 * 3600,
                        secure=request.url.scheme == "https")
    return response


@router.post("/logout")
def logout(request: Request, user: User = Depends(current_user)):
    session = request.cookies.get(SESSION_COOKIE)
    if session:
        request.app.state.store.end_session(session)
    response = RedirectResponse("/login", status_code=303)
    response.delete_cookie(SESSION_COOKIE)
    return response


@router.get("/static/{path:path}")
def static(path: str, user: User = Depends(current_user)):
    target = (STATIC_DIR / path).resolve()
    if STATIC_DIR.resolve() not in target.parents or not target.is_file():
        raise HTTPException(404, "no such file")
    return FileResponse(target, headers={"Cache-Control": "max-age=300"})


@router.get("/", response_class=HTMLResponse)
def models_page(request: Request):
    user, _ = identify(request)
    if user is None:
        if "text/html" in request.headers.get("accept", ""):
            return RedirectResponse("/login", status_code=303)
        raise NotLoggedIn()
    require_user(request)
    return _page(request, "models.html", user, title="Models")


@router.get("/create", response_class=HTMLResponse)
def create_page(request: Request, clone: str | None = None, user: User = Depends(current_user)):
    source = None
    if clone:
        key = _model_key(request, clone, user)
        from laplab.jobs.runner import models_dir
        folder = models_dir() / key
        config = json.loads((folder / "laplab.json").read_text())
        source = {"name": clone, "config": config, "reward": (folder / "reward_function.py").read_text()}
    return _page(request, "create.html", user, title="Clone model" if clone else "Create model",
                 defaults=_defaults(), source=source)


@router.get("/models/{name}", response_class=HTMLResponse)
def model_page(name: str, request: Request, user: User = Depends(current_user)):
    _model_key(request, name, user)
    return _page(request, "model.html", user, title=name, model=name)


@router.get("/models/{name}/report", response_class=HTMLResponse)
def report_redirect(name: str, request: Request, user: User = Depends(current_user)):
    """The report lives at ``.../report/`` so that its figures (files beside the page) resolve."""
    _model_key(request, name, user)
    return RedirectResponse(f"/models/{name}/report/", status_code=307)


@router.get("/models/{name}/report/", response_class=HTMLResponse)
def report_page(name: str, request: Request, user: User = Depends(current_user)):
    """The model's HTML report (``laplab report``), built in a child process; its figures are
    served by :func:`report_file`."""
    name = _model_key(request, name, user)
    from laplab.console.exports import ExportError, _laplab
    from laplab.jobs.runner import models_dir
    try:
        page = Path(_laplab(["report", name], models_dir())["page"])
    except ExportError as exc:
        raise HTTPException(400, {"message": str(exc)}) from None
    if not page.is_file():
        raise HTTPException(500, "laplab report wrote no page")
    from laplab.console.safety import banner_html
    html = page.read_text(encoding="utf-8")
    notice = banner_html(request.app.state)
    if notice:
        html = re.sub(r"(<body[^>]*>)", lambda m: m.group(1) + notice, html, count=1)
    return HTMLResponse(html, headers={"Cache-Control": "no-store"})


@router.get("/models/{name}/report/{file}")
def report_file(name: str, file: str, request: Request, user: User = Depends(current_user)):
    """A figure (PNG), video or data file of the model's last built report."""
    name = _model_key(request, name, user)
    from laplab.jobs.runner import models_dir
    folder = (models_dir() / name / "report").resolve()
    target = (folder / file).resolve()
    if target.parent != folder or not target.is_file():
        raise HTTPException(404, f"the report of {name!r} has no file {file!r}")
    return FileResponse(target, headers={"Cache-Control": "no-store"})


@router.get("/users", response_class=HTMLResponse)
def users_page(request: Request, user: User = Depends(admin_user)):
    """The admin's accounts page (over ``/api/users``)."""
    return _page(request, "users.html", user, title="Accounts")


@router.get("/leaderboard", response_class=HTMLResponse)
def leaderboard_page(request: Request, user: User = Depends(current_user)):
    return _page(request, "leaderboard.html", user, title="Leaderboard")
