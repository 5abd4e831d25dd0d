"""A race's submissions under the race's rules as they are now, from the laps their evaluations
recorded: a facilitator who edits a race after submissions came in sees them re-ranked at once,
without re-running an evaluation, each with a note of what changed.

What each change does to an evaluation driven under the old rules (its job's ``params``):

- ranking method, consecutive laps: scored again from its laps (exact);
- off-track or collision penalty: each completed lap re-timed, its served penalties replaced by the
  new ones (exact for time trials and object avoidance, where the car stands still while a penalty
  runs; approximate in head-to-bot races, where the bots drive on meanwhile: the note says so);
- fewer laps: ranked on its first laps (exact: a continuous evaluation's first N laps are an N-lap
  evaluation); more laps: ranked on the laps it drove where the ranking allows, else unranked with
  the reason;
- fewer resets per lap: a lap that needed more no longer counts as completed; more resets: a lap that
  ended at the old limit stays ended (the note says so);
- track, direction, car physics or the race type and its objects and bots: the evaluation drove
  another course, so it no longer ranks, and says why;
- allowed sensors: a model with a sensor the race no longer allows no longer ranks, and says why.
"""

from __future__ import annotations

from dataclasses import dataclass

from laplab.races.rules import RaceSettings, Score, score, sensor_refusal

INCIDENT_COUNTS = ("off_track_count", "reversed_count", "immobilized_count")  # off-track penalty; crashes: collision
DEFAULT_PENALTIES = {"off_track_penalty": 2.0, "crash_penalty": 5.0}  # laplab's evaluation defaults
OVER_RESET_LIMIT = "over_reset_limit"


@dataclass(frozen=True)
class Rescored:
    """One evaluation under the race's current rules: ``trials`` (its laps as they count now, dicts as
    the evaluation summary's), ``score`` (:class:`laplab.races.rules.Score`) and ``notes`` (what the
    current rules changed, one sentence each; empty when it ran under them)."""
    trials: list[dict]
    score: Score
    notes: tuple[str, ...]


def _track_label(key: str | None) -> str:
    name, _, reversed_ = str(key).partition("@")
    return f"{name} (reversed)" if reversed_ else name


def _race_label(race_type: dict | None) -> str:
    if not race_type:
        return "a time trial"
    try:
        from laplab.sim.race_type import RaceType
        return RaceType.from_dict(race_type, "race_type").summary()
    except Exception:  # noqa: BLE001 - an old job's dict: its kind is enough to say
        return str(race_type.get("kind", "another race type")).replace("_", " ")


def _course(race_type: dict | None) -> dict | None:
    """A race type's course: everything but its collision penalty (a scoring rule, re-applied)."""
    return None if not race_type else {k: v for k, v in race_type.items() if k != "collision_penalty"}


def course_change(current: dict, driven: dict) -> str | None:
    """Why an evaluation driven with the job params ``driven`` cannot rank under the race's evaluation
    params ``current`` (another track or direction, car, race type, objects or bots); None when it can."""
    again = "submit the model again to rank"
    if driven.get("track") != current.get("track"):
        return (f"it was driven on {_track_label(driven.get('track'))}; the race is now on "
                f"{_track_label(current.get('track'))}: {again}")
    if driven.get("physics") != current.get("physics"):
        return (f"it was driven with the car {driven.get('physics') or 'of its model'}; the race now uses "
                f"{current.get('physics') or 'each model own car'}: {again}")
    if _course(driven.get("race_type")) != _course(current.get("race_type")):
        return (f"it was driven as {_race_label(driven.get('race_type'))}; the race is now "
                f"{_race_label(current.get('race_type'))}: {again}")
    return None


def _penalised(trial: dict, off_track_s: float, collision_s: float) -> float:
    crashes = int(trial.get("crash_count", 0))
    others = sum(int(trial.get(name, 0)) for name in INCIDENT_COUNTS)
    return crashes * collision_s + others * off_track_s


