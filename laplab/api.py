"""laplab from Python, as the SageMaker RL + RoboMaker notebook drives DeepRacer.

The notebook's steps, one call each: write the model's files (reward function, action space,
hyperparameters), start a training job that runs on its own (``TrainingJob.start``, like
``estimator.fit(wait=False)``: a ``laplab train`` process, with rollout workers on Ray and the model
in an S3 store when asked), read and plot its metrics while it runs (re-run the cell), evaluate it,
and take the artifact for the car. Jobs are processes, not threads: the notebook's kernel stays free,
and a job gets the command line's supervision, limits and error paragraphs.

Nothing here imports torch; the job processes do.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from laplab.errors import UserError

if TYPE_CHECKING:
    from laplab.sim.race_type import RaceType

__all__ = ["ModelFiles", "TrainingJob", "evaluate", "export_for_car", "import_model", "training_request",
           "write_model_files"]

RUNNING, COMPLETED, FAILED, STOPPED = "InProgress", "Completed", "Failed", "Stopped"


@dataclass(frozen=True)
class ModelFiles:
    """The files a training job starts from (paths), as the notebook uploads them to S3."""

    reward_function: Path
    model_metadata: Path
    hyperparameters: Path


def write_model_files(folder: str | os.PathLike, reward_function: str, action_space: list[dict] | dict,
                      hyperparameters: dict[str, Any] | None = None, sensor: list[str] | None = None,
                      neural_network: str = "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW",
                      training_algorithm: str = "clipped_ppo") -> ModelFiles:
    """Write ``reward_function.py``, ``model_metadata.json`` and ``hyperparameters.json`` into ``folder``.

    ``action_space``: DeepRacer's list of ``{"steering_angle": deg, "speed": m/s}`` or its continuous
    ``{"steering_angle": {"low", "high"}, "speed": {"low", "high"}}``; ``sensor`` defaults to
    ``["FRONT_FACING_CAMERA"]``; ``hyperparameters`` are DeepRacer's keys (missing keys take
    DeepRacer's defaults). The files are checked as ``laplab train`` checks them: a mistake is a
    :class:`~laplab.errors.UserError` naming the file and the key.
    """
    from laplab.agents.hyperparameters import load_hyperparameters
    from laplab.env.metadata import load_model_metadata

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files = ModelFiles(folder / "reward_function.py", folder / "model_metadata.json", folder / "hyperparameters.json")
    files.reward_function.write_text(reward_function)
    metadata = {"action_space": action_space, "sensor": sensor or ["FRONT_FACING_CAMERA"],
                "neural_network": neural_network, "training_algorithm": training_algorithm,
                "action_space_type": "continuous" if isinstance(action_space, dict) else "discrete",
                "version": "5"}
    files.model_metadata.write_text(json.dumps(metadata, indent=2))
    files.hyperparameters.write_text(json.dumps(hyperparameters or {}, indent=2))
    try:
        load_model_metadata(files.model_metadata)
        load_hyperparameters(files.hyperparameters)
    except (ValueError, OSError) as exc:
        raise UserError(str(exc)) from None
    return files


def _laplab(*args: str) -> list[str]:
    return [sys.executable, "-m", "laplab.cli", *args]


def _environment() -> dict[str, str]:
    """A job process's variables: this one's, with the settings in force (laplab.settings.use_settings)."""
    from laplab.settings import current_settings
    return current_settings().child_environment()


def _store_args(store: str | None) -> list[str]:
    return ["--store", store] if store else []


@dataclass
class TrainingJob:
    """A ``laplab train`` process and the model it writes (``name``, in ``store`` or the local models
    folder). Made by :meth:`start`; ``log`` is the job's terminal output."""

    name: str
    process: subprocess.Popen
    log: Path
    store: str | None = None
    started: float = field(default_factory=time.time)

    @classmethod
    def start(cls, name: str, files: ModelFiles, track: str | list[str] | None = None,
              max_time: str | float | None = None, workers: int = 1, store: str | None = None,
              ray_address: str | None = None, extra_args: tuple[str, ...] = (),
              log_folder: str | os.PathLike | None = None, physics: str | None = None,
              race_type: "RaceType | dict | None" = None, domain_randomization: bool = False) -> "TrainingJob":
        """Start training model ``name`` in the background and return at once.

        ``track`` (None: laplab's default track) may be a list (``["reInvent2019_track",
        "Canada_Training@reversed"]``) for a multi-track job, one track per rollout worker in turn;
        ``max_time`` is seconds or a duration (``"90s"``, ``"20m"``; None: the default of every door,
        :data:`laplab.train.request.DEFAULT_MAX_TIME_S`); ``workers`` > 1 runs rollout workers on
        Ray (a local one, or the cluster at ``ray_address``); ``store`` is ``s3://bucket/prefix`` or
        None for ``$LAPLAB_HOME/models``; ``physics`` (4, 5, 6 or classic) DeepRacer's car to train with
        (None: the one the model metadata's ``version`` chooses; docs/physics.md); ``race_type`` a
        :class:`laplab.sim.race_type.RaceType` (or its dict, e.g. ``{"kind": "object_avoidance",
        "objects": 3}``; None: a time trial; docs/race-types.md); ``domain_randomization`` trains a
        camera model under the camera's domain randomisation (``laplab train --domain-randomization``).

        The request is checked here, as the console's API checks it (:meth:`TrainRequest.validate
        <laplab.train.request.TrainRequest.validate>`): a bad value raises the same
        :class:`~laplab.errors.UserError`, with the same ``field``, before any process starts.
        """
        request = training_request(name, files, track, max_time, workers, physics, race_type, domain_randomization)
        args = ["train", *_train_args(request, files), "--quiet", *_store_args(store)]
        if ray_address:
            args += ["--ray-address", ray_address]
        log = Path(log_folder or files.reward_function.parent) / f"{name}-training.log"
        with open(log, "wb") as out:
            process = subprocess.Popen(_laplab(*args, *extra_args), stdout=out, stderr=subprocess.STDOUT,
                                       stdin=subprocess.DEVNULL, env=_environment())
        return cls(name, process, log, store)

    def status(self) -> str:
        """``InProgress``, ``Completed``, ``Stopped`` or ``Failed`` (as SageMaker's DescribeTrainingJob)."""
        code = self.process.poll()
        if code is None:
            return RUNNING
        stopped = (-signal.SIGINT, -signal.SIGTERM, 128 + signal.SIGINT, 128 + signal.SIGTERM)
        return COMPLETED if code == 0 else STOPPED if code in stopped else FAILED

    def wait(self, timeout: float | None = None) -> str:
        """Wait for the job to end (or ``timeout`` seconds) and return its status."""
        try:
            self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            pass
        return self.status()

    def stop(self) -> str:
        """Ask the job to stop (as Ctrl-C: it keeps its last complete checkpoint) and wait for it."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        return self.wait()

    def output(self, lines: int = 20) -> str:
        """The last ``lines`` lines of the job's output (its error paragraph when it failed)."""
        text = self.log.read_text(errors="replace") if self.log.exists() else ""
        return "\n".join(text.splitlines()[-lines:])

    def metrics(self) -> list[dict[str, Any]]:
        """The rows of ``metrics/TrainingMetrics.json`` so far (one per training or evaluation-phase
        episode, DeepRacer's keys), or [] before the first iteration."""
        return training_metrics(self.name, self.store)

    def plot_metrics(self, window: int = 20):
        """DeepRacer's training chart: reward per episode (and its moving average), training and
        evaluation progress (%) per episode; a matplotlib Figure (a notebook shows it)."""
        from laplab.analysis.metrics_chart import training_metrics_figure
        return training_metrics_figure(self.metrics(), title=self.name, window=window)


