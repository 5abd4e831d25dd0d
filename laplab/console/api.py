"""The console's JSON API (``/api/...``); the pages use it, so do scripts and tests.

Every route but ``/api/health`` needs a user (see :mod:`laplab.console.auth`). A user sees and
changes only their own models (the admin sees all); the leaderboard shows everyone's. Bad input
gets a 400 (or FastAPI's 422 for a malformed body) whose ``detail`` is laplab's own message.
"""

from __future__ import annotations

import asyncio
import json
from dataclasses import fields
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request, Response
from fastapi.concurrency import run_in_threadpool

from laplab.console.auth import current_user
from laplab.console.bodies import CREATE_FIELDS, CloneModel, CreateModel, Resume
from laplab.console.roles import check_quota
from laplab.console.service import display_name
from laplab.evaluate.trials import EvaluationSettings
from laplab.train.request import TrainRequest
from laplab.jobs.db import StoreError, User
from laplab.jobs.runner import models_dir

router = APIRouter(prefix="/api")


def _service(request: Request):
    return request.app.state.service


def bad_request(message: str, field: str | None = None, **extra) -> HTTPException:
    detail: dict[str, Any] = {"message": message}
    if field:
        detail["field"] = field
    detail.update(extra)
    return HTTPException(400, detail)


def _input_errors() -> tuple[type[BaseException], ...]:
    from laplab.cli import user_error_types
    from laplab.evaluate.trials import EvaluationError
    return (*user_error_types(), EvaluationError)


def _field_of(exc: BaseException) -> str | None:
    """The request field an input error is about (laplab.errors.UserError carries it)."""
    field = getattr(exc, "field", None)
    return field if field in _REQUEST_FIELDS else None


_REQUEST_FIELDS = ("name", *(f.name for f in fields(TrainRequest)), *(f.name for f in fields(EvaluationSettings)))


def own_model(request: Request, name: str, user: User) -> str:
    """The key (folder name) of the model ``user`` calls ``name``; 404 unless it exists and ``user``
    may see it (other users' models do not exist for you: model names are per user)."""
    key = _service(request).resolve(user, name)
    if key is None:
        raise HTTPException(404, f"no model named {name!r} among your models")
    return key


def check_track_name(track: str | None) -> None:
    """The console takes track names (built-in or imported), never server paths."""
    if track is None:
        return
    from laplab.track.registry import available_tracks
    name = track.removesuffix("@reversed")
    known = [t.name for t in available_tracks()]
    if name not in known:
        raise bad_request(f"unknown track {track!r}: pick one of {', '.join(known)} (GET /api/tracks); "
                          "import other routes with `laplab tracks import FILE.npy`", "track")


def _check_train_inputs(values: dict) -> tuple[TrainRequest, object]:
    """The :class:`TrainRequest` of ``values`` and the TrainConfig the worker will build from it
    (every check of the CLI, the track loaded); a 400 naming the request's field otherwise."""
    check_track_name(values.get("track"))
    try:
        request = TrainRequest.from_mapping(values)
        return request, request.validate()
    except _input_errors() as exc:
        raise bad_request(str(exc), _field_of(exc)) from None


def _job_workers(request: Request, requested: int | None, episodes: int) -> dict:
    """``{"workers": N}`` for a training job of a console with a Ray cluster (``{}`` without one);
    a 400 naming ``workers`` for a count it cannot give."""
    from laplab.cluster.console import job_worker_count
    from laplab.train.errors import JobError
    cluster = request.app.state.cluster
    try:
        count = job_worker_count(requested, cluster, int(episodes))
    except JobError as exc:
        raise bad_request(str(exc), "workers") from None
    return {"workers": count} if cluster is not None else {}


async def _validate_reward(request: Request, user: User, source: str, track: str | None, metadata: dict | None,
                           race_type: dict | None = None) -> dict:
    from laplab.jobs.validate import validate_confined
    return await run_in_threadpool(validate_confined, source, track, metadata, user.id,
                                   request.app.state.sandbox, race_type)


