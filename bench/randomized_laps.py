"""Does a camera model keep lapping under the domain randomisation? (issue 30)

Evaluates a stored model twice with the same settings, N greedy trials each from the start line
under DeepRacer's evaluation rules (the console's 2 s off-track penalty, unlimited resets): once on
the track's plain look and once with ``--domain-randomization`` (training's variations, drawn per car
and frame from ``--seed``). Prints, per look: laps completed / N, clean laps (no off-track, reversed
or immobilized reset) / N, the best, median and worst lap time, the mean completion and the
off-tracks. Both evaluations are kept in the model folder (``laplab evaluate MODEL --list``).

Issue 30's row trains a camera model for 10 minutes on reinvent_base's DeepRacer look with
``bench/time_to_lap.py`` into a model folder that stays (``LAPLAB_HOME``), then evaluates it:

  LAPLAB_HOME=/tmp/dr30/home python bench/time_to_lap.py --tracks ../shared/reference-tracks/reinvent_base.npy \\
      --seeds 0 --sensor FRONT_FACING_CAMERA --budget 600 --min-time 600
  LAPLAB_HOME=/tmp/dr30/home python bench/randomized_laps.py --trials 20

``--parts`` then drives the same trials under each part of the randomisation alone (scene colours,
lighting, noise and blur, camera jitter: the other ranges set to 0), to see which one costs the laps;
those runs swap :data:`laplab.sensors.randomize.DOMAIN_RANDOMIZATION` for the part in this process
and keep nothing in the model folder.

Usage:
  python bench/randomized_laps.py [MODEL] [--trials 20] [--seed 0] [--checkpoint best|last] [--parts]
MODEL defaults to the newest model in ``$LAPLAB_HOME``.
"""

from __future__ import annotations

import argparse
import os
import statistics


def newest_model() -> str:
    """The most recently created model folder's name in ``$LAPLAB_HOME``."""
    from laplab.store.layout import list_models, model_folder
    names = list_models()
    if not names:
        raise SystemExit("randomized_laps.py: no model in $LAPLAB_HOME: name one, or train one first (see --help)")
    return max(names, key=lambda name: model_folder(name).root.stat().st_mtime)


def evaluate_looks(model: str, trials: int, seed: int, checkpoint: str) -> list[tuple[str, object]]:
    """The model's evaluation on the plain look and under the randomisation: (label, result) pairs."""
    from laplab.evaluate import EvaluationSettings, evaluate_model
    settings = EvaluationSettings(trials=trials, force=trials > 5, seed=seed, checkpoint=checkpoint)
    rows = []
    for label, randomized in (("plain look", False), ("domain randomisation", True)):
        result, _ = evaluate_model(model, EvaluationSettings(**{**settings.to_dict(), "domain_randomization": randomized}))
        rows.append((label, result))
    return rows


PARTS = {"scene colours": ("texture_variants",), "lighting": ("brightness", "contrast", "gamma"),
         "noise and blur": ("noise", "blur"), "camera jitter": ("position_jitter", "yaw_jitter_deg", "pitch_jitter_deg")}


def evaluate_parts(model: str, trials: int, seed: int, checkpoint: str) -> list[tuple[str, object]]:
    """The model's evaluation under each part of :data:`PARTS` alone (nothing written)."""
    from dataclasses import replace

    import laplab.sensors.randomize as randomize
    from laplab.evaluate import EvaluationSettings
    from laplab.evaluate.trials import prepare_evaluation, run_prepared
    full = randomize.DOMAIN_RANDOMIZATION
    settings = EvaluationSettings(trials=trials, force=trials > 5, seed=seed, checkpoint=checkpoint,
                                  domain_randomization=True)
    prepared = prepare_evaluation(model, settings)
    rows = []
    try:
        for label, kept in PARTS.items():
            randomize.DOMAIN_RANDOMIZATION = replace(full, **{name: 0 for name in sum(PARTS.values(), ())
                                                              if name not in kept})
            rows.append((f"  {label} alone", run_prepared(prepared)))
    finally:
        randomize.DOMAIN_RANDOMIZATION = full
    return rows


def row(label: str, result) -> str:
    """One printed line of figures for an evaluation result."""
    trials = result.trials
    laps = sorted(t.lap_time for t in trials if t.lap_time is not None)
    clean = sum(1 for t in trials if t.lap_time is not None
                and t.off_track_count + t.reversed_count + t.immobilized_count == 0)
    times = (f"{laps[0]:6.2f} {statistics.median(laps):6.2f} {laps[-1]:6.2f}" if laps
             else f"{'-':>6s} {'-':>6s} {'-':>6s}")
    return (f"{label:22s} {len(laps):>3d}/{len(trials):<3d} {clean:>3d}/{len(trials):<3d} {times} "
            f"{statistics.fmean(t.completion for t in trials):6.1f} {sum(t.off_track_count for t in trials):5d}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", nargs="?", help="model name (default: the newest in $LAPLAB_HOME)")
    parser.add_argument("--trials", type=int, default=20, help="greedy trials per look, 1..100 (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the randomisation's draws (default 0)")
    parser.add_argument("--checkpoint", default="best", help="best, last or a checkpoint file name")
    parser.add_argument("--parts", action="store_true", help="also each part of the randomisation alone (see above)")
    args = parser.parse_args()
    from laplab.errors import UserError
    model = args.model or newest_model()
    try:
        rows = evaluate_looks(model, args.trials, args.seed, args.checkpoint)
        if args.parts:
            rows += evaluate_parts(model, args.trials, args.seed, args.checkpoint)
    except UserError as error:
        raise SystemExit(f"randomized_laps.py: {error}") from None
    from host import host_line  # bench/host.py
    first = rows[0][1]
    print(f"host: {host_line()}; load average {os.getloadavg()[0]:.2f} at the end; "
          f"{sum(result.wall_seconds for _, result in rows):.1f} s of evaluation")
    print(f"{model} ({first.checkpoint}) on {first.track.name}, {first.vehicle.name}, {args.trials} greedy trials "
          f"per look, seed {args.seed}")
    print(f"{'look':22s} {'laps':>7s} {'clean':>7s} {'best':>6s} {'median':>6s} {'worst':>6s} {'done %':>6s} "
          f"{'off-tr':>5s}")
    for label, result in rows:
        print(row(label, result))


if __name__ == "__main__":
    main()