def training_request(name: str, files: ModelFiles | None = None, track: str | list[str] | None = None,
                     max_time: str | float | None = None, workers: int = 1, physics: str | None = None,
                     race_type=None, domain_randomization: bool = False):
    """The :class:`~laplab.train.request.TrainRequest` of :meth:`TrainingJob.start`'s arguments,
    validated (files read, the track loaded); a bad value is a UserError naming the request's field."""
    from laplab.agents.hyperparameters import load_hyperparameters
    from laplab.env.metadata import load_model_metadata
    from laplab.train.config import parse_duration
    from laplab.train.request import TrainRequest
    values: dict[str, Any] = {"name": name, "workers": workers, "physics": physics,
                              "domain_randomization": domain_randomization}
    if track is not None:
        values["tracks" if not isinstance(track, str) else "track"] = track if isinstance(track, str) else tuple(track)
    if isinstance(max_time, str):
        try:
            values["max_time_s"] = parse_duration(max_time)
        except UserError as exc:
            raise type(exc)(str(exc), field="max_time_s") from None
    elif max_time is not None:
        values["max_time_s"] = max_time
    if race_type is not None:
        values["race_type"] = race_type.to_dict() if hasattr(race_type, "to_dict") else dict(race_type)
    if files is not None:
        values["reward_path"] = str(files.reward_function)
        values["model_metadata"] = load_model_metadata(files.model_metadata).to_dict()
        values["hyperparameters"] = load_hyperparameters(files.hyperparameters).to_dict()
    request = TrainRequest.from_mapping(values)
    request.validate()
    return request


