"""How fast does the default model lap? Lap time / optimal after 5 and 20 minutes of STATE training.

Trains the default model (default reward, action space and hyperparameters, STATE sensor) on a track
for the largest of --minutes, keeps the best checkpoint as it stood at each mark, then evaluates each
as `laplab evaluate` does: 3 trials from a standing start (greedy), and 3 continuous laps (laps 2-3
are flying). Prints, per mark, the median over seeds of:

- `rest lap`: best lap of the standing-start trials, s, and its ratio to the race line's flying lap
  (`/flying`) and to the race line driven from rest (`/standing`, the physical limit of such a lap);
- `flying lap`: best of the continuous run's laps, s, and its ratio to the flying optimum.

Seeds run in parallel processes with --jobs (STATE training uses one core each; camera training
uses every core, so give camera runs --jobs 1).

Usage:
  python bench/lap_quality.py [--seeds 0 1 2] [--minutes 5 20] [--track classic_2018] [--jobs 2]
                              [--sensor STATE|FRONT_FACING_CAMERA] [--hyperparameters '{"num_epochs": 10}']
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace


def standing_optimum(track_name: str, car: str) -> tuple[float, float]:
    """(flying, standing-start) lap times of ``car``'s race line, s."""
    from laplab.track.raceline_cache import optimal_lap_time, standing_start_optimal_lap_time
    from laplab.track.registry import load_track
    from laplab.vehicle.params import vehicle_preset
    track, vehicle = load_track(track_name), vehicle_preset(car)
    return optimal_lap_time(track, vehicle), standing_start_optimal_lap_time(track, vehicle)


def train_and_evaluate(track: str, seed: int, minutes: list[float], sensor: str = "STATE",
                       hyperparameters: dict | None = None, car: str = "") -> dict:
    os.environ.setdefault("LAPLAB_HOME", tempfile.mkdtemp(prefix="laplab-bench-"))
    from laplab.env.metadata import ModelMetadata
    from laplab.evaluate.trials import EvaluationSettings, evaluate_model
    from laplab.store.checkpoints import CheckpointStore
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training

    name = f"lapq-{seed}-{int(time.time() * 1000) % 10**8}"
    config = replace(TrainConfig(), track=track, seed=seed, max_time_s=60.0 * max(minutes),
                     model_metadata=replace(ModelMetadata(), sensors=(sensor,)).to_dict(), vehicle=car)
    if hyperparameters:
        config = replace(config, hyperparameters={**config.hyper().to_dict(), **hyperparameters})
    trainer = create_training(name, config)
    store = CheckpointStore(trainer.folder)
    marks = sorted(minutes)
    kept: dict[float, tuple[str, bytes, int]] = {}

    def on_iteration(report) -> None:
        for mark in marks:
            if mark not in kept and report.elapsed_s >= 60.0 * mark:
                best = store.resolve("best")
                kept[mark] = (best.name, best.read_bytes(), report.env_steps)

    trainer.run(callbacks=(on_iteration,))
    final = store.resolve("best")
    out = {}
    for mark in marks:
        checkpoint, payload, steps = kept.get(mark, (final.name, final.read_bytes(), trainer.env_steps))
        path = trainer.folder.model_dir / checkpoint
        if not path.exists():  # pruned since: put it back to evaluate it
            path.write_bytes(payload)
        rest, _ = evaluate_model(name, EvaluationSettings(trials=3, checkpoint=checkpoint))
        flying, _ = evaluate_model(name, EvaluationSettings(trials=3, checkpoint=checkpoint, continuous=True))
        out[mark] = {"steps": steps, "checkpoint": checkpoint, "rest": rest.summary.best_lap,
                     "rest_completed": rest.summary.completed, "flying": flying.summary.best_lap,
                     "laps": [t.lap_time for t in flying.trials]}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--minutes", type=float, nargs="+", default=[5.0, 20.0])
    parser.add_argument("--track", default="classic_2018")
    parser.add_argument("--jobs", type=int, default=1, help="seeds trained at once (one core each)")
    parser.add_argument("--sensor", default="STATE")
    parser.add_argument("--hyperparameters", default="{}", help="JSON of hyperparameters to override")
    parser.add_argument("--physics", default="6", help="the car: 4, 5, 6 (default, DeepRacer on AWS's) or classic")
    args = parser.parse_args()
    from laplab.vehicle.physics import resolve_physics
    car = resolve_physics(args.physics)
    flying_opt, standing_opt = standing_optimum(args.track, car)
    print(f"{args.track}, {car}: race line {flying_opt:.3f} s flying, {standing_opt:.3f} s from a standing start")
    with ProcessPoolExecutor(args.jobs) as pool:
        n = len(args.seeds)
        runs = list(pool.map(train_and_evaluate, [args.track] * n, args.seeds, [args.minutes] * n,
                             [args.sensor] * n, [json.loads(args.hyperparameters)] * n, [car] * n))
    print(f"{'minutes':>7s} {'seed':>4s} {'env steps':>9s} {'rest lap s':>10s} {'/flying':>7s} {'/standing':>9s} "
          f"{'flying lap s':>12s} {'/flying':>7s}")
    nan = float("nan")
    for mark in sorted(args.minutes):
        rows = []
        for seed, run in zip(args.seeds, runs):
            r = run[mark]
            rest, fly = r["rest"] or nan, r["flying"] or nan
            rows.append((r["steps"], rest, fly))
            print(f"{mark:7.1f} {seed:4d} {r['steps']:9d} {rest:10.2f} {rest / flying_opt:7.3f} "
                  f"{rest / standing_opt:9.3f} {fly:12.2f} {fly / flying_opt:7.3f}")
        med = [statistics.median(row[i] for row in rows) for i in range(3)]
        print(f"{mark:7.1f} {'med':>4s} {med[0]:9.0f} {med[1]:10.2f} {med[1] / flying_opt:7.3f} "
              f"{med[1] / standing_opt:9.3f} {med[2]:12.2f} {med[2] / flying_opt:7.3f}")


if __name__ == "__main__":
    main()
