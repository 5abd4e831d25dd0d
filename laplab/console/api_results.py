"""The console's JSON API, second half: evaluations, live events, downloads and imports, reward
validation, the leaderboard and tracks (see :mod:`laplab.console.api` for the conventions)."""

from __future__ import annotations

import asyncio
import shutil
import time

from fastapi import APIRouter, Depends, File, Form, HTTPException, Query, Request, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, StreamingResponse
from starlette.background import BackgroundTask

from laplab.console import exports
from laplab.console.api import (_field_of, _input_errors, _service, _validate_reward, bad_request, check_track_name,
                                own_model)
from laplab.console.auth import current_user
from laplab.console.bodies import Evaluate, ValidateReward
from laplab.console.events import sse_message
from laplab.jobs.db import User
from laplab.jobs.runner import job_folder, models_dir

router = APIRouter(prefix="/api")
DISCONNECT_CHECK_S = 1.0  # how often a quiet stream checks that its client is still there
KEEP_ALIVE_S = 15.0


@router.post("/models/{name}/evaluations", status_code=202)
def start_evaluation(name: str, body: Evaluate, request: Request, user: User = Depends(current_user)) -> dict:
    name = own_model(request, name, user)
    service = _service(request)
    from laplab.evaluate.trials import EvaluateRequest
    check_track_name(body.track)
    try:
        settings = EvaluateRequest.from_mapping(body.model_dump())
        if settings.domain_randomization:  # refused now for a model without a camera, not when the job runs
            from laplab.env.metadata import load_model_metadata
            from laplab.evaluate.trials import randomization_for
            metadata = models_dir() / name / "model" / "model_metadata.json"
            if metadata.is_file():
                randomization_for(settings, load_model_metadata(metadata).sensors)
        if body.track:
            from laplab.track.registry import load_track
            load_track(body.track.removesuffix("@reversed"))
    except _input_errors() as exc:  # its field is the request's (no message is looked into)
        raise bad_request(str(exc), _field_of(exc)) from None
    active = service.active_job(name)
    if active is not None and active.kind != "evaluate":
        raise HTTPException(409, f"{name!r} is training: evaluate it when its training has ended")
    if not (models_dir() / name / "model" / "deepracer_checkpoints.json").exists():
        raise HTTPException(409, f"{name!r} has no checkpoint to evaluate yet")
    from laplab.console.roles import check_quota
    check_quota(request, user, "evaluate", body.model_dump())
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
    name = own_model(request, name, user)
    return [_evaluation(j) for j in _service(request).store.jobs(model=name, kind=("evaluate",))]


@router.get("/models/{name}/evaluations/{job_id}")
def get_evaluation(name: str, job_id: int, request: Request, user: User = Depends(current_user)) -> dict:
    name = own_model(request, name, user)
    job = _service(request).store.job(job_id)
    if job is None or job.model != name or job.kind != "evaluate":
        raise HTTPException(404, f"no evaluation {job_id} of {name!r}")
    return _evaluation(job)


@router.get("/models/{name}/video/{stamp}")
def evaluation_video(name: str, stamp: str, request: Request, user: User = Depends(current_user)):
    name = own_model(request, name, user)
    from laplab.store.layout import ModelFolder
    try:
        folder = ModelFolder(models_dir() / name).evaluation_dir(stamp)
    except ValueError as exc:
        raise HTTPException(404, str(exc)) from None
    videos = sorted(folder.glob("*.mp4")) + sorted(folder.glob("*.gif"))
    if not videos:
        raise HTTPException(404, "this evaluation has no video")
    return FileResponse(videos[0])