def check_max_time(request: Request, max_time_s: float | None) -> None:
    """400 naming ``max_time_s`` for a training longer than this console allows."""
    from laplab.console.limits import check_max_time as over_cap
    message = over_cap(max_time_s, request.app.state.limits.max_time_s)
    if message:
        raise bad_request(message, "max_time_s")


def _name_free(request: Request, name: str, user: User) -> str:
    """The key of ``user``'s new model ``name``: a 400 for a bad name, a 409 when ``user`` has a model
    of that name (names are per user: another user's models are never looked at, nor named)."""
    from laplab.console.service import model_key
    from laplab.store.layout import ModelNameError, validate_model_name
    key = model_key(user, name)
    try:
        validate_model_name(name)
        if key != name and len(key) > 64:
            raise ModelNameError(f"invalid model name {name!r}: at most {64 - len(key) + len(name)} characters "
                                 "on this console")
    except ModelNameError as exc:
        raise bad_request(str(exc), "name") from None
    owners = _service(request).owners()
    if key in owners or (models_dir() / key).exists() or owners.get(name) == user.id:
        raise HTTPException(409, {"message": f"you already have a model named {name!r}; models are immutable: "
                                             "pick another name or clone it", "field": "name"})
    return key


@router.get("/health", tags=["console"])
def health() -> dict:
    return {"ok": True}


@router.get("/me")
def me(user: User = Depends(current_user)) -> dict:
    return {"name": user.name, "admin": user.is_admin, "role": user.role}


@router.get("/models", response_model=list[dict])
async def list_models_route(request: Request, user: User = Depends(current_user)) -> Response:
    """Your models (all of them for the admin), newest first. Served from the last list built
    (file stats and a few SQLite reads, in a worker thread): a list older than ``LIST_TTL_S`` is
    answered at once and rebuilt in the background, so a burst of pages polling together never
    queues behind a rebuild. A status change drops the list, and the next request waits for a new one."""
    service = _service(request)
    body, fresh = service.cached_models_json(user)
    if body is None:
        body = await run_in_threadpool(service.visible_models_json, user)
    elif not fresh and service.claim_list_refresh(user):
        task = asyncio.create_task(_refresh_list(service, user))
        _BACKGROUND.add(task)
        task.add_done_callback(_BACKGROUND.discard)
    return Response(body, media_type="application/json")


_BACKGROUND: set[asyncio.Task] = set()  # strong references: the event loop keeps only weak ones


async def _refresh_list(service, user: User) -> None:
    try:
        await run_in_threadpool(service.visible_models_json, user)
    finally:
        service.list_refreshed(user)


async def _validate_and_claim(request: Request, user: User, key: str, body: CloneModel, reward_source: str | None,
                              track: str | None, model_metadata: dict | None) -> None:
    """Run the validation sweep on ``reward_source`` (None: the default reward, nothing to check; a
    failure is a 400 naming its line), then claim ``key`` (``body.name``) for ``user`` (409 when taken)."""
    if reward_source is not None:
        answer = await _validate_reward(request, user, reward_source, track, model_metadata,
                                        getattr(body, "race_type", None))
        if not answer["ok"]:
            first = answer["errors"][0]
            raise bad_request(first["message"], "reward_function", line=first.get("line"), errors=answer["errors"])
    try:
        _service(request).store.claim_model(key, user.id, body.description)
    except StoreError:
        raise HTTPException(409, {"message": f"you already have a model named {body.name!r}; models are immutable: "
                                             "pick another name or clone it", "field": "name"}) from None


