"""The JSON API of races (``/api/races``): create, edit, clone, close, delete (admins and race
facilitators, each on their own races; admins on all), join a private race by its code, submit a
model (queues the console's evaluate job under the race's rules), submissions, the leaderboard, its
CSV, and the replay of the newest result for the race board.

Every refusal is one 4xx naming the rule; nothing is written before every check has passed.
A private race does not exist (404) for a racer who has not joined it with its code.
"""

from __future__ import annotations

import time

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, Response
from pydantic import BaseModel, ConfigDict, Field

from laplab.console.auth import current_user
from laplab.console.service import display_name
from laplab.console.roles import accounts, check_quota, race_runner, races, refusal
from laplab.jobs.db import User
from laplab.jobs.runner import models_dir
from laplab.races.results import (ResultCache, board, csv_text, replay, rescoring, stale_submissions,
                                  submission_rows)
from laplab.races.rules import RaceError, RaceSettings, sensor_refusal, window_refusal
from laplab.races.store import Race

router = APIRouter(prefix="/api/races", tags=["races"])


def _race_body() -> type[BaseModel]:
    """The request body of a race: every :class:`RaceSettings` field, derived from the dataclass (so
    the two cannot drift; the dataclass's own checks give the error messages)."""
    from dataclasses import MISSING, fields
    from typing import get_type_hints

    from pydantic import create_model
    hints = get_type_hints(RaceSettings)
    columns = {}
    for f in fields(RaceSettings):
        default = f.default if f.default is not MISSING else (
            f.default_factory() if f.default_factory is not MISSING else ...)
        columns[f.name] = (hints[f.name], default)
    return create_model("RaceBody", __config__=ConfigDict(extra="forbid"), __doc__=RaceSettings.__doc__, **columns)


RaceBody = _race_body()


class Join(BaseModel):
    model_config = ConfigDict(extra="forbid")
    code: str = Field(max_length=64)


class Submit(BaseModel):
    model_config = ConfigDict(extra="forbid")
    model: str = Field(max_length=200, description="your model's name")


def _cache(request: Request) -> ResultCache:
    state = request.app.state
    if getattr(state, "race_results", None) is None:
        state.race_results = ResultCache()
    return state.race_results


def _settings(data: dict) -> RaceSettings:
    from laplab.console.api import check_track_name
    try:
        settings = RaceSettings.from_dict(data)
    except RaceError as exc:
        raise refusal(exc) from None
    check_track_name(settings.track)
    race = settings.race()
    if race is not None:  # as many objects or bots as fit on the track at their minimum distance
        from laplab.sim.race_type import RaceTypeError
        from laplab.track.registry import load_track
        try:
            track = load_track(settings.track)
            race.check_track(track.length, track.name)
        except RaceTypeError as exc:
            raise refusal(RaceError(f"options: {str(exc).replace('--', '')}", field="options")) from None
    return settings


def manages(race: Race, user: User) -> bool:
    return user.is_admin or race.owner == user.id


def visible_race(request: Request, race_id: int, user: User) -> Race:
    """The race, when ``user`` may see it: public races, private ones they joined, own, or any for an admin."""
    race = races(request).race(race_id)
    if race is None or not (not race.settings.private or manages(race, user)
                            or races(request).is_member(race.id, user.id)):
        raise HTTPException(404, {"message": f"no race {race_id} you can see (a private race is joined with its "
                                             "code: POST /api/races/join)"})
    return race


def refuse_unless_manages(race: Race, user: User) -> Race:
    """``race`` when ``user`` may change it (its owner, an admin); 403 naming the rule otherwise."""
    if not manages(race, user):
        raise HTTPException(403, {"message": f"race {race.id} belongs to another facilitator: only its owner or an "
                                             "admin changes it"})
    return race


def managed_race(request: Request, race_id: int, user: User) -> Race:
    """The race, when ``user`` (a race runner: the routes' :data:`race_runner` dependency) may change
    it; 404 when there is none, 403 naming the rule when it is another facilitator's."""
    race = races(request).race(race_id)
    if race is None:
        raise HTTPException(404, {"message": f"no race {race_id}"})
    return refuse_unless_manages(race, user)


def _view(race: Race, user: User, request: Request) -> dict:
    out = race.to_dict(with_code=manages(race, user))
    out["owner_name"] = (request.app.state.store.user_by_id(race.owner, enabled=False) or User(0, "?", False)).name
    out["open_now"] = window_refusal(race.settings, race.closed, time.time()) is None
    driven = race.settings.race()
    out["race_summary"] = driven.summary() if driven is not None else "time trial"  # e.g. "object avoidance: 3 boxes..."
    return out


@router.get("")
def list_races(request: Request, user: User = Depends(current_user)) -> list[dict]:
    joined = races(request).memberships(user.id)
    return [_view(r, user, request) for r in races(request).races()
            if not r.settings.private or manages(r, user) or r.id in joined]


@router.post("", status_code=201)
def create_race(body: RaceBody, request: Request, user: User = Depends(race_runner)) -> dict:
    race = races(request).create(user, _settings(body.model_dump()))
    return _view(race, user, request)


