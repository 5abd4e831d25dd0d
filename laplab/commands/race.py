"""``laplab race MODEL_A MODEL_B [...]``: a head-to-model race of trained models in one simulator."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    parser = subparsers.add_parser("race", help="race trained models against each other (DeepRacer's head-to-model)")
    parser.add_argument("models", nargs="+", metavar="MODEL", help="two or more model names")
    parser.add_argument("--track", default=None, help="track name or .npy path (default: the first model's track)")
    parser.add_argument("--laps", type=int, default=3, help="laps to race (default 3)")
    parser.add_argument("--max-time", type=float, default=180.0, metavar="S",
                        help="the race ends after this much simulated time (default 180 s)")
    parser.add_argument("--checkpoint", default="best", help="which checkpoint of every model: best (default) or last")
    parser.add_argument("--video", action="store_true", help="also write an MP4 of the race's top-down view")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json
    import time

    from rich.console import Console
    from rich.table import Table

    from laplab.errors import UserError
    from laplab.evaluate.race import Driver, check_same_car, race_picture, run_race
    from laplab.jobs.db import laplab_home
    from laplab.track.registry import load_track
    from laplab.train.policy import load_model_policy
    from laplab.vehicle.params import vehicle_preset

    if len(args.models) < 2 or len(set(args.models)) != len(args.models):
        raise UserError("name two or more different models: laplab race MODEL_A MODEL_B", field="models")
    if not 1 <= args.laps <= 20 or not 1.0 <= args.max_time <= 3600.0:
        raise UserError("--laps must be within 1..20 and --max-time within 1..3600 s", field="--laps")
    policies = []
    for name in args.models:
        try:
            policies.append(load_model_policy(name, args.checkpoint))
        except FileNotFoundError as exc:
            raise UserError(str(exc), field="models") from None
    check_same_car(args.models, [p.config.car for p in policies])
    track = load_track(args.track) if args.track else load_track(policies[0].config.track,
                                                                  reverse=policies[0].config.reverse)
    drivers = [Driver(p.name, lambda obs, p=p: p.act(obs), p.spec, p.config.car) for p in policies]
    result = run_race(drivers, track, vehicle_preset(policies[0].config.car), laps=args.laps, max_time=args.max_time)
    folder = laplab_home() / "races" / time.strftime("%Y%m%d-%H%M%S")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "race.json").write_text(json.dumps({**result.to_dict(), "models": args.models, "laps": args.laps}, indent=2))
    from PIL import Image
    Image.fromarray(race_picture(result, args.models)).save(folder / "topdown.png")
    if args.video:
        write_race_video(folder / "race.mp4", result)
    console = Console(highlight=False, soft_wrap=True)
    table = Table(title=f"race on {track.name}: {args.laps} laps", title_justify="left")
    for column in ("#", "model", "laps", "time s", "best lap s", "crashes", "off", "penalty s"):
        table.add_column(column, justify="left" if column == "model" else "right")
    for r in result.racers:
        table.add_row(str(r.position), r.name, str(r.laps), "–" if r.finish_time is None else f"{r.finish_time:.3f}",
                      f"{min(r.lap_times):.3f}" if r.lap_times else "–", str(r.crash_count), str(r.off_track_count),
                      f"{r.penalty_time:g}")
    console.print(table)
    console.print(f"picture: {folder / 'topdown.png'}")
    return 0


def write_race_video(path, result) -> None:
    from laplab.evaluate.video import _TopdownFrames
    from laplab.sensors.render import draw_topdown
    from laplab.sensors.video import write_episode_video
    poses = result.poses

    def frame(t: int):
        return draw_topdown(result.track, poses[t], paths=[poses[: t + 1, i, :2] for i in range(poses.shape[1])])
    write_episode_video(path, _TopdownFrames(frame, len(poses)), None,
                        {"time": [f"{c:.2f} s" for c in result.clock]})