@router.post("/models", status_code=201)
async def create_model(body: CreateModel, request: Request, user: User = Depends(current_user)) -> dict:
    service = _service(request)
    check_max_time(request, body.max_time_s)
    key = _name_free(request, body.name, user)
    train, config = _check_train_inputs(body.model_dump(include=set(CREATE_FIELDS)))
    workers = _job_workers(request, body.workers, config.hyper().num_episodes_between_training)
    params = {k: v for k, v in train.to_mapping().items() if k != "workers"}  # the console's count: _job_workers
    check_quota(request, user, "train", params)
    await _validate_and_claim(request, user, key, body, body.reward_function, body.track, body.model_metadata)
    job = service.submit("train", key, user.id, {**params, **workers}, reward_source=body.reward_function)
    return {**service.describe(key, viewer=user), "job": job.to_dict()}


@router.get("/models/{name}")
def get_model(name: str, request: Request, user: User = Depends(current_user)) -> dict:
    name = own_model(request, name, user)
    service = _service(request)
    model = service.describe(name, viewer=user)
    model["iterations"] = service.catalog.iterations(name)
    model["evaluation_jobs"] = [j.to_dict() for j in service.store.jobs(model=name, kind=("evaluate",))]
    from laplab.console.api_exports import download_blocks, export_view
    model["exports"] = [export_view(j) for j in service.store.jobs(model=name, kind=("export",))]
    model["downloads_blocked"] = download_blocks(name, model["status"])
    folder = models_dir() / name
    model["reward_function"] = (folder / "reward_function.py").read_text() if (folder / "reward_function.py").exists() else None
    config = folder / "laplab.json"
    model["config"] = json.loads(config.read_text()) if config.exists() else None
    if model["config"] and model["config"].get("cloned_from"):  # the source by the name its owner knows it by
        model["config"]["cloned_from"] = display_name(model["config"]["cloned_from"], user.id)
    model["workers"] = _worker_rows(folder, model["status"], model["iterations"])
    _, job = service.model_status(name, model)
    if model["config"] is None and job is not None and job.status == "queued":  # what it will train
        model["config"], model["reward_function"] = service.queued_config(job)
    model["rollout_workers"] = job.params.get("workers") if job is not None else None  # asked of the last job
    return model


def _worker_rows(folder, status: str, iterations: list[dict]) -> list[dict]:
    """The rollout workers of the model's last Ray session (:mod:`laplab.cluster.status`; none when
    a later session collected in-process); a worker the file calls alive is ``stopped`` once no job
    of the model runs (a killed job wrote no last word)."""
    from laplab.cluster.status import read_workers
    last = iterations[-1].get("iteration") if iterations else None
    rows = read_workers(folder, last if isinstance(last, int) else None)
    if status not in ("training", "stopping"):
        for row in rows:
            if row.get("state") in ("starting", "alive", "restarting"):
                row["state"] = "stopped"
    return rows


@router.post("/models/{name}/stop")
def stop_model(name: str, request: Request, user: User = Depends(current_user)) -> dict:
    name = own_model(request, name, user)
    service = _service(request)
    job = service.active_job(name)
    if job is None or job.kind == "evaluate":
        raise HTTPException(409, f"{name!r} is not training")
    service.stop(job)
    return service.describe(name, viewer=user)


@router.post("/models/{name}/resume", status_code=202)
def resume_model(name: str, request: Request, body: Resume | None = None, user: User = Depends(current_user)) -> dict:
    name = own_model(request, name, user)
    service = _service(request)
    if service.active_job(name) is not None:
        raise HTTPException(409, f"{name!r} already has a job queued or running")
    if not (models_dir() / name / "laplab.json").exists():
        raise HTTPException(409, f"{name!r} has no training to resume")
    max_time = body.max_time_s if body and body.max_time_s else None
    if max_time is not None:
        try:
            TrainRequest(max_time_s=max_time)  # its range and message
        except _input_errors() as exc:
            raise bad_request(str(exc), _field_of(exc)) from None
    check_max_time(request, max_time)
    saved = json.loads((models_dir() / name / "laplab.json").read_text())
    if max_time is None:
        max_time = _default_resume_time(request, name, saved)
    episodes = (saved.get("hyperparameters") or {}).get("num_episodes_between_training") or 20
    workers = _job_workers(request, body.workers if body else None, episodes)
    owner = service.owners()[name]
    check_quota(request, user, "resume", {"max_time_s": max_time})
    job = service.submit("resume", name, owner, {**({"max_time_s": max_time} if max_time else {}), **workers})
    return {**service.describe(name, viewer=user), "job": job.to_dict()}


