"""``laplab evaluate MODEL``: DeepRacer's evaluation of a trained model (trials, lap times, penalties),
kept in the model folder; ``--list`` shows the model's evaluations."""

from __future__ import annotations

import argparse
import json

from rich import box
from rich.console import Console
from rich.table import Table

from laplab.errors import UserError


def _resets(text: str) -> int | None:
    if text.strip().lower() in ("unlimited", "none", "inf"):
        return None
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of resets >= 0 or 'unlimited', got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number of resets >= 0 or 'unlimited', got {text!r}")
    return value


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "evaluate", help="evaluate a model: timed trials with DeepRacer's penalties and resets",
        description="Run timed trials of a model (all at once, one car per trial) under DeepRacer's evaluation "
                    "rules and keep the result in the model folder (simtrace, metrics, summary.json). "
                    "Lap times are simulation time with penalties included. See docs/evaluation.md.")
    parser.add_argument("model", metavar="MODEL", help="model name")
    parser.add_argument("--track", help="track name or .npy path, NAME@reversed for the other direction "
                                        "(default: the model's training track and direction)")
    parser.add_argument("--trials", type=int, default=3, help="number of trials, 1-5 (default 3)")
    parser.add_argument("--force", action="store_true", help="allow more than 5 trials (up to 100)")
    parser.add_argument("--checkpoint", default="best", help="best, last or a checkpoint file name (default best)")
    parser.add_argument("--off-track-penalty", type=float, default=2.0, metavar="S",
                        help="seconds held after an off-track, reversed or immobilized reset (default 2; league 5)")
    parser.add_argument("--crash-penalty", type=float, default=5.0, metavar="S",
                        help="seconds held after a crash (default 5)")
    parser.add_argument("--resets", type=_resets, default=None, metavar="N",
                        help="resets allowed per trial, or 'unlimited' (default unlimited, as the console); "
                             "0 ends a trial at its first incident")
    parser.add_argument("--continuous", action="store_true",
                        help="drive the trials as consecutive laps of one run (deepracer-for-cloud style)")
    parser.add_argument("--max-trial-time", type=float, default=600.0, metavar="S",
                        help="a trial still running after this much simulation time ends as time_up (default 600)")
    parser.add_argument("--seed", type=int, default=0, help="seed of sensor noise and stochastic actions (default 0)")
    parser.add_argument("--stochastic", action="store_true", help="sample actions instead of taking the greedy one")
    parser.add_argument("--video", action="store_true", help="write a video of the first trial")
    parser.add_argument("--physics", default=None, metavar="V",
                        help="drive another of DeepRacer's cars: 4, 5, 6 or classic (default: the car the model "
                             "trained with)")
    parser.add_argument("--domain-randomization", action="store_true",
                        help="the camera sees the track with training's domain randomisation (colours, lighting, "
                             "noise, blur, camera jitter), drawn per frame from --seed: does a camera model keep "
                             "lapping under it? (camera models only; such an evaluation does not rank)")
    parser.add_argument("--list", action="store_true", help="list the model's evaluations instead of running one")
    parser.add_argument("--json", action="store_true", help="print JSON instead of tables")
    from laplab.commands.store_option import add_store_option
    from laplab.commands.train import add_limit_options
    add_store_option(parser)
    add_limit_options(parser, reward=False)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from laplab.commands.store_option import evaluations_only, store_session, without_traces

    console = Console(highlight=False, soft_wrap=True)
    with store_session(args, "evaluate") as store:
        if args.list:
            if store:
                store.pull(args.model, (), evaluations_only)
            return _list(args, console)
        if store:
            store.pull(args.model, (args.checkpoint,), without_traces, publish=True)
        code = _evaluate(args, console, store.remote.url(args.model) if store else None)
    return code


def _evaluate(args: argparse.Namespace, console: Console, store_url: str | None) -> int:
    from laplab.evaluate.trials import EvaluationError, EvaluationSettings, evaluate_model
    from laplab.jobs.supervisor import report
    report(model=args.model, what="evaluation")
    try:
        settings = EvaluationSettings(
            track=args.track, trials=args.trials, checkpoint=args.checkpoint,
            off_track_penalty=args.off_track_penalty, crash_penalty=args.crash_penalty, resets=args.resets,
            continuous=args.continuous, seed=args.seed, stochastic=args.stochastic, video=args.video,
            force=args.force, max_trial_time=args.max_trial_time, physics=args.physics,
            domain_randomization=args.domain_randomization)
        result, stamp = evaluate_model(args.model, settings)
    except EvaluationError as exc:  # the setting's option names the field (trials -> --trials)
        raise _as_option_error(exc) from None
    from laplab.store.layout import model_folder
    folder = model_folder(args.model)
    if args.json:
        print(json.dumps({"stamp": stamp, **result.to_dict()}, indent=2))
        return 0
    print_evaluation(console, result, stamp, folder, store_url)
    return 0


