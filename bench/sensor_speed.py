"""Sensor throughput on a real DeepRacer track, against Gymnasium's CarRacing-v3 as the peer.

    python3 bench/sensor_speed.py [--track reinvent_base] [--runs 7] [--seconds 0.5] [--look-only]
                                  [--objects-only]

One function per sensor returns table rows; ``main`` prints them. For every configuration and
batch size N the figure is the median over ``runs`` runs (each run repeats the call for at least
``seconds``) of observations per second, with numba's threads and on one thread (batches of one
160x120 frame always render on one thread). The peer is CarRacing-v3's env.step per second (it renders
its 96x96 observation every step); the last column is the ratio. Goal for the camera: >= 20,000
frames/s at N = 64 for the default 160x120 grey camera on 2 cores. Threaded figures collapse when
other processes load the cores: check ``uptime`` first. The camera renders the track's look
(laplab.sensors.look); ``--look-only`` measures just the default camera at N = 64 with laplab's old
look (the panelled room) and with the track's look, in the same run. Rows "3 objects in view" give
every car a box 0.8 m ahead, a bot car 1.6 m ahead and 0.25 m to the left and a box 2.5 m ahead and
0.2 m to the right (object avoidance / head-to-bot); goal >= 10,000 camera frames/s at N = 64.
``--objects-only`` measures the default camera and the lidar with and without them, in the same run.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Callable, NamedTuple

import numba
import numpy as np

from laplab.sensors.camera import (FRONT_FACING_CAMERA, HUMAN_CAMERA, STEREO_CAMERAS, render_camera,
                                   render_cameras)
from laplab.sensors.look import texture_for_track
from laplab.sensors.texture import build_track_texture

TRACKS = Path(__file__).resolve().parents[1].parent / "shared" / "reference-tracks"


class Row(NamedTuple):
    sensor: str
    config: str
    n: int
    per_second: float   # observations (one car's frame / scan) per second with numba's threads, median
    call_us: float      # microseconds per batched call with numba's threads, median
    one_core: float     # observations per second on one thread, median


def threaded_and_one_core(call: Callable[[], object], runs: int, seconds: float) -> tuple[float, float]:
    """Median seconds per call with numba's threads and with one thread."""
    threads = numba.get_num_threads()
    threaded = median_call_seconds(call, runs, seconds)
    numba.set_num_threads(1)
    try:
        return threaded, median_call_seconds(call, runs, seconds)
    finally:
        numba.set_num_threads(threads)


def median_call_seconds(call: Callable[[], object], runs: int, seconds: float) -> float:
    """Median over ``runs`` runs of the mean duration of ``call`` (each run lasts >= ``seconds``)."""
    call()  # warm-up: numba compile / cache load, lru caches
    results = []
    for _ in range(runs):
        count, start = 0, time.perf_counter()
        while True:
            call()
            count += 1
            elapsed = time.perf_counter() - start
            if elapsed >= seconds:
                break
        results.append(elapsed / count)
    return float(np.median(results))


