"""``python -m laplab.jobs.worker JOB_FOLDER``: run one console job (train, resume, clone, evaluate,
export for the car, a head-to-model race).

The worker reads ``spec.json`` from its folder, runs the job with laplab's library calls, and reports
only through files there (it cannot reach the database): ``events.jsonl`` gets one line per
iteration, ``poses.json`` the cars' poses at most 15 times a second, ``result.json`` the outcome.
A ``stop`` file in the folder (or SIGTERM) stops a training after the current step and keeps the
model, as Ctrl-C does on the CLI; it ends a race within a simulated step, keeping the race so far.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
import time
import traceback
from dataclasses import asdict, fields
from pathlib import Path

POSES_HZ = 15.0
CAMERA_HZ = 2.0


class JobFiles:
    """The files of one job folder, written atomically where a reader may look at any time."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.events = folder / "events.jsonl"
        self.poses = folder / "poses.json"
        self.obstacles = folder / "obstacles.json"
        self.result = folder / "result.json"
        self.stop_requested = threading.Event()
        self._stop_file = folder / "stop"
        self._last_check = 0.0

    def should_stop(self) -> bool:
        """A signal, or the server's stop file (looked for at most 10 times a second)."""
        if self.stop_requested.is_set():
            return True
        now = time.monotonic()
        if now - self._last_check >= 0.1:
            self._last_check = now
            if self._stop_file.exists():
                self.stop_requested.set()
        return self.stop_requested.is_set()

    def event(self, kind: str, **data) -> None:
        with open(self.events, "a", encoding="utf-8") as out:
            out.write(json.dumps({"type": kind, "t": time.time(), **data}) + "\n")

    def write_camera(self, frame) -> None:
        from PIL import Image
        temporary = self.folder / "camera.tmp.png"
        Image.fromarray(frame).save(temporary)
        temporary.replace(self.folder / "camera.png")

    def write_poses(self, document: dict) -> None:
        temporary = self.poses.with_suffix(".tmp")
        temporary.write_text(json.dumps(document))
        temporary.replace(self.poses)

    def write_obstacles(self, document: dict) -> None:
        temporary = self.obstacles.with_suffix(".tmp")
        temporary.write_text(json.dumps(document))
        temporary.replace(self.obstacles)

    def finish(self, status: str, **data) -> None:
        temporary = self.result.with_suffix(".tmp")
        temporary.write_text(json.dumps({"status": status, "t": time.time(), **data}))
        temporary.replace(self.result)


class LiveFeed:
    """A trainer listener for the console's live view: the training cars' poses (model origins, x m,
    y m, yaw rad) at up to 15 Hz and, for camera models, car 0's grey camera frame at 2 Hz (with its
    race's boxes and bots). In a race with obstacles, the poses carry the driving ones (``objects``:
    head-to-bot's bots, each with the index of the car whose episode it drives in) and
    ``obstacles.json`` the standing ones (boxes), rewritten only when they change
    (:func:`laplab.sim.obstacles.footprint_rows`)."""

    def __init__(self, files: JobFiles, trainer):
        self.files = files
        self.camera = None
        if trainer.metadata.camera is not None:
            from laplab.sensors.camera import camera_for_sensor
            self.camera = camera_for_sensor(trainer.metadata.camera)[0]
            self.track = trainer.track
            self._texture = None
        self._last_pose_time = self._last_camera_time = 0.0
        self._seq = self._obstacles_seq = 0
        self._standing = None

    def on_poses(self, frame) -> None:
        now = time.monotonic()
        if now - self._last_pose_time >= 1.0 / POSES_HZ:
            self._last_pose_time = now
            self._seq += 1
            document = {"seq": self._seq, "t": time.time(), "evaluation": bool(frame.evaluation),
                        "cars": [[round(float(x), 3), round(float(y), 3), round(float(h), 3)]
                                 for x, y, h in frame.poses]}
            if frame.obstacles is not None:
                from laplab.sim.obstacles import footprint_rows
                standing, document["objects"] = footprint_rows(frame.obstacles, frame.obstacles_move)
                if standing != self._standing:
                    self._standing, self._obstacles_seq = standing, self._obstacles_seq + 1
                    self.files.write_obstacles({"seq": self._obstacles_seq, "boxes": standing})
            self.files.write_poses(document)
        if self.camera is not None and now - self._last_camera_time >= 1.0 / CAMERA_HZ:
            self._last_camera_time = now
            from laplab.sensors.camera import render_camera
            if self._texture is None:
                from laplab.sensors.look import texture_for_track
                self._texture = texture_for_track(self.track)
            obstacles = frame.obstacles.rows([0]) if frame.obstacles is not None else None
            self.files.write_camera(render_camera(self._texture, frame.poses[:1], self.camera, obstacles=obstacles)[0])


