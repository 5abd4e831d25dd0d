"""``laplab reward validate FILE``: check a reward function before training with it."""

from __future__ import annotations

import argparse

from rich.console import Console

MAX_TIMEOUT_S = 3600.0  # seconds one call may take at most (a longer wait is a hang, not a check)


def register(subparsers) -> None:
    parser = subparsers.add_parser("reward", help="work with reward functions")
    sub = parser.add_subparsers(dest="reward_command", metavar="ACTION", required=True)
    validate = sub.add_parser("validate", help="run a reward function over a sweep of realistic states")
    validate.add_argument("file", help="reward_function.py (DeepRacer's params form or the 2018 form)")
    validate.add_argument("--track", default=None, help="track name or .npy path (default: the default track)")
    validate.add_argument("--model-metadata", default=None, help="model_metadata.json for the action space")
    validate.add_argument("--timeout", type=float, default=2.0, help="seconds one call may take (default 2)")
    from laplab.commands.race_options import add_race_options
    add_race_options(validate)  # an object-avoidance reward reads the objects_* keys: put objects on the track
    validate.set_defaults(func=run_validate)


def run_validate(args: argparse.Namespace) -> int:
    import math

    from laplab.env.vector import resolve_metadata
    from laplab.errors import UserError
    from laplab.reward.loader import load_reward_function
    from laplab.reward.validate import validate_reward_function
    from laplab.track.registry import DEFAULT_TRACK, load_track

    if not (math.isfinite(args.timeout) and 0 < args.timeout <= MAX_TIMEOUT_S):
        raise UserError(f"--timeout must be a number of seconds above 0 and at most {MAX_TIMEOUT_S:g}, "
                        f"got {args.timeout:g}", field="--timeout")
    console = Console(highlight=False, soft_wrap=True)
    track = load_track(args.track or DEFAULT_TRACK)
    metadata = resolve_metadata(args.model_metadata)
    reward_fn = load_reward_function(args.file, max_speed=metadata.action_space.max_speed)
    from laplab.commands.race_options import race_type_from_args
    race = race_type_from_args(args)
    if race is not None:
        race.check_track(track.length, track.name)
    report = validate_reward_function(reward_fn, track, metadata.action_space.sweep_actions(), timeout_s=args.timeout,
                                      isolate=True, race=race)
    kind = "2018 signature" if reward_fn.is_legacy else "params dict"
    if report.passed:
        console.print(f"[green]PASS[/green] {args.file} ({kind}) on {track.name}: {report.calls} states, "
                      f"reward min {report.minimum:.4g} / mean {report.mean:.4g} / max {report.maximum:.4g}")
        return 0
    console.print(f"[red]FAIL[/red] {args.file} ({kind}) on {track.name} after {report.calls} states:")
    console.print(str(report.error), markup=False)
    return 1
