"""How close laplab's camera comes to DeepRacer's: real simulator frames against laplab's frames of the
same track from the best-matching pose, laplab's old look against the new one.

    python bench/camera_look.py [--out docs/camera-look.png] [--frames ../shared/real-deepracer/frames]

Frames: ``dr-demo-*.png`` (640x480, DeepRacer's simulator on reinvent_base) and ``sim-image-*.png``
(160x120 colour). The track of each frame is the candidate route (``CANDIDATES``) whose best pose
matches it best; the dr-demo frames are reinvent_base by their description. Everything is compared as
the car sees it: 160x120 grey (a 640x480 frame is box-averaged 4x4, then ITU-R 601 luma).

Pose search, per frame and per look: a coarse grid over the track (every 0.10 m of centre line x 5
lateral offsets from -0.3 to 0.3 m x 13 headings from -36 to 36 degrees off the track's direction),
rendered in batches, scored by the mean absolute grey difference; then Nelder-Mead from the best 4
grid poses over (x, y, yaw), keeping the best. Figures per pair: the grey-level histogram distance
(half the L1 distance of 32-bin normalised histograms: 0 same, 1 disjoint) and SSIM (7x7 uniform
windows, mean over the frame). The PNG shows, per frame, the real frame, the old look and the new
look (colour, 240x180, from each look's best pose).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw
from scipy.ndimage import uniform_filter
from scipy.optimize import minimize

from laplab.sensors.camera import FRONT_FACING_CAMERA, render_camera
from laplab.sensors.look import texture_for_track
from laplab.sensors.texture import build_track_texture, luma601
from laplab.track.registry import load_track

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
CANDIDATES = ("reinvent_base", "reInvent2019_track", "reInvent2019_wide")
VIEW = FRONT_FACING_CAMERA.with_(width=240, height=180, supersample=2, bilinear=True, grayscale=False)


def real_grey(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(160x120 grey float as the car sees it, RGB uint8 of VIEW's size for the picture) of a real frame."""
    rgb = np.asarray(Image.open(path).convert("RGB"))
    h, w = rgb.shape[:2]
    k = w // 160
    small = rgb.reshape(h // k, k, w // k, k, 3).mean(axis=(1, 3))
    picture = np.asarray(Image.fromarray(rgb).resize((VIEW.width, VIEW.height), Image.BILINEAR))
    return luma601(np.rint(small).astype(np.uint8)).astype(np.float64), picture


def grid_poses(track) -> np.ndarray:
    s = np.arange(0.0, track.length, 0.10)
    points, heading = track.point_at(s), track.heading_at(s)
    lateral, turn = np.linspace(-0.3, 0.3, 5), np.radians(np.linspace(-36, 36, 13))
    poses = []
    for d in lateral:
        for a in turn:
            poses.append(np.column_stack([points[:, 0] - d * np.sin(heading), points[:, 1] + d * np.cos(heading),
                                          heading + a]))
    return np.vstack(poses)


def distances(texture, poses: np.ndarray, target: np.ndarray, batch: int = 2048) -> np.ndarray:
    out = np.empty(len(poses))
    for start in range(0, len(poses), batch):
        frames = render_camera(texture, poses[start:start + batch]).astype(np.float32)
        out[start:start + batch] = np.abs(frames - target.astype(np.float32)).mean(axis=(1, 2))
    return out


def best_pose(texture, track, target: np.ndarray) -> tuple[np.ndarray, float]:
    poses = grid_poses(track)
    coarse = distances(texture, poses, target)
    best, best_d = None, math.inf
    for index in np.argsort(coarse)[:4]:
        result = minimize(lambda p: distances(texture, p[None], target)[0], poses[index], method="Nelder-Mead",
                          options={"initial_simplex": poses[index] + np.array([[0, 0, 0], [0.03, 0, 0], [0, 0.03, 0],
                                                                               [0, 0, 0.03]]),
                                   "xatol": 1e-3, "fatol": 1e-3, "maxiter": 200})
        if result.fun < best_d:
            best, best_d = result.x, float(result.fun)
    return best, best_d


def histogram_distance(a: np.ndarray, b: np.ndarray) -> float:
    ha = np.histogram(a, bins=32, range=(0, 256))[0] / a.size
    hb = np.histogram(b, bins=32, range=(0, 256))[0] / b.size
    return 0.5 * float(np.abs(ha - hb).sum())


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a.astype(np.float64), b.astype(np.float64)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    ma, mb = uniform_filter(a, 7), uniform_filter(b, 7)
    va, vb = uniform_filter(a * a, 7) - ma * ma, uniform_filter(b * b, 7) - mb * mb
    cov = uniform_filter(a * b, 7) - ma * mb
    s = ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
    return float(s[3:-3, 3:-3].mean())


def textures(name: str):
    track = load_track(SHARED / "reference-tracks" / f"{name}.npy")
    return track, {"old": build_track_texture(track), "new": texture_for_track(track)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default=str(SHARED / "real-deepracer" / "frames"))
    parser.add_argument("--out", default=str(ROOT / "docs" / "camera-look.png"))
    args = parser.parse_args(argv)
    paths = sorted(Path(args.frames).glob("dr-demo-*.png")) + sorted(Path(args.frames).glob("sim-image-*.png"))
    if not paths:
        print(f"no frames in {args.frames}")
        return 1
    worlds = {name: textures(name) for name in CANDIDATES}
    rows, panels = [], []
    for path in paths:
        target, picture = real_grey(path)
        names = ("reinvent_base",) if path.name.startswith("dr-demo") else CANDIDATES
        found = {}
        for name in names:
            track, looks = worlds[name]
            found[name] = {look: best_pose(texture, track, target) for look, texture in looks.items()}
        name = min(found, key=lambda n: found[n]["new"][1])
        track, looks = worlds[name]
        result = {"frame": path.name, "track": name}
        views = [picture]
        for look, texture in looks.items():
            pose, mad = found[name][look]
            grey = render_camera(texture, pose[None])[0].astype(np.float64)
            result[look] = (histogram_distance(target, grey), ssim(target, grey), mad, pose)
            views.append(render_camera(texture, pose[None], VIEW)[0])
        rows.append(result)
        panels.append((path.name, name, views, result))
        old, new = result["old"], result["new"]
        print(f"{path.name:24s} {name:20s} hist old {old[0]:.3f} new {new[0]:.3f} | SSIM old {old[1]:.3f} "
              f"new {new[1]:.3f} | MAD old {old[2]:.1f} new {new[2]:.1f} | new pose "
              f"({new[3][0]:.2f}, {new[3][1]:.2f}, {math.degrees(new[3][2]):.0f} deg)", flush=True)
    save_picture(panels, Path(args.out))
    print(f"wrote {args.out}")
    return 0


def save_picture(panels, out: Path) -> None:
    label_h, w, h = 24, VIEW.width, VIEW.height
    sheet = Image.new("RGB", (3 * w, len(panels) * (h + label_h)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for i, (frame, track, views, result) in enumerate(panels):
        y = i * (h + label_h)
        old, new = result["old"], result["new"]
        captions = [f"DeepRacer {frame[:-4]} ({track})", f"laplab old: hist {old[0]:.2f} SSIM {old[1]:.2f}",
                    f"laplab new: hist {new[0]:.2f} SSIM {new[1]:.2f}"]
        for j, (view, caption) in enumerate(zip(views, captions)):
            sheet.paste(Image.fromarray(view), (j * w, y + label_h))
            draw.text((j * w + 4, y + 6), caption, fill=(0, 0, 0))
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(out, optimize=True)  # a third the bytes


if __name__ == "__main__":
    raise SystemExit(main())