class PhaseFeed:
    """A trainer listener: where the running iteration stands (the trainer's PhaseProgress, about
    once a second: episodes collected, in-process or by Ray workers, then gradient steps, then
    evaluation laps) as ``phase`` lines of ``events.jsonl``."""

    def __init__(self, files: JobFiles):
        self.files = files

    def on_progress(self, progress) -> None:
        self.files.event("phase", **asdict(progress))


def _train(files: JobFiles, spec: dict) -> None:
    from laplab.train.jobs import clone_config, create_training_in_place, resume_training
    from laplab.train.request import TrainRequest

    kind, name, params = spec["kind"], spec["model"], spec["params"]
    cluster = spec.get("cluster")  # a console started with --ray-address: rollout workers on Ray
    workers = int(params.get("workers") or cluster.get("workers") or 1) if cluster else 1
    if params.get("workers") and not cluster:
        print(f"this console has no Ray cluster now: the job collects in-process, not with {params['workers']} "
              "rollout workers", flush=True)
    from laplab.jobs.supervisor import job_limits, report
    from laplab.reward.watchdog import RewardWatchdog, WatchdogLimits
    limits = job_limits()
    watch = WatchdogLimits(limits.reward_timeout_s, limits.reward_wait_timeout_s)
    launcher = None
    if cluster:  # the workers start once the folder is written, and stop when the trainer is closed
        from laplab.cluster.console import job_workers
        launcher = job_workers(cluster, lambda message: print(message, flush=True), watch)
    if kind == "resume":
        # an imported model's reward needs trust to run: in the console's sandbox it runs confined like
        # every user's reward (the trust rule guards a CLI user's own account); unconfined, it does not
        trainer = resume_training(name, params.get("max_time_s"), workers=workers,
                                  trust_reward=bool(spec.get("sandboxed")), launcher=launcher)
    else:
        reward_path = str(files.folder / "reward_function.py") if (files.folder / "reward_function.py").exists() else None
        given = {k: v for k, v in params.items() if k != "source"}
        request = TrainRequest.from_mapping({**given, "reward_path": reward_path, "workers": workers})
        if kind == "clone":  # the source's config, changed where the request says so
            values = request.config_values()
            changed = {*given, "workers", *(("reward_path",) if reward_path else ())} & set(values)
            config, weights = clone_config(params["source"], {k: values[k] for k in changed})
            trainer = create_training_in_place(name, config, init_weights=weights, launcher=launcher)
        else:
            trainer = create_training_in_place(name, request.to_config(), launcher=launcher)
    with trainer:  # its rollout workers (if any) stop and the folder's lock is released when the job ends
        # as `laplab train` does: reward output beyond the cap goes to the model folder's log from here on
        report(folder=str(trainer.folder.root), model=name, what="training job", iteration=trainer.iteration)
        trainer.subscribe(LiveFeed(files, trainer))
        trainer.subscribe(PhaseFeed(files))
        files.event("started", iteration=trainer.iteration)

        def on_iteration(report) -> None:
            files.event("iteration", report=report.to_dict())

        with RewardWatchdog(watch):  # the per-step limit on reward calls, as on the command line
            result = trainer.run(callbacks=(on_iteration,), should_stop=files.should_stop)
    summary = {"stop_reason": result.stop_reason, "iterations": result.iterations, "episodes": result.episodes,
               "env_steps": result.env_steps, "elapsed_s": result.elapsed_s, "best_lap_time": result.best_lap_time}
    from laplab.jobs.sandbox import reward_output_summary
    held_back = reward_output_summary()
    if held_back:
        print(held_back, flush=True)
    if result.error:
        files.finish("failed", error=result.error, **summary)
    else:
        files.finish("done", **summary)


def _evaluate(files: JobFiles, spec: dict) -> None:
    from laplab.evaluate.trials import EvaluateRequest, evaluate_model
    allowed = tuple(f.name for f in fields(EvaluateRequest) if f.name != "force")  # the console keeps 1..5 trials
    settings = EvaluateRequest.from_mapping(spec["params"], allowed)
    files.event("started")
    cluster = spec.get("cluster")  # a console started with --ray-address: the laps are driven on a Ray node
    if cluster:
        from laplab.cluster.evaluations import evaluate_model_on_ray
        from laplab.jobs.supervisor import job_limits
        result, stamp, where = evaluate_model_on_ray(spec["model"], settings, cluster["address"],
                                                     lambda message: print(message, flush=True), files.should_stop,
                                                     priority=job_limits().evaluation_priority)
        files.finish("done", stamp=stamp, summary=result.to_dict().get("summary"), driven_on=where)
        return
    result, stamp = evaluate_model(spec["model"], settings)
    files.finish("done", stamp=stamp, summary=result.to_dict().get("summary"))


