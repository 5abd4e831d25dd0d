"""Head-to-model races from a model's page ("Race another model"): the same race as ``laplab race``,
run as a confined ``duel`` job (:class:`~laplab.train.request.RaceRequest`).

- ``GET /api/models/{name}/opponents``: the models the asker may race ``name`` against, each with the
  reason it cannot be raced now (no checkpoint, another physics version), and the form's defaults.
- ``POST /api/models/{name}/duels {opponent, track, laps, max_time_s, checkpoint, video}`` queues one.
- ``GET /api/models/{name}/duels`` and ``.../duels/{id}``: the races and their results (each car's
  laps, times, crashes, off-tracks, penalty, finish position); ``.../duels/{id}/picture`` the top-down
  picture of both cars and their paths, ``.../duels/{id}/video`` the video when one was asked for.

Who may race what: a racer races their own models against their own models only; another user's
models are private, so naming one is refused with the rule, the same way whether it exists or not
(nothing is learnt about it). Admins and race facilitators may pick any model as the opponent. A race
is shown only to the user who started it (and to admins): its result tells how the opponent drives.
The job mounts the home model and the opponent read-only and nothing else of anyone's
(:func:`laplab.jobs.runner.job_mounts`).
"""

from __future__ import annotations

import json

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.responses import FileResponse
from pydantic import BaseModel, ConfigDict, Field

from laplab.console.api import _service, bad_request, check_track_name, own_model
from laplab.console.auth import current_user
from laplab.console.outcomes import without_paths
from laplab.evaluate.race_run import PICTURE_FILE, RACE_FILE, model_cars
from laplab.jobs.db import Job, User
from laplab.jobs.runner import job_folder, models_dir
from laplab.train.request import RACE_LAPS, RACE_MAX_TIME_S, RaceRequest

router = APIRouter(prefix="/api")
DUEL_STATUS = {"queued": "queued", "running": "running", "stopping": "running", "done": "done"}
PRIVATE_RULE = ("you may race {home!r} only against your own models, and you have no model named {opponent!r}: "
                "another user's models are private to them (admins and race facilitators may race any model)")


class Duel(BaseModel):
    """A head-to-model race: RaceRequest's fields and defaults, the opponent named as the asker names it."""
    model_config = ConfigDict(extra="forbid")
    opponent: str = Field(min_length=1, max_length=200)
    track: str | None = Field(None, max_length=200)
    laps: int = Field(1, ge=RACE_LAPS[0], le=RACE_LAPS[1])
    max_time_s: float = Field(RaceRequest.max_time_s, ge=RACE_MAX_TIME_S[0], le=RACE_MAX_TIME_S[1])
    checkpoint: str = Field(RaceRequest.checkpoint, max_length=20)
    video: bool = False


def _has_checkpoint(key: str) -> bool:
    return (models_dir() / key / "model" / "deepracer_checkpoints.json").exists()


def _may_race_anything(user: User) -> bool:
    return user.runs_races  # admins and race facilitators


def opponent_key(request: Request, user: User, home: str, opponent: str) -> str:
    """The key of the model ``user`` names ``opponent``: one of their own, or for admins and race
    facilitators any model (by its key). A racer naming anything else gets a 403 with the rule,
    worded alike whether that model exists or not."""
    service = _service(request)
    key = service.resolve(user, opponent)
    if key is None and _may_race_anything(user) and opponent in service.owners():
        key = opponent
    if key is None:
        if _may_race_anything(user):
            raise HTTPException(404, {"message": f"no model named {opponent!r}", "field": "opponent"})
        raise HTTPException(403, {"message": PRIVATE_RULE.format(home=home, opponent=opponent), "field": "opponent"})
    return key


def _physics_refusal(names: list[str], keys: list[str]) -> str | None:
    """``laplab race``'s paragraph when the models drive different cars (None: they race)."""
    from laplab.errors import UserError
    from laplab.evaluate.race import check_same_car
    try:
        check_same_car(names, model_cars(keys, models_dir()))
    except UserError as exc:
        return without_paths(str(exc))
    except (OSError, ValueError, TypeError):
        return "its laplab.json cannot be read: it cannot race"
    return None


