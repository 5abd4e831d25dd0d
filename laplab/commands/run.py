"""``laplab run``: the main job. Trains a model on a built-in track with the defaults, evaluates it in
3 trials, prints the summary with the gap to the optimal lap, and writes the report."""

from __future__ import annotations

import argparse
import time


def register(subparsers) -> None:
    parser = subparsers.add_parser("run", help="train a model with the defaults, evaluate it, write its report")
    parser.add_argument("--name", default=None, help="model name (default: run-<date>-<time>)")
    parser.add_argument("--track", default=None, help="track name or .npy path (default: classic_2018)")
    parser.add_argument("--reward", default=None, help="reward_function.py (default: laplab's lap_pace example)")
    parser.add_argument("--max-time", default="5m", help="training time limit (default 5m; DeepRacer's "
                                                         "average-score stop condition may end it sooner)")
    parser.add_argument("--trials", type=int, default=3, help="evaluation trials (default 3)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-report", action="store_true", help="skip the HTML report")
    from laplab.commands.train import add_limit_options
    add_limit_options(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace
    from pathlib import Path

    from rich.console import Console

    from laplab.commands.evaluate import print_evaluation
    from laplab.commands.train import run_trainer
    from laplab.evaluate.trials import EvaluationSettings, evaluate_model
    from laplab.train.config import TrainConfig, parse_duration
    from laplab.train.jobs import create_training
    from laplab.track.registry import DEFAULT_TRACK

    console = Console(highlight=False, soft_wrap=True)
    name = args.name or time.strftime("run-%Y%m%d-%H%M%S")
    config = replace(TrainConfig(), track=args.track or DEFAULT_TRACK, max_time_s=parse_duration(args.max_time),
                     seed=args.seed, reward_path=str(Path(args.reward).resolve()) if args.reward else None)
    console.rule(f"1/3 train {name}")
    trainer = create_training(name, config)
    code = run_trainer(trainer, console, quiet=False, reward_timeout=args.reward_timeout)
    if code != 0:
        return code
    console.rule(f"2/3 evaluate {name}")
    result, stamp = evaluate_model(name, EvaluationSettings(trials=args.trials, seed=args.seed))
    print_evaluation(console, result, stamp, trainer.folder)
    if not args.no_report:
        console.rule(f"3/3 report {name}")
        from laplab.analysis.report import build_report
        console.print(f"report: {build_report(trainer.folder)}")
    return 0