@router.get("/models/{name}/events")
async def model_events(name: str, request: Request, user: User = Depends(current_user)) -> StreamingResponse:
    """Server-sent events: ``status`` on each status change, ``iteration`` per training iteration,
    ``poses`` (the cars on the track, and a race's bots) up to 15 times a second while a job drives,
    ``obstacles`` (a race's boxes) when the stream opens and when they change."""
    name = own_model(request, name, user)
    service = _service(request)
    stream = service.hub.stream(name)

    async def generate():
        wake = asyncio.Event()
        stream.waiters.add(wake)
        try:
            seen, poses_seen, obstacles_seen = stream.seq, stream.poses_seq, 0  # the race's boxes: sent at once
            model = await run_in_threadpool(service.describe, name)
            yield sse_message("status", {"status": model["status"], "progress": model["progress"]})
            last_sent = last_check = time.monotonic()
            while True:
                wake.clear()  # before reading: news published from here on sets it again
                if stream.seq > seen:
                    for seq, _, _, text in list(stream.events):
                        if seq > seen:
                            yield text
                    seen = stream.seq
                    last_sent = time.monotonic()
                if stream.obstacles_seq > obstacles_seen:
                    obstacles_seen = stream.obstacles_seq
                    yield stream.obstacles_text
                    last_sent = time.monotonic()
                if stream.poses_seq > poses_seen and stream.poses is not None:
                    poses_seen = stream.poses_seq
                    yield stream.poses_text
                    last_sent = time.monotonic()
                try:
                    await asyncio.wait_for(wake.wait(), DISCONNECT_CHECK_S)
                except asyncio.TimeoutError:
                    pass
                now = time.monotonic()
                if now - last_check >= DISCONNECT_CHECK_S:
                    last_check = now
                    if await request.is_disconnected():
                        return
                    if now - last_sent > KEEP_ALIVE_S:
                        last_sent = now
                        yield ": keep-alive\n\n"
        finally:
            stream.waiters.discard(wake)

    return StreamingResponse(generate(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})


@router.get("/models/{name}/download")
async def download(name: str, request: Request, format: str = Query("tar", pattern="^(tar|onnx|car|console)$"),
                   user: User = Depends(current_user)):
    """``tar`` (laplab's archive) and ``onnx`` are made on the spot; ``car`` and ``console`` (TensorFlow)
    are built by export jobs (see :mod:`laplab.console.api_exports`): this serves the newest one."""
    name = own_model(request, name, user)
    if format in ("car", "console"):
        from laplab.console.api_exports import latest_export
        return latest_export(request, name, format)
    if not (models_dir() / name / "model" / "deepracer_checkpoints.json").exists():
        raise HTTPException(409, f"{name!r} has no checkpoint to download yet")
    try:
        path, folder = await run_in_threadpool(exports.export, name, format)
    except exports.ExportError as exc:
        raise bad_request(str(exc)) from None
    suffix = ".tar.gz" if format == "tar" else "-onnx.tar.gz"
    return FileResponse(path, media_type="application/gzip", filename=f"{name}{suffix}",
                        background=BackgroundTask(shutil.rmtree, folder, ignore_errors=True))


@router.post("/models/import", status_code=201)
async def import_model(request: Request, file: UploadFile = File(...), name: str | None = Form(None),
                       user: User = Depends(current_user)) -> dict:
    service = _service(request)
    try:
        imported = await run_in_threadpool(exports.import_archive, file.file, name or _stem(file.filename), service, user,
                                            file.filename)
    except exports.ExportError as exc:
        raise bad_request(str(exc), "file") from None
    service.models_changed()
    return service.describe(imported, viewer=user)


def _stem(filename: str | None) -> str | None:
    """``my-model.tar.gz`` -> ``my-model``: an import's name when the form names none (names are per
    user, so the name is needed before the archive is read)."""
    if not filename:
        return None
    stem = filename.rsplit("/", 1)[-1]
    for suffix in (".tar.gz", ".tgz", ".tar", ".zip"):
        stem = stem.removesuffix(suffix)
    return stem or None


@router.post("/reward/validate")
async def validate_reward(body: ValidateReward, request: Request, user: User = Depends(current_user)) -> dict:
    check_track_name(body.track)
    return await _validate_reward(request, user, body.source, body.track, body.model_metadata, body.race_type)