@router.get("/{race_id}")
def get_race(race_id: int, request: Request, user: User = Depends(current_user)) -> dict:
    return _view(visible_race(request, race_id, user), user, request)


@router.put("/{race_id}")
def edit_race(race_id: int, body: RaceBody, request: Request, user: User = Depends(race_runner)) -> dict:
    """Change the race's settings. Its submissions rank under the new rules at once, from the laps they
    drove (:mod:`laplab.races.rescore`); ``rescored`` says which now rank how (and why not)."""
    race = managed_race(request, race_id, user)
    settings = _settings(body.model_dump())
    before = _rows(request, race)
    edited = races(request).update(race.id, settings)
    out = _view(edited, user, request)
    out["rescored"] = rescoring(before, _rows(request, edited))
    return out


@router.post("/{race_id}/clone", status_code=201)
def clone_race(race_id: int, request: Request, user: User = Depends(race_runner)) -> dict:
    """A copy of the race's settings owned by the caller, with a new code and no submissions."""
    race = visible_race(request, race_id, user)
    from dataclasses import replace
    settings = replace(race.settings, name=f"{race.settings.name} (copy)"[:80])
    return _view(races(request).create(user, settings), user, request)


@router.post("/{race_id}/close")
def close_race(race_id: int, request: Request, user: User = Depends(race_runner)) -> dict:
    return _view(races(request).set_closed(managed_race(request, race_id, user).id, True), user, request)


@router.post("/{race_id}/reopen")
def reopen_race(race_id: int, request: Request, user: User = Depends(race_runner)) -> dict:
    return _view(races(request).set_closed(managed_race(request, race_id, user).id, False), user, request)


@router.delete("/{race_id}")
def delete_race(race_id: int, request: Request, user: User = Depends(race_runner)) -> dict:
    """Delete the race and its submissions' records; their evaluations still queued or running stop."""
    race = managed_race(request, race_id, user)
    service = request.app.state.service
    stopped = 0
    for sub in races(request).submissions(race.id):
        job = service.store.job(sub.job_id)
        if job is not None and job.status in ("queued", "running"):
            service.stop(job)
            stopped += 1
    races(request).delete(race.id)
    return {"deleted": race.id, "evaluations_stopped": stopped}


@router.post("/join")
def join_race(body: Join, request: Request, user: User = Depends(current_user)) -> dict:
    race = races(request).by_code(body.code)
    if race is None:
        raise HTTPException(404, {"message": "code: no race has this join code (ask your facilitator for it)",
                                  "field": "code"})
    races(request).join(race.id, user.id)
    return _view(race, user, request)


def _model_sensors(request: Request, key: str) -> tuple[list[str], str]:
    import json
    config = models_dir() / key / "laplab.json"
    saved = json.loads(config.read_text()) if config.is_file() else {}
    described = request.app.state.service.describe(key)
    race_type = saved.get("race_type")  # laplab.json keeps a RaceType's dict (old files: none, a time trial)
    kind = race_type.get("kind") if isinstance(race_type, dict) else race_type
    return list(described.get("sensor") or []), str(kind or "time_trial")


@router.post("/{race_id}/submissions", status_code=202)
def submit(race_id: int, body: Submit, request: Request, user: User = Depends(current_user)) -> dict:
    """Submit one of your models: checks the window, the submission limit, ownership, sensors, race
    type and your quota, then queues its evaluation under the race's rules (consecutive laps, the
    race's car and penalties, a video)."""
    race = visible_race(request, race_id, user)
    if (why := window_refusal(race.settings, race.closed, time.time())) is not None:
        raise HTTPException(409, {"message": why, "field": "window"})
    service = request.app.state.service
    key = service.resolve(user, body.model)
    if key is None or service.owners().get(key) != user.id:
        raise HTTPException(404, {"message": f"model: you have no model named {body.model!r}; a race takes only the "
                                             "submitter's own models", "field": "model"})
    if not (models_dir() / key / "model" / "deepracer_checkpoints.json").exists():
        raise HTTPException(409, {"message": f"model: {body.model!r} has no checkpoint yet: train it first",
                                  "field": "model"})
    active = service.active_job(key)
    if active is not None and active.kind != "evaluate":
        raise HTTPException(409, {"message": f"model: {body.model!r} is training: submit it when its training has "
                                             "ended", "field": "model"})
    sensors, race_type = _model_sensors(request, key)
    if (why := sensor_refusal(race.settings, sensors)) is not None:
        raise HTTPException(400, {"message": why, "field": "model"})
    if race_type != race.settings.race_type:
        raise HTTPException(400, {"message": f"model: {body.model!r} was trained for {race_type}; this race is "
                                             f"{race.settings.race_type}", "field": "model"})
    from laplab.races.catalogue import track_key
    evaluation = race.settings.evaluation_params(track_key(race.settings.track, race.settings.direction))
    check_quota(request, user, "evaluate", evaluation)
    try:
        stale = stale_submissions(race, races(request).submissions(race.id, user.id), service.store)
        sub = races(request).add_submission(race, user, key,
                                            lambda: service.submit("evaluate", key, user.id, evaluation), stale)
    except RaceError as exc:
        raise refusal(exc, 409) from None
    return {"id": sub.id, "race": race.id, "job": sub.job_id, "model": body.model, "state": "queued"}


