"""Rollout workers on Ray against in-process collection: env steps per second of the collection step.

For each sensor (STATE, FRONT_FACING_CAMERA) it times the trainer's collection of an iteration
(``num_episodes_between_training`` episodes, the same total cars everywhere) with the same, untrained
weights (no learning between iterations, so every variant drives the same policy):

- ``in-process``: today's path (one batched simulator in the learner's process);
- ``ray x1``: one rollout worker on Ray (the overhead: weights through the object store, episodes
  back, the merge);
- ``ray xN``: N workers sharing the cars (scaling; on a 2-core machine only 1 -> 2 means anything).

Two warm-up iterations per variant are not timed (process start, JIT compilation). Prints env steps/s,
the Ray x1 / in-process ratio and the parallel efficiency (steps/s of N workers / (N x steps/s of 1)).

Ray's cost is fixed per iteration (about 13 ms on the 2-core host), so the ratio depends on how long
the iteration's episodes are: an untrained policy crashes within ~15 steps, the worst case. With
``--trained-seconds S`` every variant drives the weights of a policy first trained in-process for S
seconds instead (episodes as a training has them after its first minutes).

With ``--training-seconds S`` it times whole training instead, as a user's job runs: ``Trainer.run``
for S seconds (collection, PPO's learning, the evaluation laps, checkpoints, logs) from the same seed,
after the same two warm-up collections, and prints training env steps per wall second up to the end
of the last whole iteration. Each run's
policy learns from its own episodes, so the variants drive different episodes; alternate several
runs (``--repeats``) and compare medians.

Usage:
  python bench/scaleout.py [--sensors STATE FRONT_FACING_CAMERA] [--workers 1 2] [--iterations 3]
                           [--episodes 20] [--trained-seconds 0] [--ray-address ADDR]
                           [--training-seconds 0] [--repeats 1]
"""

from __future__ import annotations

import argparse
import logging
import os
import tempfile
import time
from dataclasses import replace


def make_trainer(name: str, sensor: str, episodes: int, workers: int | None, weights: dict | None = None,
                 max_time_s: float = 20 * 60.0, ray_address: str | None = None):
    """A training of ``sensor`` with ``episodes`` per iteration, collected by ``workers`` rollout workers
    on Ray (even one; None: in-process); ``weights``: its policy network's to start with. Close it after."""
    from laplab.cluster.launch import RayWorkers
    from laplab.env.metadata import ModelMetadata
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training

    metadata = replace(ModelMetadata(), sensors=(sensor,)).to_dict()
    base = replace(TrainConfig(), model_metadata=metadata, max_time_s=max_time_s)
    hyper = {**base.hyper().to_dict(), "num_episodes_between_training": episodes}
    launcher = None if workers is None else RayWorkers(ray_address, ray_for_one=True)
    trainer = create_training(name, replace(base, hyperparameters=hyper, workers=workers or 1), launcher=launcher)
    if weights is not None:
        trainer.learner.policy_network.load_state_dict(weights)
    return trainer


def trained_weights(sensor: str, episodes: int, seconds: float) -> dict:
    """The policy network's weights after ``seconds`` of in-process training."""
    with make_trainer(f"pretrain-{sensor.lower().replace('_', '-')}", sensor, episodes, None,
                      max_time_s=seconds) as trainer:
        result = trainer.run()
    print(f"{sensor:20s} pre-trained {result.iterations} iterations in {seconds:g} s", flush=True)
    return {k: v.clone() for k, v in trainer.learner.policy_network.state_dict().items()}


def steps_per_second(trainer, iterations: int) -> tuple[float, float, dict[str, float]]:
    """(env steps per wall second of the collection step, the share of that wall time the slowest
    worker spent driving: the rest is Ray's overhead, broadcast, transfer and merge; the mean ms per
    iteration of each part of the collector's ``last_timing`` with workers, and ``per_step``: ms of
    wall time per batched simulator step, which the episodes' random lengths disturb less than env
    steps/s)."""
    warm_up(trainer)
    steps, batched, driving, started, parts = 0, 0, 0.0, time.perf_counter(), {}
    for _ in range(iterations):
        batch = collect(trainer)
        steps += batch.env_steps
        batched += batch.valid.shape[0]
        driving += batch.wall_seconds
        for part, seconds in (trainer.collector.last_timing if trainer.collector is not None else {}).items():
            parts[part] = parts.get(part, 0.0) + 1000 * seconds / iterations
    wall = time.perf_counter() - started
    parts["per_step"] = 1000 * wall / batched
    return steps / wall, driving / wall, parts


def collect(trainer):
    """One collection step, as the trainer's loop runs it: the episode count moves the workers'
    round-robin starts on."""
    batch = trainer._collect(lambda: False, time.perf_counter())
    trainer.episodes += len(batch.status)
    return batch


def warm_up(trainer) -> None:
    """Two collections, not timed: JIT compilation, first frames, the allocator (a first iteration is
    not enough for camera)."""
    for _ in range(2):
        collect(trainer)


class IterationEnds:
    """Listener: the wall time and env step count at the end of each whole (not time-cut) iteration."""

    def __init__(self) -> None:
        self.ends: list[tuple[float, int]] = []

    def on_iteration(self, report) -> None:
        if not report.partial:
            self.ends.append((time.perf_counter(), report.env_steps))


