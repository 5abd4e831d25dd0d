"""``laplab report MODEL``: one HTML page with PNGs about a model (training, trajectories, actions,
reward map, evaluations), written to ``<model>/report/`` or ``--out``; prints the page's path."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "report", help="write an HTML report (training curves, trajectories, evaluations) of a model",
        description="Build one self-contained HTML page with PNG figures about a model: reward, progress "
                    "and losses per iteration, recent trajectories coloured by speed, action usage, reward "
                    "by track position, and each evaluation's laps over the race line with its trial "
                    "table and video. No network, no JavaScript.")
    parser.add_argument("model", metavar="MODEL", help="model name (under $LAPLAB_HOME/models) or path to a model folder")
    parser.add_argument("--out", type=Path, help="folder to write into (default: <model folder>/report)")
    parser.add_argument("--track", help="draw on this track instead of the model's training track")
    parser.add_argument("--iterations", type=int, default=3, metavar="N",
                        help="draw the episodes of the last N iterations on the track (default 3)")
    parser.add_argument("--evaluations", type=int, default=6, metavar="N",
                        help="show the newest N evaluations (default 6)")
    from laplab.commands.store_option import add_store_option
    add_store_option(parser)
    parser.set_defaults(func=run_report)


def _resolve_folder(model: str):
    """The model folder named ``model`` (a model name first, else a folder path)."""
    from laplab.errors import UserError
    from laplab.store.layout import MODEL_NAME_PATTERN, ModelFolder, list_models, model_folder, models_root
    is_name = MODEL_NAME_PATTERN.fullmatch(model) is not None
    if is_name and model_folder(model).exists():
        return model_folder(model)
    if Path(model).expanduser().is_dir():
        return ModelFolder(Path(model))
    if not is_name:
        raise UserError(f"{model!r} is neither a model name nor a model folder.")
    known = ", ".join(list_models()[:20]) or "none"
    raise UserError(f"no model named {model!r} under {models_root()} (known models: {known}). "
                    "Train one with `laplab train --name NAME`, or give the path of a model folder.")


def run_report(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from laplab.analysis.loaders import ReportDataError
    from laplab.analysis.report import ReportSettings, build_report
    from laplab.errors import UserError
    for option, value in (("--iterations", args.iterations), ("--evaluations", args.evaluations)):
        if value < 1:
            raise UserError(f"{option} must be at least 1, got {value}.")
    from laplab.commands.store_option import store_session
    with store_session(args, "report") as store:
        out = args.out
        if store:  # the local copy goes away with the command: the page is written here by default
            folder = store.pull(args.model, ())
            out = out if out is not None else Path.cwd() / f"{args.model}-report"
        else:
            folder = _resolve_folder(args.model)
        settings = replace(ReportSettings(), recent_iterations=args.iterations, max_evaluations=args.evaluations)
        try:
            index = build_report(folder, out, track=args.track, settings=settings)
        except ReportDataError as exc:
            raise UserError(f"cannot build the report of {folder.root}: {exc}") from None
    print(index)
    from laplab.commands.outcome import record
    record(page=str(index))
    return 0