def _as_option_error(error) -> UserError:
    """An evaluation setting's error as ``laplab evaluate`` reports it: its field is the option
    (``domain_randomization`` -> ``--domain-randomization``), and a message that starts with the
    setting's words (``domain randomization ...``) starts with the option instead."""
    if not error.field:
        return UserError(str(error))
    option, words = f"--{error.field.replace('_', '-')}", error.field.replace("_", " ")
    message = str(error)
    if message.startswith(words + " "):
        message = option + message[len(words):]
    return UserError(message, field=option)


def car_line(car: str, trained_with: str | None = None) -> str:
    """What car an evaluation drove, and a word when it is laplab's classic one or not the model's own."""
    from laplab.vehicle.physics import describe_car
    from laplab.vehicle.params import CLASSIC
    line = f"car: {describe_car(car)}"
    if trained_with and trained_with != car:
        line += f"; the model trained with {trained_with}"
    elif car == CLASSIC.name:
        line += (". This model was trained before laplab drove DeepRacer's cars, so it keeps the car it learnt "
                 "on; --physics 6 drives DeepRacer on AWS's car, --physics 4 or 5 the console's")
    return line


def print_evaluation(console: Console, result, stamp: str, folder, store_url: str | None = None) -> None:
    from laplab.evaluate.summary import summary_lines, trials_table
    s = result.settings
    resets = "unlimited" if s.resets is None else str(s.resets)
    title = (f"{result.model} ({result.checkpoint}) on {result.track.name}: {len(result.trials)} "
             f"{'continuous laps' if s.continuous else 'trials'}, off-track penalty {s.off_track_penalty:g} s, "
             f"resets {resets}, {'stochastic' if s.stochastic else 'greedy'}"
             + (f", domain randomisation (seed {s.seed})" if s.domain_randomization else ""))
    console.print(trials_table(result.trials, result.summary.optimal_lap_time, title=title))
    console.print(car_line(result.vehicle.name, trained_with=result.trained_car))
    if result.race_type is not None:
        from laplab.sim.race_type import RaceType
        console.print(f"race: {RaceType.from_dict(result.race_type).summary()}")
    for line in summary_lines(result.summary):
        console.print(line)
    where = f"{store_url}{folder.evaluation_dir(stamp).name}/" if store_url else folder.evaluation_dir(stamp)
    console.print(f"evaluation {stamp}: {where}")
    if result.video:
        console.print(f"video: {result.video}")


def _list(args: argparse.Namespace, console: Console) -> int:
    from laplab.evaluate.summary import format_seconds
    from laplab.evaluate.trials import read_evaluation_summary
    from laplab.store.layout import model_folder
    from laplab.store.metrics import read_metrics

    folder = model_folder(args.model)
    if not folder.exists():
        raise FileNotFoundError(f"no model named {args.model!r} (looked in {folder.root}).")
    rows = []
    for stamp in folder.list_evaluations():
        document = read_evaluation_summary(folder, stamp)
        if document is not None:
            summary = document["summary"]
            rows.append({"stamp": stamp, "track": document["track"]["name"], "checkpoint": document.get("checkpoint"),
                         "trials": summary["trials"], "best_lap": summary["best_lap"],
                         "average_3": summary["average_3"], "completion": summary["average_completion"]})
        elif folder.evaluation_metrics(stamp).is_file():  # made by another tool: DeepRacer's metrics only
            metrics = read_metrics(folder.evaluation_metrics(stamp))
            laps = [m["elapsed_time_in_milliseconds"] / 1000 for m in metrics
                    if m.get("episode_status") == "Lap complete"]
            rows.append({"stamp": stamp, "track": None, "checkpoint": None, "trials": len(metrics),
                         "best_lap": min(laps) if laps else None, "average_3": None,
                         "completion": (sum(m["completion_percentage"] for m in metrics) / len(metrics)
                                        if metrics else 0.0)})
    if args.json:
        print(json.dumps({"model": args.model, "evaluations": rows}, indent=2))
        return 0
    if not rows:
        console.print(f"{args.model} has no evaluations yet (laplab evaluate {args.model})")
        return 0
    table = Table(title=f"evaluations of {args.model}", title_justify="left", box=box.SIMPLE_HEAD,
                  pad_edge=False, collapse_padding=True)
    for name in ("stamp", "track", "checkpoint", "trials", "best s", "avg3 s", "done %"):
        table.add_column(name, justify="left" if name in ("stamp", "track", "checkpoint") else "right",
                         no_wrap=name == "stamp", overflow="fold")
    for row in rows:
        table.add_row(row["stamp"], row["track"] or "-", row["checkpoint"] or "-", str(row["trials"]),
                      format_seconds(row["best_lap"]), format_seconds(row["average_3"]), f"{row['completion']:.1f}")
    console.print(table)
    return 0