def _home_track(key: str) -> str | None:
    """The model's training track as a race's track name (``name@reversed`` when it drove it reversed)."""
    try:
        config = json.loads((models_dir() / key / "laplab.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    track = config.get("track")
    return f"{track}@reversed" if track and config.get("reverse") else track


@router.get("/models/{name}/opponents")
def list_opponents(name: str, request: Request, user: User = Depends(current_user)) -> dict:
    shown, key = name, own_model(request, name, user)
    service = _service(request)
    owners = service.owners()
    out = []
    for other, owner in sorted(owners.items()):
        if other == key or not (_may_race_anything(user) or owner == user.id):
            continue
        handle = service.handle(other, owner, user)
        refused = None if _has_checkpoint(other) else "it has no checkpoint yet"
        if refused is None:
            refused = _physics_refusal([shown, handle], [key, other])
        account = service.store.user_by_id(owner, enabled=False)
        out.append({"name": handle, "owner": account.name if account else None, "ready": refused is None,
                    "refused": refused})
    return {"track": _home_track(key), "laps": 1, "max_time_s": RaceRequest.max_time_s, "opponents": out,
            "rule": None if _may_race_anything(user) else "You race your own models: other users' models are private"}


@router.post("/models/{name}/duels", status_code=202)
def start_duel(name: str, body: Duel, request: Request, user: User = Depends(current_user)) -> dict:
    shown, key = name, own_model(request, name, user)
    service = _service(request)
    rival = opponent_key(request, user, shown, body.opponent)
    if rival == key:
        raise bad_request(f"{shown!r} cannot race itself: pick another model", "opponent")
    check_track_name(body.track)
    from laplab.errors import UserError
    try:
        race = RaceRequest(models=(key, rival), track=body.track or _home_track(key), laps=body.laps,
                           max_time_s=body.max_time_s, checkpoint=body.checkpoint, video=body.video)
        if race.track:
            from laplab.track.registry import load_track
            load_track(race.track)
    except UserError as exc:
        raise bad_request(without_paths(str(exc)), exc.field or "track") from None
    active = service.active_job(key)
    if active is not None and active.kind not in ("evaluate", "export", "duel"):
        raise HTTPException(409, {"message": f"{shown!r} is training: race it when its training has ended"})
    for who, model in ((shown, key), (body.opponent, rival)):
        if not _has_checkpoint(model):
            raise HTTPException(409, {"message": f"{who!r} has no checkpoint to race yet", "field": "opponent"})
    refused = _physics_refusal([shown, body.opponent], [key, rival])
    if refused:
        raise bad_request(refused, "opponent")
    from laplab.console.roles import check_quota
    params = race.to_mapping()
    check_quota(request, user, "duel", params)
    job = service.submit("duel", key, user.id, params)
    return duel_view(request, job, user)


def _duel_job(request: Request, key: str, job_id: int, user: User) -> Job:
    job = _service(request).store.job(job_id)
    if job is None or job.model != key or job.kind != "duel" or not (user.is_admin or job.owner == user.id):
        raise HTTPException(404, {"message": f"no race {job_id} of this model that you started"})
    return job


def duel_view(request: Request, job: Job, viewer: User) -> dict:
    """A race job as ``viewer`` sees it: the models by the names they know them by, each car's result
    in finishing order (``car``: its colour's index in the picture), the picture's and video's URLs."""
    from laplab.sensors.render import DEFAULT_RENDER
    service = _service(request)
    owners = service.owners()
    keys = list(job.params.get("models", []))
    names = {k: service.handle(k, owners.get(k), viewer) for k in keys}
    home = names.get(job.model, job.model)
    palette = DEFAULT_RENDER.car_colors
    colours = ["#" + "".join(f"{c:02x}" for c in palette[i % len(palette)]) for i in range(len(keys))]
    out = {"id": job.id, "status": DUEL_STATUS.get(job.status, "failed"), "models": [names[k] for k in keys],
           "colours": colours, "track": job.params.get("track"), "laps": job.params.get("laps"),
           "max_time_s": job.params.get("max_time_s"), "created": job.created, "finished": job.finished,
           "error": job.error, "racers": [], "duration": None, "picture": None, "video": None,
           "stopped": bool((job.result or {}).get("stop_reason") == "stopped")}
    document = _race_document(job) if out["status"] == "done" else None
    if document:
        base = f"/api/models/{home}/duels/{job.id}"
        out.update(track=document.get("track"), duration=document.get("duration"),
                   picture=f"{base}/picture", video=f"{base}/video" if document.get("video") else None,
                   racers=[{**r, "name": names.get(r["name"], r["name"]),
                            "car": keys.index(r["name"]) if r["name"] in keys else None}
                           for r in document.get("racers", [])])
    return out


def _race_document(job: Job) -> dict | None:
    try:
        return json.loads((job_folder(job.id) / "race" / RACE_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


@router.get("/models/{name}/duels")
def list_duels(name: str, request: Request, user: User = Depends(current_user)) -> list[dict]:
    key = own_model(request, name, user)
    jobs = _service(request).store.jobs(model=key, kind=("duel",))
    return [duel_view(request, j, user) for j in jobs if user.is_admin or j.owner == user.id]


@router.get("/models/{name}/duels/{job_id}")
def get_duel(name: str, job_id: int, request: Request, user: User = Depends(current_user)) -> dict:
    key = own_model(request, name, user)
    return duel_view(request, _duel_job(request, key, job_id, user), user)


@router.get("/models/{name}/duels/{job_id}/{what}")
def get_duel_file(name: str, job_id: int, what: str, request: Request, user: User = Depends(current_user)):
    key = own_model(request, name, user)
    job = _duel_job(request, key, job_id, user)
    document = _race_document(job) or {}
    file = {"picture": document.get("picture") or PICTURE_FILE, "video": document.get("video")}.get(what)
    path = job_folder(job.id) / "race" / file if file else None
    if path is None or path.name != file or not path.is_file():
        raise HTTPException(404, {"message": f"race {job_id} has no {what}"})
    media = {".png": "image/png", ".mp4": "video/mp4", ".gif": "image/gif"}.get(path.suffix, "application/octet-stream")
    return FileResponse(path, media_type=media)