def training_steps_per_second(trainer) -> tuple[float, int]:
    """(training env steps per wall second of ``trainer.run()`` after :func:`warm_up`, whole iterations),
    counted up to the end of the last whole iteration: the time limit's cut iteration (its episodes
    dropped) would otherwise weigh by where it fell, a fifth of a minute's run for a camera iteration."""
    warm_up(trainer)
    ends = IterationEnds()
    trainer.subscribe(ends)
    steps, started = trainer.env_steps, time.perf_counter()
    trainer.run()
    if not ends.ends:
        raise SystemExit(f"no whole iteration in {trainer.config.max_time_s:g} s: give --training-seconds more")
    finished, last_steps = ends.ends[-1]
    return (last_steps - steps) / (finished - started), len(ends.ends)


def compare_training(sensor: str, args) -> None:
    """Whole training, in-process against Ray x1 (and xN), ``args.repeats`` alternated runs each."""
    from statistics import median

    figures: dict = {}
    for repeat in range(args.repeats):
        for workers in ["in-process", *args.workers]:
            label = workers if workers == "in-process" else f"ray x{workers}"
            name = f"train-{repeat}-{workers}-{sensor.lower().replace('_', '-')}"
            with make_trainer(name, sensor, args.episodes, None if workers == "in-process" else workers,
                              max_time_s=args.training_seconds, ray_address=args.ray_address) as trainer:
                rate, iterations = training_steps_per_second(trainer)
            figures.setdefault(workers, []).append(rate)
            print(f"{sensor:20s} run {repeat} {label:11s} {rate:9.1f} training env steps/s "
                  f"({iterations} whole iterations in a {args.training_seconds:g} s job)", flush=True)
    base = median(figures["in-process"])
    for workers in args.workers:
        print(f"{sensor:20s} training: ray x{workers} / in-process = {median(figures[workers]) / base:.2f} "
              f"(medians of {args.repeats}: {median(figures[workers]):.1f} / {base:.1f} env steps/s)", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensors", nargs="+", default=["STATE", "FRONT_FACING_CAMERA"])
    parser.add_argument("--workers", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=20, help="episodes (cars) per iteration, all variants")
    parser.add_argument("--trained-seconds", type=float, default=0.0,
                        help="drive a policy first trained in-process this long (0: untrained weights)")
    parser.add_argument("--ray-address", default=None)
    parser.add_argument("--training-seconds", type=float, default=0.0,
                        help="time whole training runs of this many seconds instead of the collection step")
    parser.add_argument("--repeats", type=int, default=1, help="alternated training runs per variant")
    args = parser.parse_args()
    os.environ.setdefault("LAPLAB_HOME", tempfile.mkdtemp(prefix="laplab-scaleout-"))

    import ray

    from laplab.cluster.collector import connect_ray

    started_ray = connect_ray(args.ray_address, max(args.workers))
    print(f"cpus {os.cpu_count()}, ray cluster cpus {ray.cluster_resources().get('CPU')}, "
          f"{args.episodes} cars per iteration, {args.iterations} timed iterations", flush=True)
    for sensor in args.sensors:
        if args.training_seconds > 0:
            compare_training(sensor, args)
            continue
        figures = {}
        weights = trained_weights(sensor, args.episodes, args.trained_seconds) if args.trained_seconds > 0 else None
        name = f"inproc-{sensor.lower().replace('_', '-')}"
        with make_trainer(name, sensor, args.episodes, None, weights) as trainer:
            figures["in-process"], share, parts = steps_per_second(trainer, args.iterations)
        per_step = {"in-process": parts["per_step"]}
        print(f"{sensor:20s} in-process  {figures['in-process']:9.1f} env steps/s (driving {share:.0%}; "
              f"{per_step['in-process']:.2f} ms per batched step)", flush=True)
        for workers in args.workers:
            with make_trainer(f"ray{workers}-{sensor.lower().replace('_', '-')}", sensor, args.episodes, workers,
                              weights, ray_address=args.ray_address) as trainer:
                figures[workers], share, parts = steps_per_second(trainer, args.iterations)
            per_step[workers] = parts.pop("per_step")
            print(f"{sensor:20s} ray x{workers:<5d} {figures[workers]:9.1f} env steps/s (driving {share:.0%}; "
                  f"{per_step[workers]:.2f} ms per batched step; ms per iteration: "
                  f"{', '.join(f'{part} {ms:.1f}' for part, ms in parts.items())})", flush=True)
        if 1 in figures:
            print(f"{sensor:20s} overhead: ray x1 / in-process = {figures[1] / figures['in-process']:.2f} "
                  f"(per batched step: {per_step['in-process'] / per_step[1]:.2f})")
            for workers in args.workers:
                if workers > 1:
                    print(f"{sensor:20s} scaling 1 -> {workers}: {figures[workers] / figures[1]:.2f}x, "
                          f"parallel efficiency {figures[workers] / (workers * figures[1]):.0%}")
    if started_ray:
        ray.shutdown()


if __name__ == "__main__":
    logging.getLogger("ray").setLevel(logging.ERROR)
    main()