def _rows(request: Request, race: Race, user_id: int | None = None) -> list[dict]:
    subs = races(request).submissions(race.id, user_id)
    rows = submission_rows(race, subs, request.app.state.store, _cache(request), models_dir())
    profiles = accounts(request).profiles()
    for row in rows:
        profile = profiles.get(row["user_id"])
        row.update(profile.to_dict() if profile else {"alias": "?", "initials": "?", "colour": "#888"})
        row["model"] = display_name(row["model"], row["user_id"])
    return rows


@router.get("/{race_id}/submissions")
async def list_submissions(race_id: int, request: Request, user: User = Depends(current_user)) -> list[dict]:
    """Your submissions to the race (every racer's, with their models, for its owner and admins)."""
    race = visible_race(request, race_id, user)
    return await run_in_threadpool(_rows, request, race, None if manages(race, user) else user.id)


def _own_submission(request: Request, race_id: int, submission_id: int, user: User):
    race = visible_race(request, race_id, user)
    sub = races(request).submission(submission_id)
    if sub is None or sub.race_id != race.id or not (sub.user_id == user.id or manages(race, user)):
        raise HTTPException(404, {"message": f"no submission {submission_id} of yours in race {race_id} (a racer "
                                             "sees only their own submissions' files)"})
    return race, sub


@router.get("/{race_id}/submissions/{submission_id}")
def get_submission(race_id: int, submission_id: int, request: Request, user: User = Depends(current_user)) -> dict:
    race, sub = _own_submission(request, race_id, submission_id, user)
    return next(r for r in _rows(request, race, sub.user_id) if r["id"] == sub.id)


@router.get("/{race_id}/submissions/{submission_id}/video")
def submission_video(race_id: int, submission_id: int, request: Request, user: User = Depends(current_user)):
    race, sub = _own_submission(request, race_id, submission_id, user)
    job = request.app.state.store.job(sub.job_id)
    found = _cache(request).evaluation(job, models_dir()) if job else {"stamp": None}
    if not found.get("stamp"):
        raise HTTPException(404, {"message": "this submission has no video yet"})
    from laplab.store.layout import ModelFolder
    folder = ModelFolder(models_dir() / sub.model).evaluation_dir(found["stamp"])
    videos = sorted(folder.glob("*.mp4")) + sorted(folder.glob("*.gif"))
    if not videos:
        raise HTTPException(404, {"message": "this submission's evaluation wrote no video"})
    return FileResponse(videos[0])


def leaderboard_rows(request: Request, race: Race, user: User) -> list[dict]:
    ranked = board(_rows(request, race))
    for row in ranked:  # model and login names only for their racer, the race's owner and admins
        if not (row["user_id"] == user.id or manages(race, user)):
            row["model"] = row["name"] = None  # others see the racer's display name (alias) and avatar
    return ranked


@router.get("/{race_id}/leaderboard")
async def leaderboard(race_id: int, request: Request, user: User = Depends(current_user)) -> dict:
    """The ranked board (each racer's best submission) with every lap, and the newest result's id."""
    race = visible_race(request, race_id, user)
    ranked = await run_in_threadpool(leaderboard_rows, request, race, user)
    latest = max((r for r in ranked), key=lambda r: r["created"], default=None)
    return {"race": _view(race, user, request), "entries": ranked, "latest": latest["id"] if latest else None}


@router.get("/{race_id}/leaderboard.csv")
def leaderboard_csv(race_id: int, request: Request, user: User = Depends(current_user)) -> Response:
    race = visible_race(request, race_id, user)
    names = {u.id: u.name for u in request.app.state.store.users()} if manages(race, user) else {}  # logins: its runners'
    text = csv_text(race.settings, leaderboard_rows(request, race, user), names)
    return Response(text, media_type="text/csv",
                    headers={"Content-Disposition": f'attachment; filename="race-{race.id}-results.csv"'})


@router.get("/{race_id}/replay")
async def race_replay(race_id: int, request: Request, user: User = Depends(current_user)) -> dict:
    """The newest evaluated submission's laps, top-down (the car's x, y per lap) with its racer's name."""
    race = visible_race(request, race_id, user)
    rows = [r for r in await run_in_threadpool(_rows, request, race) if r["state"] == "done"]
    if not rows:
        return {"submission": None, "laps": [], "track": race.settings.track}
    newest = max(rows, key=lambda r: r["created"])
    job = request.app.state.store.job(newest["job"])
    stamp = _cache(request).evaluation(job, models_dir())["stamp"]
    laps = await run_in_threadpool(replay, job, stamp, models_dir()) if stamp else []
    return {"submission": newest["id"], "alias": newest["alias"], "colour": newest["colour"], "laps": laps,
            "track": race.settings.track, "score": newest["score"]}
