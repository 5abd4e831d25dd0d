"""Time to a model that laps: wall time from the start of training until the greedy policy completes
3 of 3 evaluation laps (run after every iteration), with the default reward and settings.

Prints, per track and sensor, the median over seeds of: wall time to 3/3 laps, iterations, env steps,
the best lap time reached by then, and training throughput (training env steps per wall second,
collection + learning + evaluation laps + checkpoints), with the share of the wall time each took.
``--min-time S`` keeps training for at least S seconds after the first 3/3, so the throughput is the
steady state's rather than the first iteration's; the row's ``end lap`` is then the mean greedy
evaluation lap of the last iteration whose laps all completed (from a standing start) and ``/opt`` its
ratio to the race line driven from rest.

``--console ROW`` trains with the DeepRacer console's files instead of laplab's defaults: front
camera, DEEP_CONVOLUTIONAL_NETWORK_SHALLOW, the console's hyperparameters (laplab's camera
``num_epochs`` 5), and ``sac`` (continuous -30..30 degrees x 1..4 m/s), ``ppo-continuous`` (the same
space) or ``ppo-discrete`` (laplab's 21-action grid). The issue-15 rows, for an idle machine:

  python bench/time_to_lap.py --tracks classic_2018 --seeds 0 --console sac --budget 900 --min-time 600
  python bench/time_to_lap.py --tracks classic_2018 --seeds 0 --console ppo-continuous --budget 900 --min-time 600
  python bench/time_to_lap.py --tracks classic_2018 --seeds 0 --console ppo-discrete --budget 900 --min-time 600

``--workers N`` collects on N rollout workers on Ray (a local Ray, or the cluster at ``--ray-address``)
and ``--device cuda`` puts the learner on a GPU, as ``laplab train`` does: issue 13's camera model on a
16-core machine with a GPU is

  python bench/time_to_lap.py --tracks classic_2018 --seeds 0 1 2 --console ppo-discrete --workers 14 --device cuda --budget 600

``--race oa3`` trains for DeepRacer's object avoidance with 3 fixed boxes (at 25 %, 50 % and 75 % of the
lap, inner, outer, inner lane) and ``--race h2b2`` for head-to-bot with 2 bots at 1 m/s; evaluation
laps end at a collision, so 3/3 laps is 3 laps without one (issue 32's rows, for an idle machine):

  python bench/time_to_lap.py --tracks classic_2018 --seeds 0 --race oa3 --budget 600
  python bench/time_to_lap.py --tracks classic_2018 --seeds 0 --race oa3 --sensor FRONT_FACING_CAMERA --budget 1800
  python bench/time_to_lap.py --tracks classic_2018 --seeds 0 --race h2b2 --budget 600

Usage:
  python bench/time_to_lap.py [--seeds 0 1 2] [--tracks classic_2018 ../shared/reference-tracks/reinvent_base.npy]
                              [--sensor STATE|FRONT_FACING_CAMERA] [--console sac|ppo-continuous|ppo-discrete]
                              [--budget 600] [--min-time 0]
                              [--precision auto|float32|bfloat16] [--hyperparameters '{"num_epochs": 5}']
                              [--workers 1] [--device cpu|cuda] [--ray-address ADDR] [--race oa3|h2b2]
                              [--reward reward_function.py] [--look track|old] [--domain-randomization]

``--look old`` trains a camera model on laplab's look from before DeepRacer's worlds (issue 30: a
camera model trained for 10 minutes on the new look laps as fast as on the old one), e.g.

  python bench/time_to_lap.py --tracks ../shared/reference-tracks/reinvent_base.npy --seeds 0 --sensor FRONT_FACING_CAMERA --budget 600 --min-time 600 --look old

``--domain-randomization`` trains with the camera's domain randomisation (the training option
``laplab train --domain-randomization`` sets; the row's model says ``DR``), issue 30's robust model:

  python bench/time_to_lap.py --tracks ../shared/reference-tracks/reinvent_base.npy --seeds 0 --sensor FRONT_FACING_CAMERA --budget 600 --min-time 600 --domain-randomization

The trained models stay in ``$LAPLAB_HOME`` (a new temporary folder when unset): set it to evaluate
them afterwards, e.g. under the domain randomisation with ``bench/randomized_laps.py`` (issue 30).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "reference-tracks"
DEFAULT_TRACKS = ["classic_2018", str(REFERENCE / "reinvent_base.npy"), str(REFERENCE / "2022_summit_speedway.npy")]


def race_for(label: str | None):
    """The race type of a ``--race`` label (None: a time trial)."""
    from laplab.sim.race_type import RaceType
    if label is None:
        return RaceType()
    return {"oa3": RaceType("object_avoidance", object_positions=((0.25, 1), (0.5, -1), (0.75, 1))),
            "h2b2": RaceType("head_to_bot", bots=2, bot_speed=1.0)}[label]


def time_to_lap(track: str, seed: int, sensor: str, budget_s: float, min_time_s: float = 0.0,
                precision: str = "auto", hyperparameters: dict | None = None, console: str | None = None,
                workers: int = 1, device: str = "cpu", ray_address: str | None = None, car: str = "",
                race: str | None = None, reward: str | None = None, domain_randomization: bool = False) -> dict:
    from laplab.cluster.launch import RayWorkers, uses_ray
    from laplab.env.metadata import ModelMetadata
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training

    if console is not None:
        from camera_steps import ROWS, console_metadata  # bench/camera_steps.py
        metadata = console_metadata(*ROWS[console])
    else:
        metadata = replace(ModelMetadata(), sensors=(sensor,)).to_dict()
    config = replace(TrainConfig(), track=track, seed=seed, max_time_s=budget_s, model_metadata=metadata,
                     precision=precision, workers=workers, vehicle=car, race_type=race_for(race),
                     reward_path=str(Path(reward).resolve()) if reward else None,
                     domain_randomization=domain_randomization)
    if hyperparameters:
        config = replace(config, hyperparameters={**config.hyper().to_dict(), **hyperparameters})
    name = f"bench-{Path(track).stem.replace('_', '-')}-{seed}-{int(time.time() * 1000) % 10**8}"
    starting = time.perf_counter()  # its workers start before the clock, as `laplab train` starts them
    trainer = create_training(name, config, device=device, launcher=RayWorkers(ray_address))
    if uses_ray(workers, ray_address):
        print(f"(seed {seed}: {workers} rollout workers started in {time.perf_counter() - starting:.1f} s with the "
              "model folder, before the clock)", flush=True)
    first: dict = {}
    end: dict = {}
    seconds: dict[str, float] = {}

    def on_iteration(report) -> None:
        for key, value in report.seconds.items():
            seconds[key] = seconds.get(key, 0.0) + value
        if report.eval_episodes and report.eval_completed == report.eval_episodes:
            end.update(lap=report.eval_lap_time)
        if not first and report.eval_episodes and report.eval_completed == report.eval_episodes:
            first.update(wall=report.elapsed_s, iterations=report.iteration, steps=report.env_steps,
                         lap=report.eval_lap_time, best=report.best_lap_time)

    started = time.perf_counter()
    done = lambda: bool(first) and time.perf_counter() - started >= min_time_s
    with trainer:  # the workers stop with it
        result = trainer.run(callbacks=(on_iteration,), should_stop=done)
    elapsed = time.perf_counter() - started
    total = sum(seconds.values()) or 1.0
    return {"car": trainer.config.car, "lapped": bool(first), "wall": first.get("wall", float("nan")), "iterations": first.get("iterations", result.iterations),
            "steps": first.get("steps", result.env_steps), "eval_lap": first.get("lap"), "end_lap": end.get("lap"),
            "throughput": result.env_steps / max(elapsed, 1e-9), "trained_steps": result.env_steps,
            "shares": {key: value / total for key, value in seconds.items()}}


def standing_optimum(track: str, car: str) -> float:
    """The race line's lap time from rest, s (what a standing-start evaluation lap can reach), for ``car``
    (the run's: :attr:`TrainConfig.car`)."""
    from laplab.track.raceline_cache import standing_start_optimal_lap_time
    from laplab.track.registry import load_track
    from laplab.vehicle.params import vehicle_preset
    return standing_start_optimal_lap_time(load_track(track), vehicle_preset(car))


def use_old_look() -> None:
    """Camera models in this process see laplab's look from before DeepRacer's worlds (the panelled
    room, :func:`laplab.sensors.texture.build_track_texture`'s defaults) instead of the track's look:
    the observation builder asks :func:`laplab.sensors.look.texture_for_track` when it is built."""
    import laplab.sensors.look as look
    from laplab.sensors.texture import build_track_texture
    look.texture_for_track = lambda track, name=None, extra_palettes=(), **changes: build_track_texture(
        track, extra_palettes=extra_palettes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--tracks", nargs="+", default=DEFAULT_TRACKS)
    parser.add_argument("--sensor", default="STATE")
    parser.add_argument("--budget", type=float, default=600.0, help="give up after this many seconds per run")
    parser.add_argument("--min-time", type=float, default=0.0, help="train at least this many seconds")
    parser.add_argument("--precision", default="auto")
    parser.add_argument("--hyperparameters", default="{}", help="JSON of hyperparameters to override")
    parser.add_argument("--console", choices=("sac", "ppo-continuous", "ppo-discrete"),
                        help="train with the console's files (front camera, SHALLOW network); see above")
    parser.add_argument("--workers", type=int, default=1, help="rollout workers on Ray (1: in-process)")
    parser.add_argument("--device", default="cpu", help="the learner's torch device: cpu or cuda")
    parser.add_argument("--ray-address", default=None, help="join this Ray cluster (default: a local Ray)")
    parser.add_argument("--physics", default=None, help="the car: 4, 5, 6 or classic (default: the model's version)")
    parser.add_argument("--race", choices=("oa3", "h2b2"), default=None,
                        help="oa3: object avoidance, 3 fixed boxes; h2b2: head-to-bot, 2 bots at 1 m/s")
    parser.add_argument("--reward", default=None, help="reward_function.py (default: laplab's)")
    parser.add_argument("--look", choices=("track", "old"), default="track",
                        help="the camera's world: the track's DeepRacer look (default) or laplab's old panelled "
                             "room (issue 30's comparison; in-process training only)")
    parser.add_argument("--domain-randomization", action="store_true",
                        help="train with the domain randomisation (as `laplab train --domain-randomization`)")
    args = parser.parse_args()
    if args.look == "old":
        use_old_look()
    from laplab.vehicle.physics import resolve_physics
    car = resolve_physics(args.physics) if args.physics else ""
    from laplab.cluster.launch import resolve_device, uses_ray
    from laplab.train.errors import JobError
    try:
        device = resolve_device(args.device)
    except JobError as error:
        raise SystemExit(f"time_to_lap.py: {error}") from None
    label = f"camera {args.console}" if args.console else args.sensor
    if car:
        label += f" {car}"
    if uses_ray(args.workers, args.ray_address):
        label += f" x{args.workers}"
    if device != "cpu":
        label += f" {device}"
    if args.race:
        label += f" {args.race}"
    if args.look == "old":
        label += " old look"
    if args.domain_randomization:
        label += " DR"
    os.environ.setdefault("LAPLAB_HOME", tempfile.mkdtemp(prefix="laplab-bench-"))
    print(f"{'track':28s} {'model':20s} {'lapped':>6s} {'time to 3/3 s':>13s} {'iters':>5s} "
          f"{'env steps':>9s} {'eval lap s':>10s} {'end lap s':>9s} {'/opt':>5s} {'steps/s':>8s}  time shares")
    for track in args.tracks:
        if track.endswith(".npy") and not Path(track).is_file():
            print(f"{Path(track).name:28s} skipped: file not found")
            continue
        runs = [time_to_lap(track, seed, args.sensor, args.budget, args.min_time, args.precision,
                            json.loads(args.hyperparameters), args.console, args.workers, device,
                            args.ray_address, car, args.race, args.reward, args.domain_randomization)
                for seed in args.seeds]
        lapped = [r for r in runs if r["lapped"]]
        med = lambda key: statistics.median(r[key] for r in lapped) if lapped else float("nan")
        laps = [r["eval_lap"] for r in lapped if r["eval_lap"]]
        end_laps = [r["end_lap"] for r in runs if r["end_lap"]]
        end_lap = statistics.median(end_laps) if end_laps else float("nan")
        optimum = standing_optimum(track, runs[0]["car"]) if end_laps else float("nan")
        print(f"{Path(track).stem:28s} {label:20s} {len(lapped)}/{len(runs):<4d} {med('wall'):13.1f} "
              f"{med('iterations'):5.0f} {med('steps'):9.0f} {statistics.median(laps) if laps else float('nan'):10.2f} "
              f"{end_lap:9.2f} {end_lap / optimum:5.2f} "
              f"{statistics.median(r['throughput'] for r in runs):8.0f}  "
              + " ".join(f"{key} {statistics.median(r['shares'].get(key, 0.0) for r in runs):.0%}"
                         for key in runs[0]["shares"]))
        print(f"{'':28s} env steps trained: {' '.join(str(r['trained_steps']) for r in runs)} (per seed)")


if __name__ == "__main__":
    main()
