"""Simulator throughput: car-steps per second at N = 1, 64, 1024 cars (median of several runs).

(a) simulator + STATE observation, no reward function (through TimeTrialVectorEnv.step, and the
    bare Simulator.step kernel for comparison);
(b) the same with DeepRacer's follow-the-centre-line example reward function;
(c) Gymnasium's CarRacing-v3 (Box2D, one car) in the same run as the peer, as a ratio;
(d) (a) at N = 1024 for each of laplab's cars (DeepRacer's physics generations and laplab's classic car);
    the rows above drive the default car (DeepRacer on AWS's, deepracer-v6);
(e) (a) at N = 1024 with 3 boxes (object avoidance) and with 3 bot cars at 1 m/s changing lanes
    (head-to-bot): placement, bots, collisions and the STATE summary of the nearest objects.

Usage: python bench/env_speed.py [--repeats 5] [--steps 300]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from laplab.env import TimeTrialVectorEnv
from laplab.env.vector import EXAMPLES_DIR
from laplab.track.registry import load_track
from laplab.vehicle.params import DEEPRACER, PRESETS


def time_vector_env(num_cars: int, reward, steps: int, repeats: int, vehicle=DEEPRACER,
                    race=None) -> tuple[float, float]:
    """(median car-steps/s, median microseconds per step call)."""
    env = TimeTrialVectorEnv(num_cars, track=load_track("classic_2018"), reward_function=reward, keep_params=False,
                             vehicle=vehicle, race=race, seed=0)
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, env.single_action_space.n, size=(steps, num_cars))
    for k in range(20):
        env.step(actions[k])
    rates, latencies = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for k in range(steps):
            env.step(actions[k])
        elapsed = time.perf_counter() - t0
        rates.append(steps * num_cars / elapsed)
        latencies.append(elapsed / steps * 1e6)
    return statistics.median(rates), statistics.median(latencies)


def time_simulator(num_cars: int, steps: int, repeats: int) -> tuple[float, float]:
    env = TimeTrialVectorEnv(num_cars, track=load_track("classic_2018"), reward_function=None)
    sim = env.sim
    sim.reset()
    steer = np.random.default_rng(0).uniform(-0.5, 0.5, size=(steps, num_cars))
    speed = np.full(num_cars, 1.0)
    rates, latencies = [], []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        for k in range(steps):
            sim.step(steer[k], speed)
            finished = sim.state.status != 0
            if finished.any():
                sim.reset(finished)
        elapsed = time.perf_counter() - t0
        rates.append(steps * num_cars / elapsed)
        latencies.append(elapsed / steps * 1e6)
    return statistics.median(rates[1:]), statistics.median(latencies[1:])


def time_car_racing(steps: int, repeats: int) -> float | None:
    try:
        import gymnasium as gym
        env = gym.make("CarRacing-v3")
    except Exception as exc:  # box2d not installed
        print(f"CarRacing-v3 unavailable ({exc.__class__.__name__}: {exc}); pip install 'gymnasium[box2d]'")
        return None
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(steps):
            _, _, term, trunc, _ = env.step(rng.uniform([-1, 0, 0], [1, 1, 0.2]).astype(np.float32))
            if term or trunc:
                env.reset()
        rates.append(steps / (time.perf_counter() - t0))
    return statistics.median(rates)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--only-races", action="store_true", help="only the (e) rows (and no peer)")
    args = parser.parse_args()
    if args.only_races:
        return race_rows(args)
    peer = time_car_racing(min(args.steps, 200), args.repeats)
    print(f"{'case':44s} {'N':>5s} {'car-steps/s':>14s} {'us/step':>10s} {'x CarRacing':>12s}")
    rows = []
    for n in (1, 64, 1024):
        rows.append(("(a) Simulator.step kernel, STATE", n, *time_simulator(n, args.steps, args.repeats)))
        rows.append(("(a) VectorEnv.step, STATE, no reward", n, *time_vector_env(n, None, args.steps, args.repeats)))
        rows.append(("(b) VectorEnv.step, STATE, follow_centerline", n,
                     *time_vector_env(n, EXAMPLES_DIR / "follow_centerline.py", args.steps, args.repeats)))
    for car in PRESETS.values():
        rows.append((f"(d) VectorEnv.step, STATE, {car.name}", 1024, *time_vector_env(1024, None, args.steps,
                                                                                     args.repeats, car)))
    from laplab.sim.race_type import RaceType
    for label, race in (("3 boxes", RaceType("object_avoidance", objects=3)),
                        ("3 bots 1 m/s", RaceType("head_to_bot", bots=3, bot_speed=1.0, lane_change=True))):
        rows.append((f"(e) VectorEnv.step, STATE, {label}", 1024,
                     *time_vector_env(1024, None, args.steps, args.repeats, race=race)))
    for name, n, rate, latency in rows:
        ratio = f"{rate / peer:10.0f}x" if peer else "n/a"
        print(f"{name:44s} {n:5d} {rate:14,.0f} {latency:10.1f} {ratio:>12s}")
    if peer:
        print(f"{'(c) CarRacing-v3 (Box2D + pygame render)':44s} {1:5d} {peer:14,.0f} {1e6 / peer:10.1f} {'1x':>12s}")


def race_rows(args) -> None:
    from laplab.sim.race_type import RaceType
    print(f"{'case':44s} {'N':>5s} {'car-steps/s':>14s} {'us/step':>10s}")
    for label, race in (("none (time trial)", None), ("3 boxes", RaceType("object_avoidance", objects=3)),
                        ("3 bots 1 m/s", RaceType("head_to_bot", bots=3, bot_speed=1.0, lane_change=True))):
        rate, latency = time_vector_env(1024, None, args.steps, args.repeats, race=race)
        print(f"{'(e) VectorEnv.step, STATE, ' + label:44s} {1024:5d} {rate:14,.0f} {latency:10.1f}")


if __name__ == "__main__":
    main()
