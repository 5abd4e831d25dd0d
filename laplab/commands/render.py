"""``laplab render``: pictures of a track and what each sensor sees from a point of the lap."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def register(subparsers) -> None:
    parser = subparsers.add_parser("render", help="PNGs of the top-down view and each sensor at a point of the lap")
    parser.add_argument("--track", default=None, help="track name or .npy path (default: classic_2018)")
    parser.add_argument("--sensor", action="append", default=None,
                        help="FRONT_FACING_CAMERA, STEREO_CAMERAS, LEFT_CAMERA, LIDAR (repeatable; default: "
                             "FRONT_FACING_CAMERA and LIDAR)")
    parser.add_argument("--progress", type=float, default=0.0, help="where the car stands, %% of the lap (default 0)")
    parser.add_argument("--offset", type=float, default=0.0, help="lateral offset from the centre line, m (left +)")
    parser.add_argument("--heading", type=float, default=0.0, help="heading relative to the track, degrees")
    parser.add_argument("--out", default=".", help="folder for the PNGs (default: current folder)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from PIL import Image

    from laplab.errors import UserError
    from laplab.env.metadata import CAMERA_SENSORS, LIDAR_SENSORS
    from laplab.sensors.camera import HUMAN_CAMERA, camera_for_sensor, render_camera, render_cameras
    from laplab.sensors.lidar import DEFAULT_LIDAR, LidarWalls, scan
    from laplab.sensors.render import draw_lidar_polar, draw_topdown
    from laplab.sensors.look import texture_for_track
    from laplab.track.registry import DEFAULT_TRACK, load_track

    sensors = args.sensor or ["FRONT_FACING_CAMERA", "LIDAR"]
    unknown = [s for s in sensors if s not in CAMERA_SENSORS + LIDAR_SENSORS]
    if unknown:
        raise UserError(f"--sensor {unknown[0]!r} is not a sensor laplab renders; choose from "
                        f"{', '.join(CAMERA_SENSORS + LIDAR_SENSORS)}")
    if not 0.0 <= args.progress <= 100.0:
        raise UserError(f"--progress must be within 0..100 (% of the lap), got {args.progress}")
    track = load_track(args.track or DEFAULT_TRACK)
    s = args.progress / 100.0 * track.length
    centre = track.point_at(s)
    yaw = float(track.heading_at(s)) + np.radians(args.heading)
    origin = centre + args.offset * np.array([-np.sin(yaw), np.cos(yaw)])
    pose = np.array([[origin[0], origin[1], yaw]])
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"{track.name.replace('@', '-')}-{args.progress:g}"
    written = []

    def save(image: np.ndarray, name: str) -> None:
        path = out / f"{stem}-{name}.png"
        Image.fromarray(image).save(path)
        written.append(path)

    lidar_ranges = None
    if any(s in LIDAR_SENSORS for s in sensors):
        lidar_ranges = scan(LidarWalls.from_track(track), pose, DEFAULT_LIDAR)[0]
        save(draw_lidar_polar(lidar_ranges), "lidar")
    save(draw_topdown(track, pose, lidar_ranges=lidar_ranges), "topdown")
    cameras = [s for s in sensors if s in CAMERA_SENSORS]
    if cameras:
        texture = texture_for_track(track)
        for sensor in cameras:
            frames = render_cameras(texture, pose, camera_for_sensor(sensor))[0]
            for channel in range(frames.shape[-1]):
                suffix = "" if frames.shape[-1] == 1 else f"-{('left', 'right')[channel]}"
                save(frames[..., channel], f"{sensor.lower()}{suffix}-160x120")
        save(render_camera(texture, pose, HUMAN_CAMERA)[0], "camera-640x480")
    for path in written:
        print(path)
    return 0
