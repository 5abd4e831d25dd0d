"""The console application: ``create_app(...)`` builds the FastAPI app (API, pages, static files)
with its job store, runner and scheduler; ``laplab serve`` runs it under uvicorn."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os

from fastapi import Depends, FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from laplab.console.auth import current_user, load_secret
from laplab.console.error_pages import error_page, wants_html
from laplab.console.limits import BodyLimit, LoginThrottle
from laplab.console.service import ConsoleService, default_workers, threads_per_job
from laplab.jobs.db import JobStore, User, laplab_home
from laplab.jobs.runner import LocalProcessRunner
from laplab.jobs.confinement import JobLimits

log = logging.getLogger("laplab.console")


def ensure_admin(store: JobStore) -> str | None:
    """Create the admin on first start; returns its token then (``LAPLAB_ADMIN_TOKEN`` when set)."""
    if store.admin() is not None:
        return None
    env_token = os.environ.get("LAPLAB_ADMIN_TOKEN") or None
    _, token = store.add_user("admin", is_admin=True, token=env_token,
                              token_label="admin-env" if env_token else "login")
    return token


def create_app(workers: int | None = None, *, sandbox: bool | None = None, open_access: bool = False,
               limits: JobLimits | None = None, tick_s: float | None = None, warm_cache: bool = True,
               cluster=None, allow_unsandboxed: bool = False, max_body_bytes: int = 1 << 20,
               max_upload_bytes: int = 1 << 30) -> FastAPI:
    """The console app over ``$LAPLAB_HOME`` (database, secret key, model folders); ``warm_cache``
    compiles numba's kernels once in the background for new users' jobs (:mod:`laplab.jobs.warmup`);
    ``cluster`` (a :class:`laplab.cluster.console.RayCluster`) runs training jobs' rollout workers on Ray;
    ``allow_unsandboxed`` (``laplab serve --no-sandbox``) lets users other than the admin in when jobs
    run without bubblewrap (:mod:`laplab.console.safety`); ``max_body_bytes`` / ``max_upload_bytes``:
    the largest request body (import: upload) accepted, and ``limits.max_time_s`` the longest training
    (:mod:`laplab.console.limits`)."""
    from laplab.console import (api, api_accounts, api_duels, api_exports, api_races, api_results, api_users, pages,
                                pages_races)
    from laplab.console.service import TICK_S

    home = laplab_home()
    home.mkdir(parents=True, exist_ok=True)
    store = JobStore()
    first_token = ensure_admin(store)
    workers = workers or default_workers()
    limits = limits if limits is not None else JobLimits.console()
    runner = LocalProcessRunner(limits, sandbox=sandbox, cluster=cluster, threads_per_job=threads_per_job(workers))
    service = ConsoleService(store, runner, workers)
    interval = tick_s or TICK_S

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        service.hub.attach(asyncio.get_running_loop())
        async def schedule():
            while True:
                try:
                    service.tick()
                except Exception:  # noqa: BLE001 - the scheduler must survive one bad tick
                    log.exception("scheduler tick failed")
                await asyncio.sleep(interval)
        task = asyncio.create_task(schedule())
        from laplab.jobs.warmup import start_warmup
        warmup = start_warmup(home) if warm_cache else None
        try:
            yield
        finally:
            task.cancel()
            service.server_stopping = True  # jobs stopped now become `interrupted`, resumable with their time left
            if warmup is not None and warmup.poll() is None:
                warmup.kill()
                warmup.wait()
            await asyncio.get_running_loop().run_in_executor(None, runner.shutdown)
            service.tick()
            store.interrupt_running()  # any the runner could not reap

    app = FastAPI(title="laplab console", version="1", lifespan=lifespan, openapi_url=None, docs_url=None,
                  redoc_url=None,
                  description="DeepRacer's console on laplab: models, training jobs, evaluations, leaderboard, races, "
                              "invitations, quotas.")
    app.state.store, app.state.service, app.state.secret = store, service, load_secret(home)
    app.state.open_access, app.state.sandbox = open_access, runner.sandbox
    app.state.allow_unsandboxed = bool(allow_unsandboxed)
    app.state.limits, app.state.login_throttle = limits, LoginThrottle(store.path)
    app.add_middleware(BodyLimit, json_bytes=max_body_bytes, upload_bytes=max_upload_bytes)
    app.state.cluster = cluster
    app.state.first_token = first_token
    from laplab.jobs.accounts import Accounts
    from laplab.jobs.quotas import Quotas
    from laplab.races.store import RaceStore
    app.state.accounts, app.state.quotas, app.state.races = Accounts(store), Quotas(store), RaceStore(store)

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError):
        errors = exc.errors()
        first = errors[0] if errors else {}
        where = ".".join(str(p) for p in first.get("loc", ()) if p != "body")
        message = f"{where}: {first.get('msg', 'invalid value')}" if where else first.get("msg", "invalid request")
        return JSONResponse(status_code=422, content={"detail": {"message": message, "field": where or None,
                                                                 "errors": [{"loc": e.get("loc"), "msg": e.get("msg")}
                                                                            for e in errors]}})

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException):
        if exc.status_code == 400 and exc.__cause__ is not None and exc.detail == "There was an error parsing the body":
            # FastAPI's words for a body its JSON parser gave up on (not a syntax error: those are 422s)
            why = ("it nests arrays or objects deeper than Python's JSON parser allows (about 1,000 levels)"
                   if isinstance(exc.__cause__, RecursionError) else f"{type(exc.__cause__).__name__}")
            return JSONResponse(status_code=400, content={"detail": {
                "message": f"body: the request body cannot be read as JSON: {why}; send one JSON object of the "
                           "request's fields (docs/console.md lists them)", "field": "body"}})
        if wants_html(request):
            return error_page(request, exc.status_code, exc.detail)
        return await http_exception_handler(request, exc)

    @app.get("/openapi.json", include_in_schema=False)
    def openapi(user: User = Depends(current_user)) -> dict:
        return app.openapi()

    app.include_router(api.router)
    app.include_router(api_results.router)
    app.include_router(api_exports.router)
    app.include_router(api_users.router)
    app.include_router(api_accounts.router)
    app.include_router(api_races.router)
    app.include_router(api_duels.router)
    app.include_router(pages.router)
    app.include_router(pages_races.router)
    return app
