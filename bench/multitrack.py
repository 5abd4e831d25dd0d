"""Time to 3/3 laps: one 3-track job (a rollout worker per track on Ray, as deepracer-for-cloud's
``DR_TRAIN_MULTI_CONFIG``) against the same three tracks trained one at a time (in-process).

The multi-track job evaluates its policy on every training track after each iteration; it has lapped
when every evaluation lap of every track is complete (3/3 on each). Each single-track job stops at its
own first 3/3; its model is then evaluated on the two other tracks (does one track's model lap the
others?). STATE sensor, laplab's default reward, action space and hyperparameters, so the figures
compare with bench/time_to_lap.py.

Usage: python bench/multitrack.py [--tracks classic_2018 ../shared/reference-tracks/reinvent_base.npy
                                   ../shared/reference-tracks/2022_summit_speedway.npy] [--seed 0] [--budget 600]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "reference-tracks"
DEFAULT_TRACKS = ["classic_2018", str(REFERENCE / "reinvent_base.npy"), str(REFERENCE / "2022_summit_speedway.npy")]


def train_until_lapped(name: str, config, budget_s: float, workers: int) -> dict:
    """Train until the first iteration whose evaluation completes every lap (on every track)."""
    from laplab.cluster.launch import RayWorkers
    from laplab.train.jobs import create_training

    trainer = create_training(name, replace(config, max_time_s=budget_s, workers=workers), launcher=RayWorkers())
    first: dict = {}

    def on_iteration(report) -> None:
        if not first and report.eval_episodes and report.eval_completed == report.eval_episodes:
            first.update(wall=report.elapsed_s, iterations=report.iteration, steps=report.env_steps,
                         by_track=dict(report.eval_progress_by_track), lap=report.eval_lap_time)

    started = time.perf_counter()
    with trainer:  # its workers (more than one: on a local Ray) stop with it
        trainer.run(callbacks=(on_iteration,), should_stop=lambda: bool(first))
    return {"lapped": bool(first), "wall": first.get("wall", time.perf_counter() - started),
            "iterations": first.get("iterations"), "steps": first.get("steps"), "lap": first.get("lap")}


def laps_elsewhere(name: str, tracks: list[str]) -> dict[str, str]:
    """Of 3 evaluation trials of model ``name``'s last checkpoint on each of ``tracks`` (DeepRacer's
    rules: an off-track costs a reset and a penalty): laps completed, and of those, laps without one."""
    from laplab.api import evaluate
    out = {}
    for track in tracks:
        trials = evaluate(name, track=track, trials=3, extra_args=("--checkpoint", "last"))["trials"]
        done = [t for t in trials if t["status"] == "lap_complete"]
        out[Path(track).stem] = f"{len(done)}/3 laps, {sum(t['off_track_count'] == 0 for t in done)} clean"
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tracks", nargs="+", default=DEFAULT_TRACKS)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--budget", type=float, default=600.0, help="give up on a job after this many seconds")
    args = parser.parse_args()
    missing = [t for t in args.tracks if t.endswith(".npy") and not Path(t).is_file()]
    if missing:
        raise SystemExit(f"track file(s) not found: {', '.join(missing)}")
    os.environ.setdefault("LAPLAB_HOME", tempfile.mkdtemp(prefix="laplab-multitrack-"))
    from laplab.train.config import TrainConfig

    base = replace(TrainConfig(), seed=args.seed)
    print(f"cores {os.cpu_count()}, seed {args.seed}, tracks: {', '.join(Path(t).stem for t in args.tracks)}")
    multi = train_until_lapped("multi", replace(base, tracks=tuple(args.tracks)), args.budget, len(args.tracks))
    print(f"{len(args.tracks)}-track job ({len(args.tracks)} Ray workers): lapped every track {multi['lapped']}, "
          f"{multi['wall']:.1f} s, {multi['iterations']} iterations, {multi['steps']} env steps", flush=True)
    total = 0.0
    for number, track in enumerate(args.tracks):
        name = f"single-{number}"
        one = train_until_lapped(name, replace(base, track=track), args.budget, 1)
        total += one["wall"]
        others = laps_elsewhere(name, [t for t in args.tracks if t != track]) if one["lapped"] else {}
        print(f"  {Path(track).stem:24s} alone: lapped {one['lapped']}, {one['wall']:.1f} s, {one['iterations']} "
              f"iterations, {one['steps']} env steps; its model on the other tracks (laps of 3): {others}", flush=True)
    print(f"one at a time, all {len(args.tracks)} together: {total:.1f} s; the {len(args.tracks)}-track job / one at a time = "
          f"{multi['wall'] / total:.2f}")


if __name__ == "__main__":
    main()
