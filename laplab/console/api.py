"""The console's JSON API (``/api/...``); the pages use it, so do scripts and tests.

Every route but ``/api/health`` needs a user (see :mod:`laplab.console.auth`). A user sees and
changes only their own models (the admin sees all); the leaderboard shows everyone's. Bad input
gets a 400 (or FastAPI's 422 for a malformed body) whose ``detail`` is laplab's own message.
"""

from __future__ import annotations

import asyncio
import json
import math
import time
from typing import Any

from fastapi import APIRouter, Depends, File, Form, HTTPException, Query, Request, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, StreamingResponse
from pydantic import BaseModel, ConfigDict, Field
from starlette.background import BackgroundTask

from laplab.console import exports
from laplab.console.auth import current_user
from laplab.jobs.db import StoreError, User
from laplab.jobs.runner import job_folder, models_dir

router = APIRouter(prefix="/api")
POSES_INTERVAL_S = 1.0 / 15.0


class CreateModel(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str
    description: str = Field("", max_length=255)
    track: str | None = None
    reward_function: str | None = Field(None, max_length=100_000)
    model_metadata: dict | None = None
    hyperparameters: dict | None = None
    max_time_s: float = 600.0
    max_episodes: int | None = None
    seed: int = 0


class CloneModel(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str
    description: str = Field("", max_length=255)
    track: str | None = None
    reward_function: str | None = Field(None, max_length=100_000)
    model_metadata: dict | None = None
    hyperparameters: dict | None = None
    max_time_s: float = 600.0
    max_episodes: int | None = None


class Resume(BaseModel):
    model_config = ConfigDict(extra="forbid")
    max_time_s: float | None = None


class Evaluate(BaseModel):
    model_config = ConfigDict(extra="forbid")
    track: str | None = None
    trials: int = 3
    checkpoint: str = "best"
    off_track_penalty: float = 2.0
    crash_penalty: float = 5.0
    resets: int | None = None
    continuous: bool = False
    max_trial_time: float = 600.0
    video: bool = False


class ValidateReward(BaseModel):
    model_config = ConfigDict(extra="forbid")
    source: str = Field(max_length=100_000)
    track: str | None = None
    model_metadata: dict | None = None


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
    from laplab.agents.hyperparameters import HyperparameterError
    from laplab.env.action_space import ActionSpaceError
    from laplab.env.metadata import MetadataError
    from laplab.store.layout import ModelNameError
    from laplab.track.geometry import TrackError
    for kind, name in ((HyperparameterError, "hyperparameters"), (ActionSpaceError, "model_metadata"),
                       (MetadataError, "model_metadata"), (ModelNameError, "name"), (TrackError, "track")):
        if isinstance(exc, kind):
            return name
    return None


def own_model(request: Request, name: str, user: User) -> None:
    """404 unless ``name`` exists and ``user`` may see it (other users' models do not exist for you)."""
    if not _service(request).can_see(user, name):
        raise HTTPException(404, f"no model named {name!r} among your models")


def _check_train_inputs(values: dict) -> None:
    """Build the TrainConfig the worker will build (every validator of the CLI), and load the track."""
    from dataclasses import replace

    from laplab.track.registry import load_track
    from laplab.train.config import TrainConfig
    try:
        config = replace(TrainConfig(), **{k: v for k, v in values.items() if v is not None})
        load_track(config.track)
    except _input_errors() as exc:
        raise bad_request(str(exc), _field_of(exc) or ("max_time_s" if "max time" in str(exc) else None)) from None
    except (TypeError, ValueError) as exc:
        raise bad_request(str(exc)) from None


async def _validate_reward(request: Request, user: User, source: str, track: str | None, metadata: dict | None) -> dict:
    from laplab.jobs.validate import validate_confined
    return await run_in_threadpool(validate_confined, source, track, metadata, user.id,
                                   request.app.state.sandbox)


def _name_free(request: Request, name: str) -> None:
    from laplab.store.layout import ModelNameError, validate_model_name
    try:
        validate_model_name(name)
    except ModelNameError as exc:
        raise bad_request(str(exc), "name") from None
    if name in _service(request).owners() or (models_dir() / name).exists():
        raise HTTPException(409, {"message": f"a model named {name!r} already exists; models are immutable: "
                                             "pick another name or clone it", "field": "name"})


@router.get("/health", tags=["console"])
def health() -> dict:
    return {"ok": True}


@router.get("/me")
def me(user: User = Depends(current_user)) -> dict:
    return {"name": user.name, "admin": user.is_admin}


@router.get("/models")
def list_models_route(request: Request, user: User = Depends(current_user)) -> list[dict]:
    return _service(request).visible_models(user)


@router.post("/models", status_code=201)
async def create_model(body: CreateModel, request: Request, user: User = Depends(current_user)) -> dict:
    service = _service(request)
    _name_free(request, body.name)
    values = {"track": body.track, "model_metadata": body.model_metadata, "hyperparameters": body.hyperparameters,
              "max_time_s": body.max_time_s, "max_episodes": body.max_episodes, "seed": body.seed}
    _check_train_inputs(values)
    if body.reward_function is not None:
        answer = await _validate_reward(request, user, body.reward_function, body.track, body.model_metadata)
        if not answer["ok"]:
            first = answer["errors"][0]
            raise bad_request(first["message"], "reward_function", line=first.get("line"), errors=answer["errors"])
    try:
        service.store.claim_model(body.name, user.id, body.description)
    except StoreError as exc:
        raise HTTPException(409, {"message": str(exc), "field": "name"}) from None
    job = service.submit("train", body.name, user.id, {k: v for k, v in values.items() if v is not None},
                         reward_source=body.reward_function)
    return {**service.describe(body.name), "job": job.to_dict()}


@router.get("/models/{name}")
def get_model(name: str, request: Request, user: User = Depends(current_user)) -> dict:
    own_model(request, name, user)
    service = _service(request)
    model = service.describe(name)
    model["iterations"] = service.catalog.iterations(name)
    model["evaluation_jobs"] = [j.to_dict() for j in service.store.jobs(model=name, kind=("evaluate",))]
    folder = models_dir() / name
    model["reward_function"] = (folder / "reward_function.py").read_text() if (folder / "reward_function.py").exists() else None
    config = folder / "laplab.json"
    model["config"] = json.loads(config.read_text()) if config.exists() else None
    return model


@router.post("/models/{name}/stop")
def stop_model(name: str, request: Request, user: User = Depends(current_user)) -> dict:
    own_model(request, name, user)
    service = _service(request)
    job = service.active_job(name)
    if job is None or job.kind == "evaluate":
        raise HTTPException(409, f"{name!r} is not training")
    service.stop(job)
    return service.describe(name)


@router.post("/models/{name}/resume", status_code=202)
def resume_model(name: str, request: Request, body: Resume | None = None, user: User = Depends(current_user)) -> dict:
    own_model(request, name, user)
    service = _service(request)
    if service.active_job(name) is not None:
        raise HTTPException(409, f"{name!r} already has a job queued or running")
    if not (models_dir() / name / "laplab.json").exists():
        raise HTTPException(409, f"{name!r} has no training to resume")
    max_time = body.max_time_s if body and body.max_time_s else None
    if max_time is not None and not (math.isfinite(max_time) and max_time > 0):
        raise bad_request(f"max time must be a positive number of seconds, got {max_time!r}", "max_time_s")
    owner = service.owners()[name]
    job = service.submit("resume", name, owner, {"max_time_s": max_time} if max_time else {})
    return {**service.describe(name), "job": job.to_dict()}


@router.post("/models/{name}/clone", status_code=201)
async def clone_model(name: str, body: CloneModel, request: Request, user: User = Depends(current_user)) -> dict:
    own_model(request, name, user)
    service = _service(request)
    if service.active_job(name) is not None:
        raise HTTPException(409, f"{name!r} is training: clone it when its training has ended")
    if not (models_dir() / name / "laplab.json").exists():
        raise HTTPException(409, f"{name!r} has no laplab training configuration to clone from")
    _name_free(request, body.name)
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
    _check_train_inputs(values)
    source = body.reward_function
    if source is None:
        source = (models_dir() / name / "reward_function.py").read_text()
    answer = await _validate_reward(request, user, source, values["track"], values["model_metadata"])
    if not answer["ok"]:
        first = answer["errors"][0]
        raise bad_request(first["message"], "reward_function", line=first.get("line"), errors=answer["errors"])
    try:
        service.store.claim_model(body.name, user.id, body.description)
    except StoreError as exc:
        raise HTTPException(409, {"message": str(exc), "field": "name"}) from None
    params = {k: v for k, v in values.items() if v is not None and k != "model_metadata"}
    job = service.submit("clone", body.name, user.id, {**params, "source": name}, reward_source=source)
    return {**service.describe(body.name), "job": job.to_dict()}


@router.delete("/models/{name}")
def delete_model(name: str, request: Request, user: User = Depends(current_user)) -> dict:
    own_model(request, name, user)
    service = _service(request)
    if service.active_job(name) is not None:
        raise HTTPException(409, f"{name!r} has a job queued or running: stop it before deleting the model")
    service.delete_model(name)
    return {"deleted": name}


@router.post("/models/{name}/evaluations", status_code=202)
def start_evaluation(name: str, body: Evaluate, request: Request, user: User = Depends(current_user)) -> dict:
    own_model(request, name, user)
    service = _service(request)
    from laplab.evaluate.trials import EvaluationError, EvaluationSettings
    try:
        EvaluationSettings(**body.model_dump())
        if body.track:
            from laplab.track.registry import load_track
            load_track(body.track.removesuffix("@reversed"))
    except _input_errors() as exc:
        raise bad_request(str(exc), _field_of(exc) or ("trials" if "trials" in str(exc) else None)) from None
    except EvaluationError as exc:
        raise bad_request(str(exc)) from None
    active = service.active_job(name)
    if active is not None and active.kind != "evaluate":
        raise HTTPException(409, f"{name!r} is training: evaluate it when its training has ended")
    if not (models_dir() / name / "model" / "deepracer_checkpoints.json").exists():
        raise HTTPException(409, f"{name!r} has no checkpoint to evaluate yet")
    job = service.submit("evaluate", name, service.owners()[name], body.model_dump())
    return {"id": job.id, "status": job.status}


def _evaluation(job) -> dict:
    from laplab.evaluate.trials import read_evaluation_summary
    from laplab.store.layout import ModelFolder
    status = {"queued": "queued", "running": "running", "stopping": "running", "done": "done"}.get(job.status, "failed")
    out = {"id": job.id, "status": status, "settings": job.params, "created": job.created, "error": job.error,
           "trials": [], "summary": None, "stamp": None}
    stamp = (job.result or {}).get("stamp")
    if stamp:
        document = read_evaluation_summary(ModelFolder(models_dir() / job.model), stamp)
        if document:
            trials = [{**t, "progress": t.get("completion")} for t in document.get("trials", [])]
            out.update(stamp=stamp, trials=trials, summary=document.get("summary"),
                       track=document.get("track", {}).get("name"), video=document.get("video"))
    return out


@router.get("/models/{name}/evaluations")
def list_evaluations(name: str, request: Request, user: User = Depends(current_user)) -> list[dict]:
    own_model(request, name, user)
    return [_evaluation(j) for j in _service(request).store.jobs(model=name, kind=("evaluate",))]


@router.get("/models/{name}/evaluations/{job_id}")
def get_evaluation(name: str, job_id: int, request: Request, user: User = Depends(current_user)) -> dict:
    own_model(request, name, user)
    job = _service(request).store.job(job_id)
    if job is None or job.model != name or job.kind != "evaluate":
        raise HTTPException(404, f"no evaluation {job_id} of {name!r}")
    return _evaluation(job)


@router.get("/models/{name}/video/{stamp}")
def evaluation_video(name: str, stamp: str, request: Request, user: User = Depends(current_user)):
    own_model(request, name, user)
    from laplab.store.layout import ModelFolder
    try:
        folder = ModelFolder(models_dir() / name).evaluation_dir(stamp)
    except ValueError as exc:
        raise HTTPException(404, str(exc)) from None
    videos = sorted(folder.glob("*.mp4")) + sorted(folder.glob("*.gif"))
    if not videos:
        raise HTTPException(404, "this evaluation has no video")
    return FileResponse(videos[0])


def _sse(kind: str, data: dict, event_id: int | None = None) -> str:
    head = f"id: {event_id}\n" if event_id is not None else ""
    return f"{head}event: {kind}\ndata: {json.dumps(data)}\n\n"


@router.get("/models/{name}/events")
async def model_events(name: str, request: Request, user: User = Depends(current_user)) -> StreamingResponse:
    """Server-sent events: ``status`` on each status change, ``iteration`` per training iteration,
    ``poses`` (the cars on the track) up to 15 times a second while a job drives."""
    own_model(request, name, user)
    service = _service(request)
    stream = service.hub.stream(name)

    async def generate():
        seen, poses_seen = stream.seq, stream.poses_seq
        model = service.describe(name)
        yield _sse("status", {"status": model["status"], "progress": model["progress"]})
        last_check = last_sent = time.monotonic()
        while True:
            if stream.seq > seen:
                for seq, kind, data in list(stream.events):
                    if seq > seen:
                        yield _sse(kind, data, seq)
                seen = stream.seq
            if stream.poses_seq > poses_seen and stream.poses is not None:
                poses_seen = stream.poses_seq
                yield _sse("poses", stream.poses)
            now = time.monotonic()
            if now - last_check > 1.0:
                last_check = now
                if await request.is_disconnected():
                    return
                if now - last_sent > 15.0:
                    last_sent = now
                    yield ": keep-alive\n\n"
            await asyncio.sleep(POSES_INTERVAL_S / 2)

    return StreamingResponse(generate(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})


@router.get("/models/{name}/download")
async def download(name: str, request: Request, format: str = Query("tar", pattern="^(tar|onnx)$"),
                   user: User = Depends(current_user)):
    own_model(request, name, user)
    if not (models_dir() / name / "model" / "deepracer_checkpoints.json").exists():
        raise HTTPException(409, f"{name!r} has no checkpoint to download yet")
    try:
        path, folder = await run_in_threadpool(exports.export, name, format)
    except exports.ExportError as exc:
        raise bad_request(str(exc)) from None
    import shutil
    suffix = ".tar.gz" if format == "tar" else "-onnx.tar.gz"
    return FileResponse(path, media_type="application/gzip", filename=f"{name}{suffix}",
                        background=BackgroundTask(shutil.rmtree, folder, ignore_errors=True))


@router.post("/models/import", status_code=201)
async def import_model(request: Request, file: UploadFile = File(...), name: str | None = Form(None),
                       user: User = Depends(current_user)) -> dict:
    service = _service(request)
    try:
        imported = await run_in_threadpool(exports.import_archive, file.file, name, service, user)
    except exports.ExportError as exc:
        raise bad_request(str(exc), "file") from None
    return service.describe(imported)


@router.post("/reward/validate")
async def validate_reward(body: ValidateReward, request: Request, user: User = Depends(current_user)) -> dict:
    if body.track:
        from laplab.track.registry import load_track
        try:
            load_track(body.track)
        except _input_errors() as exc:
            raise bad_request(str(exc), "track") from None
    return await _validate_reward(request, user, body.source, body.track, body.model_metadata)


@router.get("/reward/examples")
def reward_examples(user: User = Depends(current_user)) -> list[dict]:
    from pathlib import Path

    import laplab.reward.examples as examples
    folder = Path(examples.__file__).parent
    return [{"name": p.stem, "source": p.read_text()} for p in sorted(folder.glob("*.py")) if p.stem != "__init__"]


@router.get("/leaderboard")
async def leaderboard_route(request: Request, track: str | None = None, user: User = Depends(current_user)) -> list[dict]:
    """Per track, every user's best evaluated model (average of 3 consecutive laps, best lap, completion)."""
    service = _service(request)
    from laplab.evaluate.leaderboard import leaderboard
    try:
        boards = await run_in_threadpool(leaderboard, track, models_dir())
    except _input_errors() as exc:
        raise bad_request(str(exc), "track") from None
    owners = service.owners()
    names = {u.id: u.name for u in service.store.users()}
    out = []
    for board_track, entries in boards.items():
        rows, seen = [], set()
        for entry in entries:
            owner = owners.get(entry.model)
            if owner is None or owner in seen:
                continue
            seen.add(owner)
            rows.append({**entry.to_dict(), "rank": len(rows) + 1, "user": names.get(owner)})
        out.append({"track": board_track, "entries": rows})
    return out


@router.get("/tracks")
def tracks(request: Request, user: User = Depends(current_user)) -> list[dict]:
    from laplab.console.tracks import track_list
    return track_list()


@router.get("/tracks/{name}/outline")
def track_outline(name: str, user: User = Depends(current_user)) -> dict:
    from laplab.console.tracks import outline
    try:
        return outline(name)
    except _input_errors() as exc:
        raise HTTPException(404, str(exc)) from None


@router.get("/tracks/{name}/picture.png")
async def track_picture(name: str, user: User = Depends(current_user)):
    from laplab.console.tracks import picture
    try:
        path = await run_in_threadpool(picture, name)
    except _input_errors() as exc:
        raise HTTPException(404, str(exc)) from None
    return FileResponse(path, media_type="image/png", headers={"Cache-Control": "max-age=3600"})


@router.get("/models/{name}/log")
def job_log(name: str, request: Request, user: User = Depends(current_user)) -> dict:
    own_model(request, name, user)
    jobs = _service(request).store.jobs(model=name)
    if not jobs:
        return {"log": ""}
    path = job_folder(jobs[-1].id) / "log.txt"
    text = path.read_text(errors="replace")[-20_000:] if path.exists() else ""
    return {"job": jobs[-1].id, "log": text}