@router.get("/reward/examples")
def reward_examples(user: User = Depends(current_user)) -> list[dict]:
    from pathlib import Path

    import laplab.reward.examples as examples
    folder = Path(examples.__file__).parent
    return [{"name": p.stem, "source": p.read_text()} for p in sorted(folder.glob("*.py")) if p.stem != "__init__"]


@router.get("/leaderboard")
async def leaderboard_route(request: Request, track: str | None = None, user: User = Depends(current_user)) -> list[dict]:
    """Per track, every user's best evaluated model (average of 3 consecutive laps, best lap, completion);
    racers by their display name (``user``, ``alias``) and avatar (``initials``, ``colour``), never
    their login name."""
    service = _service(request)
    from laplab.evaluate.leaderboard import leaderboard
    try:
        boards = await run_in_threadpool(leaderboard, track, models_dir())
    except _input_errors() as exc:
        raise bad_request(str(exc), "track") from None
    owners = service.owners()
    from laplab.console.roles import accounts
    profiles = accounts(request).profiles()  # racers by their display names, as the race boards show them
    out = []
    for board_track, entries in boards.items():
        rows, seen = [], set()
        for entry in entries:
            owner = owners.get(entry.model)
            if owner is None or owner in seen:
                continue
            seen.add(owner)
            profile = profiles.get(owner)
            shown = profile.to_dict() if profile else {"alias": "?", "initials": "?", "colour": "#888", "country": ""}
            row = {**entry.to_dict(), "rank": len(rows) + 1, "user": shown["alias"], "alias": shown["alias"],
                   "initials": shown["initials"], "colour": shown["colour"], "country": shown["country"]}
            # the model's name only for its owner (as they name it) and the admin (its key, to open it): names
            # never reveal another user's models; the racer's name and times are the leaderboard
            row["model"] = (service.handle(entry.model, owner, user) if user.is_admin or owner == user.id else None)
            rows.append(row)
        out.append({"track": board_track, "entries": rows})
    return out


@router.get("/tracks")
def tracks(request: Request, user: User = Depends(current_user)) -> list[dict]:
    from laplab.console.tracks import track_list
    return track_list()


@router.get("/tracks/catalogue")
def track_catalogue(user: User = Depends(current_user)) -> list[dict]:
    """DeepRacer's 62 official tracks by display name, each with its simapp route and whether it is
    here (``laplab tracks fetch --names "DISPLAY NAME"`` fetches one)."""
    from laplab.races.catalogue import catalogue
    from laplab.track.registry import available_tracks
    here = {t.name for t in available_tracks()}
    return [{"id": t.id, "name": t.name, "route": t.route, "variants": list(t.variants), "available": t.route in here,
             "directions": ["counterclockwise", "clockwise"], "fetch": f'laplab tracks fetch --names "{t.name}"'}
            for t in catalogue()]


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


@router.get("/models/{name}/camera.png")
def camera_png(name: str, request: Request, user: User = Depends(current_user)):
    """The newest camera frame of a camera model's running (or last) training job."""
    name = own_model(request, name, user)
    for job in reversed(_service(request).store.jobs(model=name)):
        path = job_folder(job.id) / "camera.png"
        if path.exists():
            return FileResponse(path, media_type="image/png", headers={"Cache-Control": "no-store"})
    raise HTTPException(404, f"{name!r} has no camera frame (not a camera model, or not trained here)")


@router.get("/models/{name}/log")
def job_log(name: str, request: Request, user: User = Depends(current_user)) -> dict:
    name = own_model(request, name, user)
    jobs = _service(request).store.jobs(model=name)
    if not jobs:
        return {"log": ""}
    path = job_folder(jobs[-1].id) / "log.txt"
    text = path.read_text(errors="replace")[-20_000:] if path.exists() else ""
    return {"job": jobs[-1].id, "log": text}