def _train_args(request, files: ModelFiles) -> list[str]:
    """``laplab train`` options asking for ``request`` (its model files passed as the files)."""
    args = ["--name", request.name, "--reward", str(files.reward_function), "--model-metadata",
            str(files.model_metadata), "--hyperparameters", str(files.hyperparameters),
            "--max-time", f"{request.max_time_s:f}s", "--seed", str(request.seed)]
    for one in request.tracks or ((request.track,) if request.track else ()):
        args += ["--track", one]
    if request.workers not in (None, 1):
        args += ["--workers", str(request.workers)]
    if request.physics:
        args += ["--physics", request.physics]
    if request.race_type is not None:
        args += race_type_args(request.race_type)
    if request.domain_randomization:
        args.append("--domain-randomization")
    return args


def read_model_file(name: str, relative: str, store: str | None = None) -> bytes | None:
    """The bytes of ``relative`` (e.g. ``metrics/TrainingMetrics.json``) in model ``name``'s folder, or
    None when it does not exist yet."""
    if store:
        from laplab.store.remote import RemoteModels
        from laplab.store.s3 import ObjectMissing, ObjectStore, StoreError, parse_store_url
        try:
            return RemoteModels(ObjectStore(parse_store_url(store))).read(name, relative)
        except ObjectMissing:
            return None
        except StoreError as exc:
            raise UserError(str(exc)) from None
    from laplab.store.layout import model_folder
    path = model_folder(name).root / relative
    return path.read_bytes() if path.is_file() else None


def training_metrics(name: str, store: str | None = None) -> list[dict[str, Any]]:
    """The rows of model ``name``'s ``metrics/TrainingMetrics.json`` ([] before the first iteration)."""
    data = read_model_file(name, "metrics/TrainingMetrics.json", store)
    if data is None:
        return []
    try:
        return list(json.loads(data)["metrics"])
    except (ValueError, KeyError, TypeError):  # written atomically; a foreign file may still be bad
        raise UserError(f"model {name!r}: metrics/TrainingMetrics.json is not DeepRacer's metrics "
                        "JSON ({\"metrics\": [...]})") from None


