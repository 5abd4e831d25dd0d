"""``laplab race MODEL_A MODEL_B [...]``: a head-to-model race of trained models in one simulator."""

from __future__ import annotations

import argparse

from laplab.train.request import RaceRequest


def register(subparsers) -> None:
    parser = subparsers.add_parser("race", help="race trained models against each other (DeepRacer's head-to-model)")
    parser.add_argument("models", nargs="+", metavar="MODEL", help="two or more model names")
    parser.add_argument("--track", default=None, help="track name (name@reversed: the other way; default: the "
                                                       "first model's track and direction)")
    parser.add_argument("--laps", type=int, default=RaceRequest.laps, help=f"laps to race (default {RaceRequest.laps})")
    parser.add_argument("--max-time", type=float, default=RaceRequest.max_time_s, metavar="S",
                        help=f"the race ends after this much simulated time (default {RaceRequest.max_time_s:g} s)")
    parser.add_argument("--checkpoint", default=RaceRequest.checkpoint,
                        help="which checkpoint of every model: best (default) or last")
    parser.add_argument("--video", action="store_true", help="also write an MP4 of the race's top-down view")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import time

    from rich.console import Console
    from rich.table import Table

    from laplab.errors import UserError
    from laplab.evaluate.race_run import PICTURE_FILE, VIDEO_FILE, run_model_race
    from laplab.jobs.db import laplab_home
    from laplab.train.request import as_cli_error

    try:
        request = RaceRequest(models=tuple(args.models), track=args.track, laps=args.laps, max_time_s=args.max_time,
                              checkpoint=args.checkpoint, video=bool(args.video))
    except UserError as exc:
        raise as_cli_error(exc) from None
    folder = laplab_home() / "races" / time.strftime("%Y%m%d-%H%M%S")
    result = run_model_race(request, folder)
    console = Console(highlight=False, soft_wrap=True)
    table = Table(title=f"race on {result.track.name}: {args.laps} laps", title_justify="left")
    for column in ("#", "model", "laps", "time s", "best lap s", "crashes", "off", "penalty s"):
        table.add_column(column, justify="left" if column == "model" else "right")
    for r in result.racers:
        table.add_row(str(r.position), r.name, str(r.laps), "–" if r.finish_time is None else f"{r.finish_time:.3f}",
                      f"{min(r.lap_times):.3f}" if r.lap_times else "–", str(r.crash_count), str(r.off_track_count),
                      f"{r.penalty_time:g}")
    console.print(table)
    console.print(f"picture: {folder / PICTURE_FILE}")
    if args.video:
        videos = sorted(folder.glob(VIDEO_FILE.replace(".mp4", ".*")))
        console.print(f"video: {videos[0] if videos else folder / VIDEO_FILE}")
    return 0
