"""``laplab leaderboard``: every evaluated model ranked per track (average of three consecutive laps,
then best lap, then completion)."""

from __future__ import annotations

import argparse
import json

from rich import box
from rich.console import Console
from rich.table import Table


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "leaderboard", help="rank evaluated models per track",
        description="Rank every evaluated model by its best evaluation on a track: average of three consecutive "
                    "laps, then best lap, then completion. Run `laplab evaluate MODEL` to add evaluations.")
    parser.add_argument("--track", help="only this track (name as evaluated, e.g. classic_2018 or NAME@reversed)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of tables")
    from laplab.commands.store_option import add_store_option
    add_store_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from laplab.errors import UserError
    from laplab.evaluate.leaderboard import leaderboard
    from laplab.evaluate.summary import format_gap, format_seconds
    from laplab.evaluate.trials import EvaluationError

    from laplab.commands.store_option import evaluations_only, store_session
    with store_session(args, "leaderboard") as store:
        if store:
            store.pull_all(evaluations_only)
        try:
            boards = leaderboard(args.track)
        except EvaluationError as exc:
            raise UserError(str(exc)) from None
    if args.json:
        print(json.dumps([{"track": entries[0].track, "race": entries[0].race, "board": board,
                           "entries": [e.to_dict() for e in entries]}
                          for board, entries in boards.items()], indent=2))
        return 0
    console = Console(highlight=False, soft_wrap=True)
    if not boards:
        where = f" on track {args.track}" if args.track else ""
        console.print(f"no evaluations{where} yet: run `laplab evaluate MODEL` first")
        return 0
    for track, entries in boards.items():
        table = Table(title=f"leaderboard: {track}", title_justify="left", box=box.SIMPLE_HEAD,
                      pad_edge=False, collapse_padding=True)
        # avg3: average of three consecutive laps; gap: best lap / the race line's lap time.
        for name in ("#", "model", "evaluation", "avg3 s", "best s", "done %", "off", "gap"):
            table.add_column(name, justify="left" if name in ("model", "evaluation") else "right",
                             no_wrap=name != "model", overflow="fold")
        for e in entries:
            table.add_row(str(e.rank), e.model, e.stamp, format_seconds(e.average_3), format_seconds(e.best_lap),
                          f"{e.completion:.1f}", str(e.off_track_count), format_gap(e.gap_to_optimal))
        console.print(table)
    return 0
