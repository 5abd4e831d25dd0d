"""Where an iteration's "save" part goes: wall time of each listener call (the model folder's recorders)
and of each kind of file operation inside them, for a training job run for ``--budget`` seconds.

The trainer times an iteration in four parts (collect, learn, evaluate, save; ``bench/time_to_lap.py``
prints their shares); "save" is everything the listeners do after the evaluation laps. This script
wraps the listeners' ``on_episodes`` / ``on_checkpoint`` / ``on_iteration`` and the functions that
serialise, compress, write and fsync, and prints milliseconds per iteration for each (a nested
operation is counted in its own row and in its callers'). ``--wait`` also times how long the job's end
waits for the model folder's writes (laplab's background writer, when it has one).

Usage:
  python bench/save_profile.py [--console ppo-discrete | --sensor STATE] [--budget 60]
"""

from __future__ import annotations

import argparse
import collections
import functools
import os
import tempfile
import time
from dataclasses import replace

TIMES: dict[str, list[float]] = collections.defaultdict(list)


def timed(label: str, function):
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        started = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            TIMES[label].append(time.perf_counter() - started)
    return wrapper


def patch(owner, name: str, label: str) -> None:
    if hasattr(owner, name):
        setattr(owner, name, timed(label, getattr(owner, name)))


def instrument() -> None:
    """Wrap the file operations of the model folder's writes (before the job is built)."""
    import torch

    import laplab.store.atomic as atomic
    import laplab.store.checkpoints as checkpoints
    import laplab.store.metrics as metrics
    import laplab.store.robomaker_log as robomaker
    import laplab.store.simtrace as simtrace
    import laplab.train.resume_codec as codec
    import laplab.train.trainer as trainer
    try:
        import laplab.train.checkpoint_state as checkpoint_state  # where checkpoints are made (before: trainer)
    except ImportError:
        checkpoint_state = None

    patch(torch, "save", "torch.save (checkpoint + resume)")
    patch(os, "fsync", "os.fsync (all)")
    patch(codec, "pack_state", "pack_state (Adam moments, zstd)")
    for module in (trainer, checkpoint_state):  # the trainer's own names, and those its writers look up
        if module is not None:
            patch(module, "on_cpu", "on_cpu (weights to CPU, old code)")
            patch(module, "pack_state", "pack_state (Adam moments, zstd)")
            patch(module, "checkpoint_writer", "checkpoint_writer (state built)")
            patch(module, "resume_writer", "resume_writer (state built)")
    patch(checkpoints.CheckpointStore, "_write_records", "deepracer_checkpoints.json")
    patch(checkpoints.CheckpointStore, "_prune", "prune old checkpoints")
    patch(metrics.TrainingMetricsWriter, "append_training", "TrainingMetrics.json (training rows)")
    patch(metrics.TrainingMetricsWriter, "append_evaluation", "TrainingMetrics.json (evaluation rows)")
    patch(simtrace.SimtraceWriter, "write_rows", "simtrace CSV rows")
    patch(robomaker.RobomakerLogWriter, "write_iteration", "robomaker log")
    patch(atomic, "atomic_write_json", "atomic_write_json (all)")
    for module in (checkpoints, metrics):
        patch(module, "atomic_write_json", "atomic_write_json (all)")


def wrap_listeners(trainer) -> None:
    for listener in trainer._listeners:
        for event in ("on_episodes", "on_checkpoint", "on_iteration"):
            if getattr(listener, event, None) is not None:
                setattr(listener, event, timed(f"{type(listener).__name__}.{event}", getattr(listener, event)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--console", choices=("sac", "ppo-continuous", "ppo-discrete"))
    parser.add_argument("--sensor", default="STATE")
    parser.add_argument("--budget", type=float, default=60.0)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    os.environ.setdefault("LAPLAB_HOME", tempfile.mkdtemp(prefix="laplab-save-profile-"))
    instrument()
    from laplab.env.metadata import ModelMetadata
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training

    if args.console:
        from camera_steps import ROWS, console_metadata  # bench/camera_steps.py
        metadata = console_metadata(*ROWS[args.console])
    else:
        metadata = replace(ModelMetadata(), sensors=(args.sensor,)).to_dict()
    config = replace(TrainConfig(), track="classic_2018", seed=0, max_time_s=args.budget, model_metadata=metadata)
    trainer = create_training(f"save-profile-{int(time.time() * 1000) % 10**8}", config, device=args.device)
    TIMES.clear()  # checkpoint 0 is not an iteration's
    wrap_listeners(trainer)
    seconds: dict[str, float] = collections.defaultdict(float)
    trainer.run(callbacks=(lambda report: [seconds.__setitem__(k, seconds[k] + v)
                                           for k, v in report.seconds.items()],))
    started = time.perf_counter()
    trainer.close()
    closing = time.perf_counter() - started
    iterations = max(trainer.iteration, 1)
    total = sum(seconds.values()) or 1.0
    print(f"{iterations} iterations, {total:.1f} s timed; shares "
          + " ".join(f"{k} {v / total:.0%}" for k, v in seconds.items())
          + f"; save {1000 * seconds['save'] / iterations:.0f} ms per iteration; close {1000 * closing:.0f} ms; "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'operation':42s} {'calls':>6s} {'ms/iteration':>12s} {'ms/call':>8s} {'max ms':>7s}")
    for label, values in sorted(TIMES.items(), key=lambda item: -sum(item[1])):
        print(f"{label:42s} {len(values):6d} {1000 * sum(values) / iterations:12.1f} "
              f"{1000 * sum(values) / len(values):8.1f} {1000 * max(values):7.1f}")


if __name__ == "__main__":
    main()
