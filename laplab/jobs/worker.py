"""``python -m laplab.jobs.worker JOB_FOLDER``: run one console job (train, resume, clone, evaluate).

The worker reads ``spec.json`` from its folder, runs the job with laplab's library calls, and reports
only through files there (it cannot reach the database): ``events.jsonl`` gets one line per
iteration, ``poses.json`` the cars' poses at most 15 times a second, ``result.json`` the outcome.
A ``stop`` file in the folder (or SIGTERM) stops a training after the current step and keeps the
model, as Ctrl-C does on the CLI.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
import time
import traceback
from dataclasses import asdict, replace
from pathlib import Path

POSES_HZ = 15.0
CAMERA_HZ = 2.0


def camera_frame(obs):
    """The newest camera frame (120, 160) uint8 of the first car, or None for models without a camera
    (observations: ``(E, C, H, W)`` uint8, or a dict holding one such array per camera sensor)."""
    import numpy as np
    if isinstance(obs, dict):
        from laplab.env.metadata import CAMERA_SENSORS
        obs = next((v for k, v in obs.items() if k in CAMERA_SENSORS), None)
    if not isinstance(obs, np.ndarray) or obs.ndim != 4 or obs.dtype != np.uint8 or not len(obs):
        return None
    return obs[0, -1]


class JobFiles:
    """The files of one job folder, written atomically where a reader may look at any time."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.events = folder / "events.jsonl"
        self.poses = folder / "poses.json"
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

    def finish(self, status: str, **data) -> None:
        temporary = self.result.with_suffix(".tmp")
        temporary.write_text(json.dumps({"status": status, "t": time.time(), **data}))
        temporary.replace(self.result)


def _live_trainer_class():
    """A Trainer that also publishes the training cars' poses (an isolated per-step hook: it wraps
    the policy the trainer calls once per simulator step, and leaves the trainer's code alone)."""
    from laplab.train.trainer import Trainer

    class LiveTrainer(Trainer):
        pose_sink = None
        camera_sink = None
        _last_pose_time = 0.0
        _last_camera_time = 0.0
        _pose_seq = 0

        def _policy(self, deterministic: bool):
            act = super()._policy(deterministic)
            sim = self.eval_sim if deterministic else self.sim

            def act_and_publish(obs):
                now = time.monotonic()
                if self.pose_sink is not None and now - self._last_pose_time >= 1.0 / POSES_HZ:
                    self._last_pose_time = now
                    self._pose_seq += 1
                    st = sim.state
                    self.pose_sink({"seq": self._pose_seq, "t": time.time(), "evaluation": deterministic,
                                    "cars": [[round(float(x), 3), round(float(y), 3), round(float(h), 3)]
                                             for x, y, h in zip(st.x, st.y, st.yaw)]})
                if self.camera_sink is not None and not deterministic and now - self._last_camera_time >= 1.0 / CAMERA_HZ:
                    self._last_camera_time = now
                    frame = camera_frame(obs)
                    if frame is not None:
                        self.camera_sink(frame)
                return act(obs)
            return act_and_publish

    return LiveTrainer


def _new_trainer(name: str, config, init_weights=None):
    """:func:`laplab.train.jobs.create_training` for a folder the server made (empty) for this job."""
    from laplab.store.layout import model_folder
    from laplab.train.errors import JobError
    from laplab.train.jobs import load_and_validate_reward, reward_file
    from laplab.train.trainer import load_weights_only
    from laplab.track.registry import load_track

    folder = model_folder(name)
    if folder.exists() and any(folder.root.iterdir()):
        raise JobError(f"a model named {name!r} already exists; models are immutable")
    load_track(config.track)
    reward_fn = load_and_validate_reward(config)
    folder.create()
    folder.write_model_metadata(config.metadata().to_dict())
    folder.write_hyperparameters(config.hyper().to_dict())
    folder.write_reward_function(reward_file(config).read_text())
    folder.write_laplab_config(config.to_dict())
    trainer = _live_trainer_class()(folder, config, reward_fn)
    if init_weights is not None:
        load_weights_only(trainer.learner, init_weights)
    trainer.save_initial_checkpoint()
    return trainer


def _resumed_trainer(name: str, max_time_s: float | None):
    from laplab.train.jobs import resume_training
    trainer = resume_training(name, max_time_s)
    trainer.__class__ = _live_trainer_class()  # same state, plus the pose hook (no second simulator)
    return trainer


def _train(files: JobFiles, spec: dict) -> None:
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import clone_config

    kind, name, params = spec["kind"], spec["model"], spec["params"]
    if kind == "resume":
        trainer = _resumed_trainer(name, params.get("max_time_s"))
    else:
        reward_path = str(files.folder / "reward_function.py") if (files.folder / "reward_function.py").exists() else None
        values = {k: params[k] for k in ("track", "model_metadata", "hyperparameters", "max_time_s", "max_episodes", "seed")
                  if params.get(k) is not None}
        if reward_path:
            values["reward_path"] = reward_path
        if kind == "clone":
            config, weights = clone_config(params["source"], values)
            trainer = _new_trainer(name, config, init_weights=weights)
        else:
            trainer = _new_trainer(name, replace(TrainConfig(), **values))
    trainer.pose_sink = files.write_poses
    if trainer.metadata.camera is not None:
        trainer.camera_sink = files.write_camera
    files.event("started", iteration=trainer.iteration)

    def on_iteration(report) -> None:
        files.event("iteration", report=asdict(report))

    result = trainer.run(callbacks=(on_iteration,), should_stop=files.should_stop)
    summary = {"stop_reason": result.stop_reason, "iterations": result.iterations, "episodes": result.episodes,
               "env_steps": result.env_steps, "elapsed_s": result.elapsed_s, "best_lap_time": result.best_lap_time}
    if result.error:
        files.finish("failed", error=result.error, **summary)
    else:
        files.finish("done", **summary)


def _evaluate(files: JobFiles, spec: dict) -> None:
    from laplab.evaluate.trials import EvaluationSettings, evaluate_model
    params = spec["params"]
    allowed = ("track", "trials", "checkpoint", "off_track_penalty", "crash_penalty", "resets", "continuous",
               "max_trial_time", "video")
    settings = EvaluationSettings(**{k: params[k] for k in allowed if k in params})
    files.event("started")
    result, stamp = evaluate_model(spec["model"], settings)
    files.finish("done", stamp=stamp, summary=result.to_dict().get("summary"))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    files = JobFiles(Path(argv[0]))
    signal.signal(signal.SIGTERM, lambda *_: files.stop_requested.set())
    signal.signal(signal.SIGINT, lambda *_: files.stop_requested.set())
    from laplab.cli import user_error_types
    from laplab.evaluate.trials import EvaluationError
    try:
        spec = json.loads((files.folder / "spec.json").read_text())
        print(f"laplab job {spec['id']}: {spec['kind']} {spec['model']}", flush=True)
        if spec["kind"] == "evaluate":
            _evaluate(files, spec)
        else:
            _train(files, spec)
    except (*user_error_types(), EvaluationError, MemoryError) as exc:
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