def _laps(count: int) -> str:
    return f"{count} lap{'' if count == 1 else 's'}"


def _seconds(value: float) -> str:
    return f"{value:g} s"


def rescore(settings: RaceSettings, current: dict, driven: dict, trials: list[dict],
            sensors: list[str] | None = None) -> Rescored:
    """Score ``trials`` (an evaluation's laps, driven with the job params ``driven`` by a model with
    ``sensors``, None: not recorded) under ``settings`` (whose evaluation params are ``current``);
    see the module docstring for each rule."""
    if (why := course_change(current, driven)) is not None:
        return Rescored(list(trials), Score(None, why), ())
    if sensors is not None and (why := sensor_refusal(settings, sensors)) is not None:
        why = why.removeprefix("model: ").replace("the race allows", "the race now allows")
        return Rescored(list(trials), Score(None, f"{why}: submit a model with those sensors to rank"), ())
    notes: list[str] = []
    laps_driven = len(trials)
    counted = [dict(t) for t in trials[:settings.laps]]
    if laps_driven > settings.laps:
        notes.append(f"ranked on its first {_laps(settings.laps)} of the {_laps(laps_driven)} it drove (the race "
                     f"now has {_laps(settings.laps)})")
    elif 0 < laps_driven < settings.laps:
        notes.append(f"it drove {_laps(laps_driven)}; the race now has {_laps(settings.laps)}")

    old = {name: float(driven.get(name, default)) for name, default in DEFAULT_PENALTIES.items()}
    new = {"off_track_penalty": float(settings.off_track_penalty), "crash_penalty": float(settings.collision_penalty)}
    cap = driven.get("max_trial_time")
    if old != new:
        for trial in counted:
            if trial.get("status") != "lap_complete" or trial.get("lap_time") is None:
                continue
            served = float(trial.get("penalty_time", _penalised(trial, old["off_track_penalty"], old["crash_penalty"])))
            now = _penalised(trial, new["off_track_penalty"], new["crash_penalty"])
            lap = float(trial["lap_time"]) - served + now
            trial.update(lap_time=lap, duration=lap, penalty_time=now)
            if cap is not None and lap >= float(cap):
                trial.update(status="time_up", lap_time=None)
        changed = [f"{label} {_seconds(old[key])} → {_seconds(new[key])}"
                   for key, label in (("off_track_penalty", "off-track"), ("crash_penalty", "collision"))
                   if old[key] != new[key]]
        note = f"lap times re-timed with the race's penalties now ({', '.join(changed)})"
        if (current.get("race_type") or {}).get("kind") == "head_to_bot":
            note += "; the bots would have moved on differently while the car stood: submit again for an exact run"
        notes.append(note)

    old_resets, new_resets = driven.get("resets"), settings.max_resets
    if new_resets is not None and (old_resets is None or new_resets < old_resets):
        for number, trial in enumerate(counted, 1):
            if trial.get("status") == "lap_complete" and int(trial.get("reset_count", 0)) > new_resets:
                trial.update(status=OVER_RESET_LIMIT, lap_time=None)
                notes.append(f"lap {number} needed {trial.get('reset_count')} resets; the race now allows "
                             f"{new_resets}, so it does not count as completed")
    elif old_resets is not None and (new_resets is None or new_resets > old_resets):
        ended = [n for n, t in enumerate(counted, 1) if t.get("status") not in ("lap_complete", "time_up")]
        if ended:
            notes.append(f"lap {ended[0]} ended at the old limit of {old_resets} resets per lap; the race now "
                         f"allows {'unlimited' if new_resets is None else new_resets}: submit again to drive "
                         "under the new limit")

    result = score(settings, counted)
    if result.value is None and laps_driven < settings.laps:
        result = Score(None, f"it drove {_laps(laps_driven)} before the race asked {settings.laps}: {result.reason}; "
                             "submit the model again to drive every lap")
    return Rescored(counted, result, tuple(notes))