def _run(args: list[str], what: str) -> tuple[str, dict]:
    """Run ``laplab ARGS``; (its printed output, its JSON outcome: :mod:`laplab.commands.outcome`).
    A refusal raises :class:`UserError` with the command's own message and field."""
    import tempfile

    from laplab.commands.outcome import RESULT_FILE_ENV
    with tempfile.TemporaryDirectory(prefix="laplab-api-") as scratch:
        result_file = Path(scratch) / "outcome.json"
        done = subprocess.run(_laplab(*args), capture_output=True, text=True, stdin=subprocess.DEVNULL,
                              env={**_environment(), RESULT_FILE_ENV: str(result_file)})
        try:
            outcome = json.loads(result_file.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            outcome = {}
    if done.returncode != 0:
        if outcome.get("error"):
            raise UserError(f"{what} failed: {outcome['error']}", field=outcome.get("field"))
        lines = (done.stderr.strip() or done.stdout.strip()).splitlines()  # a crash: its last words
        ours = [i for i, line in enumerate(lines) if line.startswith("laplab")]
        message = " ".join(lines[ours[0]:] if ours else lines[-6:]) or f"exit code {done.returncode}"
        raise UserError(f"{what} failed: {message}")
    return done.stdout, outcome


def evaluate(name: str, track: str | None = None, trials: int | None = None, store: str | None = None,
             extra_args: tuple[str, ...] = (), physics: str | None = None,
             domain_randomization: bool = False) -> dict[str, Any]:
    """Evaluate model ``name`` as ``laplab evaluate`` does (DeepRacer's trial rules, the car it trained
    with unless ``physics`` names another; kept in the model folder) and return its result: ``trials``
    (lap times, statuses, off-tracks; None: EvaluateRequest's default, 3), the summary, the ``car``.
    ``domain_randomization``: the camera sees training's domain randomisation (a camera model only).
    The settings are checked here first (:class:`~laplab.evaluate.trials.EvaluateRequest`: the
    console's messages and fields)."""
    from laplab.evaluate.trials import EvaluateRequest
    request = EvaluateRequest.from_mapping({"track": track, "physics": physics,
                                            "domain_randomization": domain_randomization,
                                            **({"trials": trials} if trials is not None else {})})
    args = ["evaluate", name, "--trials", str(request.trials), "--json", *_store_args(store), *extra_args]
    if physics:
        args += ["--physics", str(physics)]
    if track:
        args += ["--track", track]
    if request.domain_randomization:
        args.append("--domain-randomization")
    return json.loads(_run(args, f"evaluating {name!r}")[0])


def export_for_car(name: str, out: str | os.PathLike, store: str | None = None, checkpoint: str = "best") -> Path:
    """Write the car's model archive (``model.tar.gz``: ``agent/model.pb`` and ``model_metadata.json``,
    which the car's console uploads) for model ``name`` to ``out`` and return its path."""
    out = Path(out)
    _run(["export", name, "--format", "car", "--checkpoint", checkpoint, "--out", str(out), *_store_args(store)],
         f"exporting {name!r} for the car")
    if out.is_dir():
        archives = sorted(out.glob("*.tar.gz"), key=lambda p: p.stat().st_mtime)
        if not archives:
            raise UserError(f"exporting {name!r} for the car wrote no .tar.gz into {out}")
        return archives[-1]
    return out


def import_model(source: str | os.PathLike, name: str | None = None) -> str:
    """Add a model as ``laplab import`` does: a `laplab export` archive, or a DeepRacer model (a folder,
    ``.tar.gz`` or ``.zip`` of the console's / DeepRacer on AWS's layout, an ``s3://BUCKET/PREFIX`` that
    deepracer-for-cloud uploaded, a car's ``model.pb`` with its model_metadata.json beside it).
    Returns the new model's name; nothing is added when it fails (:class:`UserError`). The model's
    reward function is not trusted: training it asks for ``--trust-reward`` once (docs/import.md)."""
    text = str(source)
    args = ["import", text if text.startswith("s3://") else str(Path(text).resolve())]
    if name:
        args += ["--name", name]
    return str(_run(args, f"importing {text}")[1]["model"])


def race_type_args(race_type) -> list[str]:
    """``laplab train`` options for a :class:`~laplab.sim.race_type.RaceType` or its dict (validated here)."""
    from laplab.sim.race_type import RaceType, TIME_TRIAL
    race = race_type if isinstance(race_type, RaceType) else RaceType.from_dict(dict(race_type), "race_type")
    if race.kind == TIME_TRIAL:
        return []
    default = RaceType()
    args = ["--race-type", race.kind]
    names = {"objects": "--objects", "min_object_distance": "--min-object-distance", "object_type": "--object-type",
             "bots": "--bots", "bot_speed": "--bot-speed", "bot_lane": "--bot-lane",
             "min_bot_distance": "--min-bot-distance", "lane_change_min_s": "--lane-change-min",
             "lane_change_max_s": "--lane-change-max", "lane_change_distance": "--lane-change-distance",
             "collision_penalty": "--collision-penalty"}
    for name, option in names.items():
        if getattr(race, name) != getattr(default, name) and not (name == "objects" and race.object_positions):
            args += [option, str(getattr(race, name))]
    if race.object_positions:
        args += ["--object-positions", ";".join(f"{d!r},{lane}" for d, lane in race.object_positions)]
    for name, option in (("randomize_objects", "--randomize-objects"), ("randomize_bots", "--randomize-bots"),
                         ("lane_change", "--lane-change")):
        if getattr(race, name):
            args.append(option)
    return args
