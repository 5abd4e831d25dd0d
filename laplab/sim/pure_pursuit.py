"""A batched pure-pursuit controller that follows a closed path (centre line or race line).

Used as laplab's built-in policy (a baseline that laps without training) and to drive a race line
in the simulator to check its predicted lap time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laplab.vehicle.params import DEEPRACER, VehicleParams


@dataclass(frozen=True)
class PurePursuitParams:
    """``lookahead`` = ``lookahead_base`` + ``lookahead_gain`` x speed (m); ``speed`` m/s when the path
    has no speed profile."""

    lookahead_base: float = 0.25
    lookahead_gain: float = 0.15
    speed: float = 1.5


class PurePursuit:
    """Steers N cars toward the point of ``path`` one look-ahead distance ahead of them.

    ``path`` (M, 2) closed polyline (row 0 == row M-1 or not), ``speeds`` (M,) m/s target speeds along
    it (None: constant ``params.speed``).
    """

    def __init__(self, path: np.ndarray, speeds: np.ndarray | None = None,
                 params: PurePursuitParams = PurePursuitParams(), vehicle: VehicleParams = DEEPRACER):
        path = np.asarray(path, dtype=np.float64)
        if np.allclose(path[0], path[-1]):
            path = path[:-1]
            speeds = None if speeds is None else np.asarray(speeds)[: path.shape[0]]
        self.path, self.params, self.vehicle = path, params, vehicle
        seg = np.linalg.norm(np.diff(np.vstack([path, path[:1]]), axis=0), axis=1)
        self.arc = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(self.arc[-1])
        self.speeds = None if speeds is None else np.asarray(speeds, dtype=np.float64)

    def _nearest(self, xy: np.ndarray) -> np.ndarray:
        d2 = ((xy[:, None, :] - self.path[None, :, :]) ** 2).sum(-1)
        return np.argmin(d2, axis=1)

    def act(self, poses: np.ndarray, speeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Commands for poses (N, 3) of the model origin and measured speeds (N,): (steer rad, speed m/s)."""
        p, v = self.params, self.vehicle
        nearest = self._nearest(poses[:, :2])
        lookahead = p.lookahead_base + p.lookahead_gain * np.maximum(speeds, 0.5)
        target_arc = np.mod(self.arc[nearest] + lookahead + v.wheelbase, self.length)
        tx = np.interp(target_arc, self.arc, np.append(self.path[:, 0], self.path[0, 0]))
        ty = np.interp(target_arc, self.arc, np.append(self.path[:, 1], self.path[0, 1]))
        dx, dy = tx - poses[:, 0], ty - poses[:, 1]
        alpha = np.arctan2(dy, dx) - poses[:, 2]
        alpha = np.mod(alpha + np.pi, 2 * np.pi) - np.pi
        distance = np.maximum(np.hypot(dx, dy), 1e-6)
        steer = v.steering_for_curvature(2.0 * np.sin(alpha) / distance, speeds)
        if self.speeds is None:
            speed = np.full(poses.shape[0], p.speed)
        else:
            # Look a little ahead in the speed profile too, so braking starts before the corner.
            ahead = np.mod(self.arc[nearest] + 0.5 * lookahead, self.length)
            speed = np.interp(ahead, self.arc, np.append(self.speeds, self.speeds[0]))
        return steer, speed