def _duel(files: JobFiles, spec: dict) -> None:
    """A head-to-model race (:class:`~laplab.train.request.RaceRequest`), the same code as ``laplab
    race``: its race.json, top-down picture (and video) go to the job folder's ``race/``. The stop
    file (or SIGTERM) ends the race within a simulated step: it finishes ``done`` with
    ``stop_reason`` ``stopped`` and the race as far as it went (race.json, picture; no video)."""
    from laplab.evaluate.race_run import run_model_race
    from laplab.train.request import RaceRequest
    request = RaceRequest.from_mapping(spec["params"])
    if request.models[0] != spec["model"]:
        raise ValueError(f"a race job of {spec['model']!r} races {request.models[0]!r} first")
    files.event("started", models=list(request.models))
    result = run_model_race(request, files.folder / "race", should_stop=files.should_stop)
    files.finish("done", order=[r.name for r in result.racers], duration=float(result.clock[-1]),
                 stop_reason="stopped" if result.stopped else None)


EXPORT_FORMATS = ("car", "console")
TENSORFLOW_MISSING = ("the car's format needs TensorFlow on the console's machine ({}): install it there with "
                      "`pip install 'laplab[deepracer]'` (tensorflow-cpu, openvino) and restart `laplab serve`.")


class ExportJobError(ValueError):
    """An export that cannot be made, with the message for the model's page."""


def _export(files: JobFiles, spec: dict) -> None:
    """The car's tar.gz (``agent/model.pb`` + ``model_metadata.json``) or the DeepRacer console's
    import layout (as a tar.gz), built from the model's checkpoint with TensorFlow into ``export/``."""
    import tarfile
    from laplab.train.request import ExportRequest
    name, request = spec["model"], ExportRequest.from_mapping(spec["params"]).as_job()
    fmt, checkpoint = request.format, request.checkpoint
    from laplab.export.car import CAR_SENSORS, CONSOLE_SENSORS, CarExportError, check_model_exportable
    try:  # a model the car cannot run is refused before TensorFlow and torch load (seconds each)
        check_model_exportable(name, *((CAR_SENSORS, "the DeepRacer car") if fmt == "car"
                                       else (CONSOLE_SENSORS, "the DeepRacer console")))
    except CarExportError as exc:
        raise ExportJobError(str(exc)) from None
    try:
        import tensorflow  # noqa: F401  (fail early, with the install line)
        from laplab.export.car import export_car
        from laplab.export.console import export_console
    except ImportError as exc:
        raise ExportJobError(TENSORFLOW_MISSING.format(exc)) from None
    out = files.folder / "export"
    out.mkdir(exist_ok=True)
    files.event("started", format=fmt)
    try:
        if fmt == "car":
            path, graph = export_car(name, checkpoint, out / f"{name}.tar.gz")
        else:
            result = export_console(name, checkpoint, out / f"{name}-console")
            graph, path = result.graph, out / f"{name}-console.tar.gz"
            with tarfile.open(path.with_suffix(".tmp"), "w:gz") as tar:
                tar.add(result.folder, arcname=f"{name}-console")
            path.with_suffix(".tmp").replace(path)
    except (CarExportError, FileNotFoundError) as exc:
        raise ExportJobError(str(exc)) from None
    files.finish("done", format=fmt, file=path.name, size=path.stat().st_size, checkpoint=graph.checkpoint,
                 parity_error=graph.parity_error)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    from laplab.jobs.supervisor import enter_job_from_environment
    # the limits, death with the server, the os._exit guard and the reward output cap of a supervised
    # CLI job (the server sets LAPLAB_JOB_LIMITS: laplab.jobs.runner)
    enter_job_from_environment()
    files = JobFiles(Path(argv[0]))
    signal.signal(signal.SIGTERM, lambda *_: files.stop_requested.set())
    signal.signal(signal.SIGINT, lambda *_: files.stop_requested.set())
    from laplab.cli import user_error_types
    from laplab.evaluate.trials import EvaluationError
    try:
        spec = json.loads((files.folder / "spec.json").read_text())
        from laplab.jobs.priority import describe_priority
        print(f"laplab job {spec['id']}: {spec['kind']} {spec['model']} (CPU: {describe_priority()})", flush=True)
        if spec["kind"] == "evaluate":
            _evaluate(files, spec)
        elif spec["kind"] == "export":
            _export(files, spec)
        elif spec["kind"] == "duel":
            _duel(files, spec)
        else:
            _train(files, spec)
    except (*user_error_types(), EvaluationError, ExportJobError, MemoryError) as exc:
        message = str(exc) if not isinstance(exc, MemoryError) else "the job ran out of its memory limit"
        print(message, file=sys.stderr, flush=True)
        files.finish("failed", error=message)
        return 1
    except Exception as exc:  # noqa: BLE001 - anything else: logged with its traceback, reported in one line
        traceback.print_exc()
        files.finish("failed", error=f"{type(exc).__name__}: {exc} (see the job log)")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
