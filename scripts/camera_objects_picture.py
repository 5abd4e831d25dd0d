"""Draw docs/camera-objects.png: what the camera sees of DeepRacer's boxes and cars.

    python scripts/camera_objects_picture.py [--track reinvent_base] [--out docs/camera-objects.png]

Two scenes on the track's look: a box 1.1 m ahead turned a little (two of its sides show) with a bot
car beyond it to the right, and another model's car (CAR_COLOR Orange) 1.2 m ahead on the left with
a box further on. Each row: the 160x120 grey observation
(upscaled 4x, nearest) beside the 640x480 RGB human camera.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from laplab.sensors.camera import FRONT_FACING_CAMERA, HUMAN_CAMERA, render_camera
from laplab.sensors.look import texture_for_track
from laplab.sensors.obstacle_look import BOT_CAR, BOX, BOX_SIZE, CAR_SIZE, MODEL_CAR, ObstacleLook

ROOT = Path(__file__).resolve().parents[1]
TRACKS = ROOT.parent / "shared" / "reference-tracks"


def scene(route: np.ndarray, index: int, items: list[tuple[float, float, float, int]]):
    """A pose on the centre line at ``index`` facing along it, and obstacles at (ahead m, left m,
    yaw relative to the car rad, kind) from it: (poses (1, 3), seven (1, K) arrays)."""
    x, y = route[index, 0:2]
    step = route[index + 3, 0:2] - route[index, 0:2]
    yaw = float(np.arctan2(step[1], step[0]))
    c, s = np.cos(yaw), np.sin(yaw)
    rows = []
    for ahead, left, turn, kind in items:
        size = BOX_SIZE if kind == BOX else CAR_SIZE
        rows.append((x + ahead * c - left * s, y + ahead * s + left * c, yaw + turn, size[0] / 2, size[1] / 2,
                     size[2], kind))
    table = np.array(rows, dtype=np.float64)[None]
    return np.array([[x, y, yaw]]), tuple(table[..., i] for i in range(6)) + (table[..., 6].astype(np.int64),)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--track", default="reinvent_base")
    parser.add_argument("--out", default=str(ROOT / "docs" / "camera-objects.png"))
    args = parser.parse_args()
    route = np.load(TRACKS / f"{args.track}.npy")
    texture = texture_for_track(route, name=args.track)
    look = ObstacleLook(model_car_color="Orange")
    scenes = [scene(route, 12, [(1.1, 0.12, 0.35, BOX), (2.2, -0.3, 0.0, BOT_CAR)]),
              scene(route, 40, [(1.2, 0.2, 0.1, MODEL_CAR), (2.6, -0.15, -0.6, BOX)])]
    rows = []
    for poses, obstacles in scenes:
        grey = render_camera(texture, poses, FRONT_FACING_CAMERA, obstacles=obstacles, obstacle_look=look)[0]
        human = render_camera(texture, poses, HUMAN_CAMERA, obstacles=obstacles, obstacle_look=look)[0]
        observation = np.repeat(np.kron(grey, np.ones((4, 4), dtype=np.uint8))[..., None], 3, axis=2)
        rows.append(np.hstack([observation, np.full((480, 8, 3), 255, np.uint8), human]))
    picture = np.vstack([rows[0], np.full((8, rows[0].shape[1], 3), 255, np.uint8), rows[1]])
    Image.fromarray(picture).save(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
