"""``laplab drive``: laplab's built-in pure-pursuit policy drives a track, scored by a reward function;
prints lap time, progress and total reward per lap (a baseline that needs no training)."""

from __future__ import annotations

import argparse

import numpy as np
from rich.console import Console
from rich.table import Table


def register(subparsers) -> None:
    parser = subparsers.add_parser("drive", help="drive the built-in pure-pursuit policy round a track and score it")
    parser.add_argument("--track", default=None, help="track name or .npy path (default: classic_2018)")
    parser.add_argument("--reward", default=None, help="reward_function.py (default: laplab's lap_pace example)")
    parser.add_argument("--laps", type=int, default=3, help="laps to drive, each from the round-robin start")
    parser.add_argument("--speed", type=float, default=1.5, help="target speed of the built-in policy, m/s")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from laplab.errors import UserError
    from laplab.env.vector import DEFAULT_REWARD, resolve_reward_function
    from laplab.reward.params import ParamsBuilder, rewards_for
    from laplab.sim.pure_pursuit import PurePursuit, PurePursuitParams
    from laplab.sim.simulator import Simulator
    from laplab.sim.state import IN_PROGRESS, STATUS_NAMES
    from laplab.track.registry import DEFAULT_TRACK, load_track

    if args.laps < 1 or not 0.1 <= args.speed <= 4.0:
        raise UserError("--laps must be >= 1 and --speed within the car's 0.1-4 m/s")
    console = Console(highlight=False, soft_wrap=True)
    track = load_track(args.track or DEFAULT_TRACK)
    reward_fn = resolve_reward_function(args.reward or DEFAULT_REWARD)
    sim = Simulator(track, args.laps)  # one car per lap, at consecutive round-robin starts
    sim.reset()
    policy = PurePursuit(track.centerline, params=PurePursuitParams(speed=args.speed))
    params = ParamsBuilder(sim)
    total_reward = np.zeros(args.laps)
    while (sim.state.status == IN_PROGRESS).any():
        steer, speed = policy.act(sim.poses(), sim.state.speed)
        cars = np.flatnonzero(sim.step(steer, speed))
        total_reward[cars] += rewards_for(params, reward_fn, cars)[0]
    st = sim.state
    table = Table(title=f"built-in pure-pursuit policy on {track.name} ({track.length:.2f} m, "
                        f"{track.nominal_width:.3f} m wide) at {args.speed} m/s")
    for col in ("lap", "start", "status", "progress %", "lap time s", "steps", "total reward"):
        table.add_column(col, justify="right")
    for i in range(args.laps):
        start = f"{100 * sim.episode.round_robin_advance * i % 100:.0f}%"
        lap_time = f"{st.lap_time[i]:.3f}" if st.lap_time[i] > 0 else "-"
        table.add_row(str(i + 1), start, STATUS_NAMES[st.status[i]], f"{st.progress[i]:.1f}", lap_time,
                      str(st.steps[i]), f"{total_reward[i]:.2f}")
    console.print(table)
    return 0
