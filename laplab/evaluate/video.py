"""A video of one evaluation trial: the top-down view with the car's path, its front camera, and
the step's numbers, rebuilt from the trial's simtrace rows (penalty holds show as still frames)."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Callable

import numpy as np

from laplab.vehicle.dynamics import pose_for_reference

MAX_VIDEO_FRAMES = 2700  # 3 minutes at 15 fps; longer trials are cut


class _TopdownFrames(Sequence):
    """Frames drawn when read, so a long trial streams to MP4 without holding every image."""

    def __init__(self, draw: Callable[[int], np.ndarray], count: int):
        self._draw, self._count = draw, count

    def __len__(self) -> int:
        return self._count

    def __getitem__(self, index: int) -> np.ndarray:
        if not -self._count <= index < self._count:
            raise IndexError(index)
        return self._draw(index % self._count)


def trial_poses(result, trial: int = 0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Model-origin poses (T, 3) of trial ``trial`` and its trace rows (columns of T rows)."""
    rows = result.trace["episode"] == trial
    if not rows.any():
        raise ValueError(f"the evaluation has no rows for trial {trial} (trials 0..{len(result.trials) - 1})")
    columns = {name: values[rows] for name, values in result.trace.items()}
    yaw = np.radians(columns["yaw"])
    poses = pose_for_reference(np.column_stack([columns["X"], columns["Y"]]), yaw, result.vehicle.reference_offset)
    return poses, columns


def trial_obstacles(result, trial: int, count: int):
    """A function of a frame index giving that row's :class:`~laplab.sim.obstacles.Obstacles` (1, K) of
    trial ``trial``; None for an evaluation without obstacles."""
    if getattr(result, "obstacles", None) is None:
        return None
    from laplab.sim.obstacles import Obstacles
    rows = result.obstacles[result.trace["episode"] == trial][:count]
    return lambda t: Obstacles(*(rows[t:t + 1, :, j] if j < 6 else rows[t:t + 1, :, j].astype(np.int64)
                                 for j in range(7)))


def write_trial_video(path: str | Path, result, trial: int = 0, camera: bool = True) -> Path:
    """Write trial ``trial`` of an :class:`~laplab.evaluate.trials.EvaluationResult` to ``path``
    (.mp4, or .gif without imageio-ffmpeg); returns the path written. At most MAX_VIDEO_FRAMES frames."""
    from laplab.sensors.render import draw_topdown
    from laplab.sensors.video import write_episode_video

    poses, columns = trial_poses(result, trial)
    if len(poses) > MAX_VIDEO_FRAMES:
        warnings.warn(f"trial {trial + 1} has {len(poses)} steps; the video shows the first {MAX_VIDEO_FRAMES}",
                      stacklevel=2)
        poses, columns = poses[:MAX_VIDEO_FRAMES], {k: v[:MAX_VIDEO_FRAMES] for k, v in columns.items()}
    track = result.track
    path_xy = poses[:, :2]
    obstacles = trial_obstacles(result, trial, len(poses))
    topdown = _TopdownFrames(lambda t: draw_topdown(track, poses[t:t + 1], paths=[path_xy[: t + 1]],
                                                    obstacles=None if obstacles is None else obstacles(t)), len(poses))
    frames = None
    if camera:
        from laplab.sensors.camera import FRONT_FACING_CAMERA, render_camera
        from laplab.sensors.look import texture_for_track
        frames = render_camera(texture_for_track(track), poses, FRONT_FACING_CAMERA)
    start = result.trials[trial].start_time
    overlays = {"speed": columns["throttle"], "steering": columns["steer"], "progress": columns["progress"],
                "time": [f"{t - start:.2f} s" for t in columns["tstamp"]],
                "status": [str(s) for s in columns["episode_status"]]}
    return write_episode_video(path, topdown, frames, overlays)