def _default_resume_time(request: Request, name: str, saved: dict) -> float | None:
    """A resume's budget when the request names none: after an interruption (a server stop, a crash
    of the server) only the time the interrupted job had left; else the saved max time. Capped by the
    console's limit, and named in the job so that its wall-clock limit follows from it."""
    from laplab.console.service import TRAIN_KINDS, time_left_s
    jobs = _service(request).store.jobs(model=name, kind=TRAIN_KINDS)
    if jobs and jobs[-1].status == "interrupted":
        left = time_left_s(jobs[-1])
        if left is not None and left < 1.0:
            raise HTTPException(409, {"message": f"{name!r} had used its whole max time when it was interrupted: "
                                                 "name a new max_time_s to train it further", "field": "max_time_s"})
        if left is not None:
            return min(left, request.app.state.limits.max_time_s)
    budget = saved.get("max_time_s")
    return None if budget is None else min(float(budget), request.app.state.limits.max_time_s)


@router.post("/models/{name}/clone", status_code=201)
async def clone_model(name: str, body: CloneModel, request: Request, user: User = Depends(current_user)) -> dict:
    name = own_model(request, name, user)
    service = _service(request)
    if service.active_job(name) is not None:
        raise HTTPException(409, f"{name!r} is training: clone it when its training has ended")
    if not (models_dir() / name / "laplab.json").exists():
        raise HTTPException(409, f"{name!r} has no laplab training configuration to clone from")
    check_max_time(request, body.max_time_s)
    key = _name_free(request, body.name, user)
    source_config = json.loads((models_dir() / name / "laplab.json").read_text())
    if body.model_metadata is not None:
        from laplab.env.metadata import metadata_from_dict
        try:
            old = metadata_from_dict(source_config["model_metadata"], "source")
            new = metadata_from_dict(body.model_metadata, "model_metadata")
        except _input_errors() as exc:
            raise bad_request(str(exc), "model_metadata") from None
        for what in ("action_space", "sensors", "neural_network", "training_algorithm"):
            if getattr(old, what) != getattr(new, what):
                raise bad_request(f"a clone keeps its source's {what.replace('_', ' ')}: {name!r} has "
                                  f"{getattr(old, what)}, the request asks for {getattr(new, what)}", "model_metadata")
    values = {"track": body.track or source_config.get("track"), "model_metadata": source_config["model_metadata"],
              "hyperparameters": body.hyperparameters or source_config.get("hyperparameters"),
              "max_time_s": body.max_time_s, "max_episodes": body.max_episodes}
    train, config = _check_train_inputs({**values, "workers": body.workers})
    workers = _job_workers(request, body.workers, config.hyper().num_episodes_between_training)
    check_quota(request, user, "clone", values)
    source = body.reward_function
    if source is None:
        source = (models_dir() / name / "reward_function.py").read_text()
    await _validate_and_claim(request, user, key, body, source, values["track"], values["model_metadata"])
    params = {k: v for k, v in train.to_mapping().items() if k in values and k != "model_metadata"}
    job = service.submit("clone", key, user.id, {**params, **workers, "source": name}, reward_source=source)
    return {**service.describe(key, viewer=user), "job": job.to_dict()}


@router.delete("/models/{name}")
def delete_model(name: str, request: Request, user: User = Depends(current_user)) -> dict:
    shown, name = name, own_model(request, name, user)
    service = _service(request)
    if service.active_job(name) is not None:
        raise HTTPException(409, f"{shown!r} has a job queued or running: stop it before deleting the model")
    service.delete_model(name)
    return {"deleted": shown}