def poses_on_track(route: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) poses near random centre-line points, heading along the track +- 0.3 rad."""
    rows = rng.integers(0, len(route) - 1, n)
    step = route[rows + 1, 0:2] - route[rows, 0:2]
    yaw = np.arctan2(step[:, 1], step[:, 0]) + rng.uniform(-0.3, 0.3, n)
    return np.column_stack([route[rows, 0:2] + rng.normal(0.0, 0.1, (n, 2)), yaw])


def interleaved_cpu_rates(calls: dict[str, Callable[[], object]], frames: int, runs: int,
                          seconds: float) -> dict[str, tuple[float, float]]:
    """(median, best) frames per CPU-second of this process on one thread for each call, the calls
    taking turns in ``seconds``-long slices ``runs`` times (what a loaded host cannot steal, and a
    slowdown of the host hits every call alike)."""
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    rates: dict[str, list[float]] = {name: [] for name in calls}
    try:
        for call in calls.values():
            call()
        for _ in range(runs):
            for name, call in calls.items():
                count, start = 0, time.process_time()
                while time.process_time() - start < seconds:
                    call()
                    count += 1
                rates[name].append(frames * count / (time.process_time() - start))
    finally:
        numba.set_num_threads(threads)
    return {name: (float(np.median(r)), float(np.max(r))) for name, r in rates.items()}


def look_rows(route: np.ndarray, name: str, runs: int, seconds: float) -> list[Row]:
    """The default 160x120 grey camera at N = 64 on laplab's old look and on the track's look; also
    prints frames per CPU-second on one thread, the looks taking turns."""
    rows, calls = [], {}
    poses = poses_on_track(route, 64, np.random.default_rng(0))
    out = np.empty((64, FRONT_FACING_CAMERA.height, FRONT_FACING_CAMERA.width), np.uint8)
    for label, texture in (("old look (panelled room)", build_track_texture(route)),
                           (f"{name}'s look", texture_for_track(route, name=name))):
        call = calls[label] = (lambda t: lambda: render_camera(t, poses, out=out))(texture)
        threaded, one_core = threaded_and_one_core(call, runs, seconds)
        rows.append(Row("camera", f"160x120 grey, {label}", 64, 64 / threaded, 1e6 * threaded, 64 / one_core))
    for label, (median, best) in interleaved_cpu_rates(calls, 64, runs, seconds).items():
        print(f"{label}: {median:,.0f} frames per CPU-second on one thread (median; best {best:,.0f}), interleaved")
    return rows


def objects_ahead(poses: np.ndarray) -> tuple[np.ndarray, ...]:
    """Three obstacles in view of every car: (x, y, yaw, half_length, half_width, height, kind), each (N, 3)."""
    from laplab.sensors.obstacle_look import BOT_CAR, BOX, BOX_SIZE, CAR_SIZE
    ahead, left = np.array([0.8, 1.6, 2.5]), np.array([0.0, 0.25, -0.2])
    c, s = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
    x = poses[:, 0:1] + ahead * c - left * s
    y = poses[:, 1:2] + ahead * s + left * c
    sizes = np.array([BOX_SIZE, CAR_SIZE, BOX_SIZE])
    full = lambda values: np.broadcast_to(values, x.shape).copy()
    return (x, y, full(poses[:, 2:3] + np.array([0.3, 0.0, -0.5])), full(sizes[:, 0] / 2), full(sizes[:, 1] / 2),
            full(sizes[:, 2]), full(np.array([BOX, BOT_CAR, BOX])))


def object_rows(route: np.ndarray, runs: int, seconds: float, name: str = "") -> list[Row]:
    """The default camera (N = 1, 64, 256) and the lidar (N = 64) without and with 3 objects in view."""
    from laplab.sensors.lidar import DEFAULT_LIDAR, LidarWalls, scan
    texture, walls = texture_for_track(route, name=name), LidarWalls.from_track(route)
    rng = np.random.default_rng(0)
    rows = []
    for n in (1, 64, 256):
        poses = poses_on_track(route, n, rng)
        objects = objects_ahead(poses)
        out = np.empty((n, FRONT_FACING_CAMERA.height, FRONT_FACING_CAMERA.width), np.uint8)
        calls = {}
        for label, given in (("time trial", None), ("3 objects in view", objects)):
            call = calls[label] = (lambda g: lambda: render_camera(texture, poses, out=out, obstacles=g))(given)
            threaded, one_core = threaded_and_one_core(call, runs, seconds)
            rows.append(Row("camera", f"160x120 grey, {label}", n, n / threaded, 1e6 * threaded, n / one_core))
        if n == 64:
            for label, (median, best) in interleaved_cpu_rates(calls, n, runs, seconds).items():
                print(f"camera N=64, {label}: {median:,.0f} frames per CPU-second on one thread (median; best "
                      f"{best:,.0f}), interleaved")
    poses = poses_on_track(route, 64, rng)
    for label, given in (("time trial", None), ("3 objects in view", objects_ahead(poses))):
        call = (lambda g: lambda: scan(walls, poses, DEFAULT_LIDAR, rng, obstacles=g))(given)
        threaded, one_core = threaded_and_one_core(call, runs, seconds)
        rows.append(Row("lidar", f"64 beams, {label}", 64, 64 / threaded, 1e6 * threaded, 64 / one_core))
    return rows


def camera_rows(route: np.ndarray, runs: int, seconds: float, name: str = "") -> list[Row]:
    """Camera frames/s: 160x120 grey with the default anti-aliasing (mip levels), none, bilinear
    magnification, 2x2 supersampling, the stereo pair (one observation = two frames) and the 640x480
    RGB human view (2x2 supersampled, bilinear)."""
    start = time.perf_counter()
    texture = texture_for_track(route, name=name)
    print(f"camera texture: {texture.width}x{texture.height} texels of {texture.texel_size} m, "
          f"{texture.num_levels} mip levels, built in {time.perf_counter() - start:.2f} s")
    rng = np.random.default_rng(0)
    configs = [("160x120 grey, mip (default)", FRONT_FACING_CAMERA, (1, 64, 256)),
               ("160x120 grey, no AA", FRONT_FACING_CAMERA.with_(mipmap=False), (1, 64, 256)),
               ("160x120 grey, mip + bilinear", FRONT_FACING_CAMERA.with_(bilinear=True), (1, 64, 256)),
               ("160x120 grey, 2x2 supersampled", FRONT_FACING_CAMERA.with_(supersample=2), (1, 64, 256)),
               ("stereo 2x160x120 grey", STEREO_CAMERAS, (1, 64, 256)),
               ("640x480 RGB human view", HUMAN_CAMERA, (1, 8))]
    rows = []
    for name, camera, sizes in configs:
        for n in sizes:
            poses = poses_on_track(route, n, rng)
            if isinstance(camera, tuple):
                out = np.empty((n, camera[0].height, camera[0].width, len(camera)), dtype=np.uint8)
                call = lambda: render_cameras(texture, poses, camera, out=out)
            else:
                out = np.empty((n, camera.height, camera.width) + (() if camera.grayscale else (3,)), np.uint8)
                call = lambda: render_camera(texture, poses, camera, out=out)
            threaded, one_core = threaded_and_one_core(call, runs, seconds)
            rows.append(Row("camera", name, n, n / threaded, 1e6 * threaded, n / one_core))
    return rows


def lidar_rows(route: np.ndarray, runs: int, seconds: float) -> list[Row]:
    """Lidar scans/s (64 beams against the borders) at N = 1, 64, 256."""
    from laplab.sensors.lidar import DEFAULT_LIDAR, LidarWalls, scan
    walls = LidarWalls.from_track(route)
    rng = np.random.default_rng(1)
    rows = []
    for n in (1, 64, 256):
        poses = poses_on_track(route, n, rng)
        threaded, one_core = threaded_and_one_core(lambda: scan(walls, poses, DEFAULT_LIDAR, rng), runs, seconds)
        rows.append(Row("lidar", "64 beams, noise 0.01 m", n, n / threaded, 1e6 * threaded, n / one_core))
    return rows


def camera_env_rows(runs: int, seconds: float) -> list[Row]:
    """Full env steps/s with the camera observation: TimeTrialVectorEnv.step (dynamics, projection,
    termination, follow-the-centre-line reward, render) on the default built-in track."""
    from laplab.env import TimeTrialVectorEnv
    rows = []
    for n in (64, 256):
        env = TimeTrialVectorEnv(n, model_metadata={"sensor": ["FRONT_FACING_CAMERA"]}, keep_params=False)
        env.reset(seed=0)
        actions = np.random.default_rng(0).integers(0, env.single_action_space.n, n)
        threaded, one_core = threaded_and_one_core(lambda: env.step(actions), runs, seconds)
        rows.append(Row("env", "VectorEnv.step, FRONT_FACING_CAMERA", n, n / threaded, 1e6 * threaded, n / one_core))
    return rows


def carracing_steps_per_second(runs: int, seconds: float) -> float | None:
    """Median env.step/s of Gymnasium's CarRacing-v3 with random actions (None without Box2D)."""
    try:
        import gymnasium as gym
        env = gym.make("CarRacing-v3")
    except Exception as exc:  # gymnasium[box2d] missing
        print(f"peer CarRacing-v3 unavailable ({exc}); pip install 'gymnasium[box2d]'")
        return None
    env.reset(seed=0)
    env.action_space.seed(0)

    def step():
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()

    result = 1.0 / median_call_seconds(step, runs, seconds)
    env.close()
    return result


