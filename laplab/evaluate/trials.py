"""DeepRacer evaluation as a library call: settings, results, and the functions that run and store it.

- :func:`evaluate_policy` runs the trials of a policy on a track (pure: no files).
- :func:`save_evaluation` writes a result into a model folder (simtrace, metrics, summary.json, video).
- :func:`evaluate_model` does both for a stored model and returns the result and its stamp.

The rules (penalties, resets, the time cap, continuous laps) are described in
:mod:`laplab.evaluate.runner` and ``docs/evaluation.md``.
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import asdict, dataclass, field, fields, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import numpy as np

from laplab.env.metadata import ModelMetadata
from laplab.errors import UserError
from laplab.env.observations import ObservationBuilder
from laplab.env.spec import ModelSpec, model_spec
from laplab.env.step import EpisodeStepper
from laplab.evaluate.runner import run_trials
from laplab.evaluate.summary import EvaluationSummary, TrialResult, summarize
from laplab.sim.simulator import Simulator
from laplab.sim.state import EpisodeParams
from laplab.store.atomic import atomic_write_json
from laplab.store.layout import ModelFolder
from laplab.track.geometry import Track
from laplab.vehicle.params import DEEPRACER, VehicleParams

CONSOLE_MAX_TRIALS = 5  # the DeepRacer console's limit
FORCED_MAX_TRIALS = 100
SUMMARY_FILE = "summary.json"
SUMMARY_VERSION = 1


class EvaluationError(UserError, ValueError):
    """Evaluation settings out of range (``field``: the setting), or a model that cannot be evaluated."""


@dataclass(frozen=True)
class EvaluationSettings:
    """How an evaluation is run (DeepRacer console defaults): the one evaluate request of every door
    (``laplab evaluate``, the console's API body, the job worker, :func:`laplab.api.evaluate`;
    :data:`EvaluateRequest` is this class). Its errors' ``field`` is the setting's name.

    - ``track``: name or path (``name@reversed`` drives it the other way); None: the model's
      training track and direction.
    - ``trials``: 1..5 (the console's limit); up to 100 with ``force``.
    - ``checkpoint``: ``best``, ``last`` or a checkpoint file name.
    - ``off_track_penalty``: s a car stands after an off-track, reversed or immobilized reset (console 2,
      league 5); ``crash_penalty``: s after a crash (5).
    - ``resets``: resets allowed per trial (None: unlimited, the console's default; 0: the first
      incident ends the trial).
    - ``continuous``: the trials are consecutive laps of one run (deepracer-for-cloud's style).
    - ``seed``: seeds sensor noise and, with ``stochastic``, the policy's sampling.
    - ``stochastic``: sample actions from the policy instead of taking the greedy one.
    - ``video``: write an MP4 (else GIF) of the first trial.
    - ``max_trial_time``: s of simulation time (penalties included) after which a trial still running
      ends as ``time_up``; 600 s is 9,000 decisions, several times the slowest sensible lap.
    - ``physics``: the car to drive (``--physics``: 4, 5, 6, ``classic`` or a car's name); None: the
      car the model trained with (:mod:`laplab.vehicle.physics`).
    - ``race_type``: the race to drive, a :class:`laplab.sim.race_type.RaceType`'s dict (its objects and
      bots; a race of the console sets it); None: the model's own race type.
    - ``domain_randomization``: the camera sees the track's look with training's domain randomisation
      (:data:`laplab.sensors.randomize.DOMAIN_RANDOMIZATION`: colour variants of the scene,
      brightness, contrast, gamma, noise, blur, camera jitter), drawn anew per car and frame from
      ``seed``; refused for a model without a camera. Such an evaluation does not rank on leaderboards.
    """

    track: str | None = None
    trials: int = 3
    checkpoint: str = "best"
    off_track_penalty: float = 2.0
    crash_penalty: float = 5.0
    resets: int | None = None
    continuous: bool = False
    seed: int | None = 0
    stochastic: bool = False
    video: bool = False
    force: bool = False
    max_trial_time: float = 600.0
    physics: str | None = None
    race_type: dict | None = None
    domain_randomization: bool = False

    def __post_init__(self) -> None:
        limit = FORCED_MAX_TRIALS if self.force else CONSOLE_MAX_TRIALS
        if isinstance(self.trials, bool) or not isinstance(self.trials, int) or not 1 <= self.trials <= limit:
            hint = "" if self.force else f" (the DeepRacer console's limit; --force allows up to {FORCED_MAX_TRIALS})"
            raise EvaluationError(f"trials must be an integer from 1 to {limit}{hint}, got {self.trials!r}",
                                  field="trials")
        for name in ("off_track_penalty", "crash_penalty"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise EvaluationError(f"{name.replace('_', ' ')} must be a number of seconds >= 0, got {value!r}",
                                      field=name)
        if self.resets is not None and (isinstance(self.resets, bool) or not isinstance(self.resets, int)
                                        or self.resets < 0):
            raise EvaluationError(f"resets must be an integer >= 0 or None (unlimited), got {self.resets!r}",
                                  field="resets")
        if not (isinstance(self.max_trial_time, (int, float)) and math.isfinite(self.max_trial_time)
                and self.max_trial_time > 0):
            raise EvaluationError(f"max trial time must be a positive number of seconds, got {self.max_trial_time!r}",
                                  field="max_trial_time")
        if not isinstance(self.checkpoint, str) or not self.checkpoint:
            raise EvaluationError(f"checkpoint must be 'best', 'last' or a checkpoint name, got {self.checkpoint!r}",
                                  field="checkpoint")
        if self.physics is not None:
            from laplab.vehicle.physics import PhysicsError, resolve_physics
            try:
                object.__setattr__(self, "physics", resolve_physics(self.physics))
            except PhysicsError as error:
                raise EvaluationError(str(error), field="physics") from None
        if not isinstance(self.domain_randomization, bool):
            raise EvaluationError(f"domain randomization must be true or false, got {self.domain_randomization!r}",
                                  field="domain_randomization")
        if self.race_type is not None:
            from laplab.sim.race_type import RaceType, RaceTypeError
            try:
                object.__setattr__(self, "race_type", RaceType.from_dict(self.race_type, "race_type").to_dict())
            except (RaceTypeError, TypeError) as error:
                raise EvaluationError(f"race_type: {error}", field="race_type") from None

    @classmethod
    def from_mapping(cls, data: dict[str, Any], allowed: tuple[str, ...] | None = None) -> "EvaluationSettings":
        """Settings from a JSON body or a job's params (only the ``allowed`` names; None: all); an
        unknown key is refused, naming it."""
        names = allowed if allowed is not None else tuple(f.name for f in fields(cls))
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise EvaluationError(f"unknown evaluation setting {unknown[0]!r}: known are {', '.join(names)}",
                                  field=unknown[0])
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


EvaluateRequest = EvaluationSettings  # the evaluate request of every door (laplab.train.request has the others)


@dataclass(frozen=True)
class EvaluationResult:
    """An evaluation: its trials and summary, the simtrace columns of every step (``trace``, as
    :class:`laplab.store.simtrace.SimtraceWriter` takes them), and what it ran on."""

    settings: EvaluationSettings
    track: Track
    vehicle: VehicleParams
    metadata: ModelMetadata
    trials: tuple[TrialResult, ...]
    summary: EvaluationSummary
    trace: dict[str, np.ndarray] = field(repr=False)
    decisions: int = 0
    wall_seconds: float = 0.0
    model: str | None = None
    checkpoint: str | None = None
    video: str | None = None
    trained_car: str | None = None
    race_type: dict | None = None  # laplab.sim.race_type.RaceType.to_dict(); None: a time trial
    obstacles: np.ndarray | None = field(default=None, repr=False)  # (rows, slots, 7) per trace row

    def to_dict(self) -> dict[str, Any]:
        """The ``summary.json`` document."""
        return {
            "version": SUMMARY_VERSION, "model": self.model, "checkpoint": self.checkpoint,
            "track": {"name": self.track.name, "length": self.track.length, "direction": self.track.direction},
            "settings": self.settings.to_dict(), "trials": [t.to_dict() for t in self.trials],
            "summary": self.summary.to_dict(), "video": self.video,
            "action_space_type": self.metadata.action_space.kind, "sensors": list(self.metadata.sensors),
            "car": self.vehicle.name, "trained_car": self.trained_car, "race_type": self.race_type, "decisions": self.decisions, "wall_seconds": self.wall_seconds,
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        }


@contextlib.contextmanager
def _policy_randomness(policy: Any, seed: int | None, stochastic: bool):
    """Seed a stored model's sampling (torch's global generator, restored afterwards, and the
    learner's e-greedy generator) so a stochastic evaluation repeats with its seed."""
    learner = getattr(policy, "learner", None)
    if not stochastic or seed is None or learner is None:
        yield
        return
    import torch
    saved_rng = getattr(learner, "rng", None)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        learner.rng = np.random.default_rng(seed)
        try:
            yield
        finally:
            learner.rng = saved_rng


def _actor(policy: Any, stochastic: bool) -> Callable[[Any], np.ndarray]:
    if hasattr(policy, "act"):
        return lambda observations: policy.act(observations, deterministic=not stochastic)
    if callable(policy):
        return policy
    raise TypeError(f"evaluate_policy: policy must be a ModelPolicy (with .act) or a callable(obs) -> actions, "
                    f"got {type(policy).__name__}")


def evaluate_policy(policy: Any, track: Track, settings: EvaluationSettings = EvaluationSettings(), *,
                    spec: ModelSpec | None = None, vehicle: VehicleParams | None = None,
                    optimal_lap_time: float | None = None,
                    standing_start_lap_time: float | None = None, race=None) -> EvaluationResult:
    """Run ``settings.trials`` trials of ``policy`` on ``track`` in one batched Simulator.

    ``policy``: a :class:`laplab.train.policy.ModelPolicy` (greedy unless ``settings.stochastic``) or
    a callable mapping a batch of observations (K, ...) to K env actions (indices, or points of
    [-1, 1]^2). A policy with a ``bind(simulator)`` method gets the Simulator before the first step
    (scripted drivers that read the car's state). ``spec`` (sensors, frame stack, action space) defaults
    to the policy's, else laplab's default model; ``vehicle`` to the policy's training car, else DeepRacer's.
    ``optimal_lap_time`` (s) fills the summary's gap to optimal, ``standing_start_lap_time`` (s) its
    yardstick for laps from rest. ``race`` (a :class:`laplab.sim.race_type.RaceType`) puts its objects
    on the track, default the policy's training race type (time trial without one). Deterministic for
    a given seed.
    """
    started = time.perf_counter()
    spec = spec or getattr(policy, "spec", None) or model_spec()
    if not isinstance(spec, ModelSpec):
        raise TypeError(f"evaluate_policy: spec must be a ModelSpec (laplab.env.spec.model_spec), got {type(spec).__name__}")
    if vehicle is None:
        config = getattr(policy, "config", None)
        from laplab.vehicle.params import vehicle_preset
        vehicle = vehicle_preset(config.car) if config is not None else DEEPRACER
    slots = 1 if settings.continuous else settings.trials
    episode = EpisodeParams(round_robin_advance=0.0, spread_starts=False, max_steps=2**62)
    if race is None:
        race = getattr(getattr(policy, "config", None), "race_type", None)
    sim = Simulator(track, slots, vehicle, episode, race=race, seed=settings.seed)
    observations = ObservationBuilder(sim, spec, seed=settings.seed, randomization=randomization_for(settings, spec.sensors))
    act = _actor(policy, settings.stochastic)
    if hasattr(policy, "bind"):
        policy.bind(sim)
    with _policy_randomness(policy, settings.seed, settings.stochastic):
        run = run_trials(EpisodeStepper(sim, spec.action_space), observations.observe, act, settings)
    return EvaluationResult(settings=settings, track=track, vehicle=vehicle, metadata=spec.metadata, trials=run.trials,
                            summary=summarize(run.trials, optimal_lap_time, standing_start_lap_time), trace=run.trace,
                            decisions=run.decisions, wall_seconds=time.perf_counter() - started,
                            model=getattr(policy, "name", None), checkpoint=getattr(policy, "checkpoint", None),
                            race_type=sim.race.to_dict() if sim.race.has_objects else None,
                            obstacles=run.obstacles)


def randomization_for(settings: EvaluationSettings, sensors: tuple[str, ...]):
    """Training's domain randomisation when ``settings`` asks for it (None otherwise) for a model with
    ``sensors``; refused, naming the setting, for a model that has no camera to randomise."""
    if not settings.domain_randomization:
        return None
    from laplab.env.metadata import camera_sensor
    if camera_sensor(sensors) is None:
        raise EvaluationError(
            f"domain randomization changes what a camera sees, and this model has no camera (sensors: "
            f"{', '.join(sensors)}): evaluate it without domain randomization", field="domain_randomization")
    from laplab.sensors.randomize import DOMAIN_RANDOMIZATION
    return DOMAIN_RANDOMIZATION


def save_evaluation(folder: ModelFolder, result: EvaluationResult) -> tuple[str, EvaluationResult]:
    """Write ``result`` as a new evaluation of the model in ``folder``; returns its stamp and the
    result (with the video path when ``result.settings.video``).

    Files: ``evaluation-<stamp>/evaluation-simtrace/0-iteration.csv`` (every trial, ``episode`` =
    trial index), ``metrics/evaluation/evaluation-<stamp>.json`` (one row per trial) and
    ``evaluation-<stamp>/summary.json`` (laplab's own: trials, summary, track, settings).
    """
    from laplab.store.metrics import EvaluationMetricsWriter
    from laplab.store.simtrace import SimtraceWriter
    stamp = folder.new_evaluation()
    with SimtraceWriter(folder.evaluation_simtrace(stamp), fsync=False) as writer:
        writer.write_rows(result.trace)
    trials = result.trials
    counts = {name: [getattr(t, name) for t in trials]
              for name in ("crash_count", "immobilized_count", "off_track_count", "reversed_count")}
    EvaluationMetricsWriter(folder.evaluation_metrics(stamp)).append_trials(
        completion_percentage=[t.completion for t in trials], start_time=[t.start_time for t in trials],
        metric_time=[t.start_time + t.duration for t in trials], episode_status=[t.status for t in trials],
        **counts)
    if result.settings.video:
        from laplab.evaluate.video import write_trial_video
        path = write_trial_video(folder.evaluation_dir(stamp) / "trial-1.mp4", result, trial=0)
        result = replace(result, video=str(path))
    atomic_write_json(folder.evaluation_dir(stamp) / SUMMARY_FILE, result.to_dict())
    return stamp, result


@dataclass(frozen=True)
class PreparedEvaluation:
    """What :func:`evaluate_policy` needs for a stored model, read from its folder: the ``policy``,
    the ``track``, the ``vehicle`` and ``race`` (a :class:`laplab.sim.race_type.RaceType`) to drive,
    the final ``settings`` and the optimal lap times (s, None when the race line cannot be solved)."""

    policy: Any
    track: Track
    vehicle: VehicleParams
    race: Any
    settings: EvaluationSettings
    optimal: float | None
    standing: float | None


def prepare_evaluation(name: str, settings: EvaluationSettings = EvaluationSettings()) -> PreparedEvaluation:
    """Load stored model ``name`` at ``settings.checkpoint`` and everything its evaluation drives."""
    from laplab.evaluate.optimal import optimal_lap_time, standing_start_optimal_lap_time
    from laplab.track.registry import load_track
    from laplab.train.policy import load_model_policy
    from laplab.vehicle.params import vehicle_preset

    policy = load_model_policy(name, settings.checkpoint, seed=0 if settings.seed is None else settings.seed)
    config = policy.config
    track = load_track(settings.track) if settings.track else load_track(config.track, reverse=config.reverse)
    vehicle = vehicle_preset(settings.physics or config.car)
    race = config.race_type
    if settings.race_type is not None:  # a race's own objects and bots (a console race sets them)
        from laplab.sim.race_type import RaceType
        race = RaceType.from_dict(settings.race_type, "race_type")
    if race.has_objects:
        race.check_track(track.length, track.name)
        if settings.crash_penalty == EvaluationSettings.crash_penalty:  # the race's own, unless asked otherwise
            settings = replace(settings, crash_penalty=race.collision_penalty)
    try:
        optimal = optimal_lap_time(track, vehicle)
        standing = standing_start_optimal_lap_time(track, vehicle)
    except (ValueError, RuntimeError, ArithmeticError) as exc:  # a race line that cannot be solved
        import warnings
        warnings.warn(f"no optimal lap time for track {track.name!r}: {exc}", stacklevel=2)
        optimal = standing = None
    return PreparedEvaluation(policy, track, vehicle, race, settings, optimal, standing)


def run_prepared(prepared: PreparedEvaluation) -> EvaluationResult:
    """Drive a :class:`PreparedEvaluation` (pure: no files; what a Ray node runs for a console job)."""
    result = evaluate_policy(prepared.policy, prepared.track, prepared.settings, vehicle=prepared.vehicle,
                             optimal_lap_time=prepared.optimal, standing_start_lap_time=prepared.standing,
                             race=prepared.race)
    return replace(result, trained_car=prepared.policy.config.car)


def evaluate_model(name: str, settings: EvaluationSettings = EvaluationSettings()) -> tuple[EvaluationResult, str]:
    """Evaluate stored model ``name`` at ``settings.checkpoint`` and keep the evaluation in its
    folder; returns the result and the evaluation's stamp."""
    prepared = prepare_evaluation(name, settings)
    stamp, result = save_evaluation(prepared.policy.folder, run_prepared(prepared))
    return result, stamp


def read_evaluation_summary(folder: ModelFolder, stamp: str) -> dict[str, Any] | None:
    """The ``summary.json`` document of evaluation ``stamp`` (None when absent: an evaluation made
    by another tool, which has only the DeepRacer files)."""
    from laplab.store.atomic import read_json
    path = folder.evaluation_dir(stamp) / SUMMARY_FILE
    if not path.is_file():
        return None
    document = read_json(path)
    if not isinstance(document, dict) or "summary" not in document or "trials" not in document:
        raise EvaluationError(f"{path}: not a laplab evaluation summary (expected keys 'summary' and 'trials')")
    return document


def evaluation_summary_path(folder: ModelFolder, stamp: str) -> Path:
    return folder.evaluation_dir(stamp) / SUMMARY_FILE
