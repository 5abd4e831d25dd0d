"""One head-to-model race from a :class:`~laplab.train.request.RaceRequest`, with what it leaves behind.

``laplab race`` and the console's race job (``laplab.jobs.worker``) both call :func:`run_model_race`:
the models' policies are loaded, refused when they drive different cars (physics versions), raced
with :func:`laplab.evaluate.race.run_race`, and the race is written into a folder:

    race.json     the racers in finishing order (laps, times, lap times, crashes, off-tracks,
                  penalty seconds, position), the models in their driving order, laps, track, duration
    topdown.png   the race's end from above: every car (car i in colour i of the models' order) and its path
    race.mp4      with ``video``: the race's top-down view, step by step (not for a stopped race)

A race stopped early (``should_stop``, the console's Stop) writes race.json (``"stopped": true``, the
cars ranked where they were) and the picture of the race so far, and no video, so that it ends promptly.

:func:`model_cars` reads every model's car from its ``laplab.json`` without loading a network (what
the console checks before it queues a race).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from laplab.errors import UserError
from laplab.train.request import RaceRequest

RACE_FILE, PICTURE_FILE, VIDEO_FILE = "race.json", "topdown.png", "race.mp4"


def model_cars(names: list[str], models_dir: Path | None = None) -> list[str]:
    """The car (a vehicle preset name) each model drives, read from its ``laplab.json``."""
    from laplab.store.layout import model_folder
    from laplab.train.config import TrainConfig
    cars = []
    for name in names:
        folder = model_folder(name, models_dir)
        cars.append(TrainConfig.from_dict(folder.read_laplab_config(), str(folder.laplab_config)).car)
    return cars


def run_model_race(request: RaceRequest, folder: Path, names: list[str] | None = None,
                   should_stop: Callable[[], bool] | None = None):
    """Race ``request.models`` and write the race into ``folder`` (see the module docstring).

    ``names``: how the racers are called in messages and in ``race.json`` (default: the model names;
    the console passes the names its user knows them by). Returns the
    :class:`~laplab.evaluate.race.RaceResult`. A missing model, a missing checkpoint or different cars
    raise a :class:`~laplab.errors.UserError` before anything is written. ``should_stop`` (asked once
    a simulated step) ends the race early (see the module docstring)."""
    from laplab.evaluate.race import Driver, check_same_car, race_picture, run_race
    from laplab.track.registry import load_track
    from laplab.train.policy import load_model_policy
    from laplab.vehicle.params import vehicle_preset

    names = list(names or request.models)
    policies = []
    for model in request.models:
        try:
            policies.append(load_model_policy(model, request.checkpoint))
        except FileNotFoundError as exc:
            raise UserError(str(exc), field="models") from None
    check_same_car(names, [p.config.car for p in policies])
    home = policies[0].config
    track = load_track(request.track) if request.track else load_track(home.track, reverse=home.reverse)
    drivers = [Driver(name, lambda obs, p=p: p.act(obs), p.spec, p.config.car) for name, p in zip(names, policies)]
    result = run_race(drivers, track, vehicle_preset(home.car), laps=request.laps, max_time=request.max_time_s,
                      should_stop=should_stop)
    folder.mkdir(parents=True, exist_ok=True)
    from PIL import Image
    Image.fromarray(race_picture(result, names)).save(folder / PICTURE_FILE)
    document = {**result.to_dict(), "models": names, "laps": request.laps, "max_time_s": request.max_time_s,
                "checkpoint": request.checkpoint, "car": home.car, "picture": PICTURE_FILE, "video": None}
    if request.video and not result.stopped:
        document["video"] = write_race_video(folder / VIDEO_FILE, result).name
    temporary = folder / (RACE_FILE + ".tmp")
    temporary.write_text(json.dumps(document, indent=2))
    temporary.replace(folder / RACE_FILE)
    return result


def write_race_video(path: Path, result) -> Path:
    """The race's top-down view, every car and its path so far, one frame per step; returns the file
    written (a ``.gif`` where imageio-ffmpeg is missing)."""
    from laplab.evaluate.video import _TopdownFrames
    from laplab.sensors.render import draw_topdown
    from laplab.sensors.video import write_episode_video
    poses = result.poses

    def frame(t: int):
        return draw_topdown(result.track, poses[t], paths=[poses[: t + 1, i, :2] for i in range(poses.shape[1])])
    return write_episode_video(path, _TopdownFrames(frame, len(poses)), None,
                               {"time": [f"{c:.2f} s" for c in result.clock]})