def print_table(rows: list[Row], peer: float | None) -> None:
    header = (f"{'sensor':<8} {'configuration':<34} {'N':>5} {'obs/s':>10} {'us/call':>11} {'x CarRacing':>12}"
              f" {'obs/s 1 core':>13}")
    print(header)
    print("-" * len(header))
    for row in rows:
        ratio = f"{row.per_second / peer:12.1f}" if peer else f"{'-':>12}"
        print(f"{row.sensor:<8} {row.config:<34} {row.n:>5} {row.per_second:>10,.0f} {row.call_us:>11,.1f} {ratio}"
              f" {row.one_core:>13,.0f}")
    if peer:
        print(f"peer: Gymnasium CarRacing-v3, {peer:,.0f} env steps/s (one 96x96 RGB frame per step)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--track", default="reinvent_base", help="route name in ../shared/reference-tracks")
    parser.add_argument("--runs", type=int, default=7, help="runs per figure (the median is printed)")
    parser.add_argument("--seconds", type=float, default=0.5, help="minimum duration of one run")
    parser.add_argument("--look-only", action="store_true", help="only the camera at N = 64, old look vs new")
    parser.add_argument("--objects-only", action="store_true", help="only the camera and lidar with 3 objects")
    args = parser.parse_args()
    route = np.load(TRACKS / f"{args.track}.npy")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"track {args.track}; numba threads {numba.get_num_threads()}; load average {load:.2f} "
          f"on {os.cpu_count()} cores")
    if args.look_only:
        print_table(look_rows(route, args.track, args.runs, args.seconds), None)
        return
    if args.objects_only:
        print_table(object_rows(route, args.runs, args.seconds, args.track), None)
        return
    rows = camera_rows(route, args.runs, args.seconds, args.track) + lidar_rows(route, args.runs, args.seconds)
    rows += object_rows(route, args.runs, args.seconds, args.track)
    rows += camera_env_rows(args.runs, args.seconds)
    peer = carracing_steps_per_second(args.runs, args.seconds)
    print_table(rows, peer)


if __name__ == "__main__":
    main()
