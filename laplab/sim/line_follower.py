"""Drive a race line in the simulator: a batched curvature-feedforward controller and lap runs.

The simulator's car is a kinematic bicycle whose path curvature follows its wheels' angle ``delta``:
``kappa = g tan(delta + delta_off) / L / (1 + u v^2)``, capped at ``a_lat / v^2`` (:meth:`VehicleParams.curvature`:
gain ``g``, offset ``delta_off``, wheelbase ``L``, understeer ``u``, grip ``a_lat``). DeepRacer's cars answer
late: the previous command still acts for ``action_delay`` (``d``) of each 1/15 s decision ``dt``, the
wheels follow the saturated command ``sigma tanh(c / sigma)`` with a first-order lag of time constant
``tau``, the speed follows ``speed_ratio`` (``r``) times its command with a lag ``tau_v``. :class:`LineFollower`
makes up for each of these from the car's own :class:`VehicleParams`, for N cars at once:

1. Delay: each car is carried through ``d dt`` on its previous command (:func:`laplab.vehicle.dynamics.step`);
   the new command acts from that pose, speed ``v`` and wheel angle ``delta_0`` on, for one ``dt``.
2. Errors there: ``s`` (m) the arc length of the origin's projection onto the line, ``e`` (m) its
   signed distance from the line (left positive), ``psi = yaw + atan(a kappa_line(s)) - heading_line(s)``
   (rad): the origin lies ``a = -pivot_offset`` ahead of the point that moves along the yaw, so on a
   curve its path runs ``atan(a kappa)`` left of the yaw.
3. Steering, the line's curvature half way through the decision plus a correction, inverted through the
   car's curvature law and its lag (the wheels reach ``delta_T`` by the decision's end, then a new command)::

       kappa_T = kappa_line(s + curvature_preview * v dt) - lateral_gain * e - heading_gain * psi
       delta_T = atan(kappa_T (1 + u v^2) L / g) - delta_off
       delta_c = delta_0 + (delta_T - delta_0) / (1 - exp(-dt / tau))        (delta_T itself when tau = 0)
       steer   = sigma atanh(delta_c / sigma), clipped to the steering lock

4. Speed, the line's speed where the decision is three quarters done, capped where the correction would
   need more grip, the speed lag inverted the same way over that time, and the speed ratio divided out::

       v_T   = min(v_line(s_v), sqrt(a_lat / |kappa_line(s_v) + correction|)),  s_v = s + speed_preview * v dt
       speed = (v + (v_T - v) / (1 - exp(-speed_preview dt / tau_v))) / r, clipped to [0, max_speed]

For laplab's classic car (no delay, no lags, gain 1, ratio 1) this is plain curvature feedforward. In arc
length the error obeys ``e'' + heading_gain e' + lateral_gain e = 0`` (small angles), a damped oscillator
that settles within a metre or two. The speed cap matters because a race line's speeds use all the grip:
at the limit a correction on top saturates the tyres (the car understeers and drifts wide) unless the car
slows to where the curvature it then needs fits within the grip. Called without the car's wheel angle and
previous commands, :meth:`LineFollower.act` takes the car as settled and only reads the curvature
``response_steps`` further ahead. Pure pursuit, by contrast, aims at a chord of the line and cuts every corner.

:func:`drive_line` starts cars on the line's first point (at rest or at the line's speed there) and
drives one lap; :func:`laplab.track.speed_profile.standing_start_lap_time` is the lap time the
line's speed plan predicts when the car starts from rest. The follower needs no margin: it drives each
car's own line at the line's speeds (docs/physics.md, "The race line"; figures in BENCHMARKS.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from laplab.sim.simulator import Simulator
from laplab.sim.state import IN_PROGRESS, EpisodeParams
from laplab.track.geometry import Track
from laplab.vehicle.dynamics import CarState
from laplab.vehicle.dynamics import step as step_car
from laplab.vehicle.params import DEEPRACER, VehicleParams


@dataclass(frozen=True)
class LineFollowerParams:
    """Gains of :class:`LineFollower`.

    lateral_gain: 1/m^2, commanded curvature per metre of lateral error.
    heading_gain: 1/m, commanded curvature per radian of heading error.
    curvature_preview: decision steps (of ``v dt`` metres) ahead at which the line's curvature is read.
    speed_preview: decision steps ahead at which the line's speed is read (braking starts in time).
    grip_speed_cap: slow down so that the corrected curvature stays within the grip.
    """

    lateral_gain: float = 4.0
    heading_gain: float = 2.0
    curvature_preview: float = 0.5
    speed_preview: float = 0.75
    grip_speed_cap: bool = True

    def __post_init__(self) -> None:
        for name in ("lateral_gain", "heading_gain", "curvature_preview", "speed_preview"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"LineFollowerParams.{name} must be a finite number >= 0, got {value!r}")


def _closed_path(points: np.ndarray, speeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validated (M, 2) points and (M,) speeds with a repeated closing row dropped."""
    points = np.asarray(points, dtype=np.float64)
    speeds = np.asarray(speeds, dtype=np.float64).reshape(-1)
    if points.ndim != 2 or points.shape[1] != 2 or points.shape[0] < 4:
        raise ValueError(f"LineFollower: points must be a closed path of shape (M, 2), M >= 4, got {points.shape}")
    if speeds.shape[0] != points.shape[0]:
        raise ValueError(f"LineFollower: expected one speed per point ({points.shape[0]}), got {speeds.shape[0]}")
    if not (np.isfinite(points).all() and np.isfinite(speeds).all()) or (speeds < 0).any():
        raise ValueError("LineFollower: points and speeds must be finite, speeds >= 0 m/s")
    if np.allclose(points[0], points[-1], atol=1e-9, rtol=0.0):
        points, speeds = points[:-1], speeds[:-1]
    keep = np.linalg.norm(points - np.roll(points, -1, axis=0), axis=1) > 1e-9
    return np.ascontiguousarray(points[keep]), np.ascontiguousarray(speeds[keep])


def menger_curvature(points: np.ndarray) -> np.ndarray:
    """(M,) signed curvature (1/m, positive = left) of each point of the closed path (M, 2) and its
    two neighbours; exact on a circle."""
    a, b, c = np.roll(points, 1, axis=0), points, np.roll(points, -1, axis=0)
    ab, bc = b - a, c - b
    cross = ab[:, 0] * bc[:, 1] - ab[:, 1] * bc[:, 0]
    denom = np.linalg.norm(ab, axis=1) * np.linalg.norm(bc, axis=1) * np.linalg.norm(c - a, axis=1)
    return np.where(denom > 0, 2.0 * cross / np.maximum(denom, 1e-300), 0.0)


class LineFollower:
    """Follows a closed line with a speed plan, for N cars at once (control law: module docstring).

    points: (M, 2) m, the path of the model origin (rear-axle centre), closed (row 0 == row M-1) or
    not; speeds: (M,) m/s planned at each point; vehicle: the car being driven.
    """

    def __init__(self, points: np.ndarray, speeds: np.ndarray, vehicle: VehicleParams = DEEPRACER,
                 params: LineFollowerParams = LineFollowerParams()):
        self.points, self.speeds = _closed_path(points, speeds)
        self.vehicle, self.params = vehicle, params
        closed = np.vstack([self.points, self.points[:1]])
        self._seg_start = self.points
        self._seg_vec = closed[1:] - closed[:-1]
        self._seg_len = np.linalg.norm(self._seg_vec, axis=1)
        self._seg_dir = self._seg_vec / self._seg_len[:, None]
        self.arc = np.concatenate([[0.0], np.cumsum(self._seg_len)])  # (M+1,)
        self.length = float(self.arc[-1])
        self.curvature = menger_curvature(self.points)
        self._closed_curvature = np.append(self.curvature, self.curvature[0])
        self._closed_speeds = np.append(self.speeds, self.speeds[0])
        # Heading at each point (central difference), interpolated within segments: the segments'
        # own headings jump by kappa * ds at every point, which the heading gain would turn into noise.
        chord = np.roll(self.points, -1, axis=0) - np.roll(self.points, 1, axis=0)
        self.heading = np.arctan2(chord[:, 1], chord[:, 0])
        self._heading_step = np.mod(np.roll(self.heading, -1) - self.heading + np.pi, 2.0 * np.pi) - np.pi
        self._pivot_lead = -vehicle.pivot_offset  # m the origin lies ahead of the point moving along the yaw
        # The car through its action delay on the previous command: the same dynamics over that part of a
        # step, on the simulator's own sub-step grid (3 of v6's 4 sub-steps).
        self._delay_params = None if vehicle.action_delay <= 0 else vehicle.with_(
            decision_hz=vehicle.decision_hz / vehicle.action_delay, action_delay=0.0,
            substeps=max(1, round(vehicle.action_delay * vehicle.substeps)))

    @property
    def start_pose(self) -> np.ndarray:
        """(3,) pose (x, y, yaw) on the line's first point, heading along it."""
        return np.array([self.points[0, 0], self.points[0, 1], self.heading[0]])

    def project(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arc length s (N,) m, lateral error e (N,) m (left of the line positive) and heading error
        psi (N,) rad of the model origins of poses (N, 3) against the nearest line segment.

        Segments pointing against the car's yaw are passed over, so a car beside a hairpin does not
        snap to the other leg."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        n = poses.shape[0]
        segment, t = np.empty(n, dtype=np.int64), np.empty(n)
        heading = np.stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])], axis=1)
        for lo in range(0, n, 256):  # chunks bound the (chunk, M) temporaries
            rel = poses[lo:lo + 256, None, :2] - self._seg_start[None]
            frac = np.clip((rel * self._seg_vec[None]).sum(-1) / self._seg_len ** 2, 0.0, 1.0)
            gap = rel - frac[..., None] * self._seg_vec[None]
            dist_sq = (gap * gap).sum(-1)
            against = (heading[lo:lo + 256, None, :] * self._seg_dir[None]).sum(-1) < 0.0
            best = np.argmin(dist_sq + 1e6 * against, axis=1)
            segment[lo:lo + 256], t[lo:lo + 256] = best, frac[np.arange(best.size), best]
        direction = self._seg_dir[segment]
        rel = poses[:, :2] - self._seg_start[segment]
        lateral = direction[:, 0] * rel[:, 1] - direction[:, 1] * rel[:, 0]
        psi = poses[:, 2] - (self.heading[segment] + t * self._heading_step[segment])
        psi = np.mod(psi + np.pi, 2.0 * np.pi) - np.pi
        return self.arc[segment] + t * self._seg_len[segment], lateral, psi

    def _curvature_at(self, arc: np.ndarray) -> np.ndarray:
        return np.interp(np.mod(arc, self.length), self.arc, self._closed_curvature)

    def act(self, poses: np.ndarray, speeds: np.ndarray, steer: np.ndarray | None = None,
            previous: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Commands for poses (N, 3) of the model origins and measured speeds (N,) m/s:
        (steering angle (N,) rad, speed (N,) m/s).

        ``steer`` (N,) rad: the wheels' actual angle (the simulator's ``state.steer``, after the
        saturation); ``previous``: the last decision's (steering, speed) commands, each (N,). With both,
        the car is first carried through the action delay on its previous command, and the steering and
        speed lags are made up (module docstring); without them the car is taken as settled."""
        p, v = self.params, self.vehicle
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        speeds = np.maximum(np.asarray(speeds, dtype=np.float64).reshape(-1), 0.0)
        known = steer is not None and previous is not None
        preview = p.curvature_preview * v.dt
        if known:
            steer = np.asarray(steer, dtype=np.float64).reshape(-1)
            if self._delay_params is not None:
                state = step_car(CarState(poses[:, 0], poses[:, 1], poses[:, 2], speeds, steer),
                                 previous[0], previous[1], self._delay_params)
                poses = np.column_stack([state.x, state.y, state.yaw])
                speeds, steer = np.maximum(state.speed, 0.0), state.steer
        else:
            preview += v.response_steps * v.dt
        s, lateral, psi = self.project(poses)
        psi = psi + np.arctan(self._pivot_lead * self._curvature_at(s))  # the origin's path runs wide of the yaw
        correction = -p.lateral_gain * lateral - p.heading_gain * psi
        kappa = self._curvature_at(s + preview * speeds) + correction
        wheel = v.wheel_for_curvature(kappa, speeds)
        if known and v.steering_time_constant > 0:
            reach = 1.0 - math.exp(-v.dt / v.steering_time_constant)  # of the way to the command in a step
            wheel = steer + (wheel - steer) / reach
        command = v.command_for_wheel(wheel)

        speed_arc = s + p.speed_preview * v.dt * speeds
        speed = np.interp(np.mod(speed_arc, self.length), self.arc, self._closed_speeds)
        if p.grip_speed_cap:
            needed = np.abs(self._curvature_at(speed_arc) + correction)
            speed = np.minimum(speed, np.sqrt(v.max_lateral_acceleration / np.maximum(needed, 1e-9)))
        if known and v.speed_time_constant > 0 and p.speed_preview > 0:
            reach = 1.0 - math.exp(-p.speed_preview * v.dt / v.speed_time_constant)
            speed = speeds + (speed - speeds) / reach
        return command, np.clip(speed / v.speed_ratio, 0.0, v.max_speed)


@dataclass(frozen=True)
class LineDrive:
    """One simulated lap per car: lap_time (N,) s (0 when no lap), status (N,) status codes,
    max_lateral_error (N,) m largest distance of the origin from the line, min_wheels_on (N,) fewest
    wheels on the track at any step."""

    lap_time: np.ndarray
    status: np.ndarray
    max_lateral_error: np.ndarray
    min_wheels_on: np.ndarray


def start_on_line(sim: Simulator, cars: np.ndarray, follower: LineFollower, flying: np.ndarray) -> None:
    """Start new episodes for ``cars`` with their origin on the line's first point, heading along it.

    ``flying`` (K,) bool: at the line's speed there, with the steering its curvature needs (a flying
    lap), else at rest. The lap is counted from this pose: the episode's start arc is moved to the
    projection of the car's reference point, so progress starts at 0 and the lap ends when the
    reference point crosses the same spot again.
    """
    cars = np.asarray(cars, dtype=np.int64).reshape(-1)
    flying = np.broadcast_to(np.asarray(flying, dtype=bool), cars.shape)
    sim.reset(np.isin(np.arange(sim.num_cars), cars), ndist=0.0)
    speed = np.where(flying, follower.speeds[0], 0.0)
    wheel = np.where(flying, follower.vehicle.wheel_for_curvature(follower.curvature[0], follower.speeds[0]), 0.0)
    command = np.where(flying, follower.vehicle.command_for_wheel(wheel), 0.0)
    sim.place(cars, np.tile(follower.start_pose, (cars.size, 1)), speed=speed, steer=wheel, cmd_steer=command,
              cmd_speed=speed / sim.vehicle.speed_ratio)
    st = sim.state
    st.start_arc[cars], st.travel[cars], st.progress[cars] = st.arc[cars], 0.0, 0.0


def drive_line(track: Track, points: np.ndarray, speeds: np.ndarray, flying: np.ndarray,
               vehicle: VehicleParams = DEEPRACER, params: LineFollowerParams = LineFollowerParams(),
               max_steps: int = 20_000) -> LineDrive:
    """Drive one lap of the line (points (M, 2), speeds (M,)) per entry of ``flying`` (N,) bool with a
    :class:`LineFollower` in a :class:`Simulator` on ``track``; see :func:`start_on_line`."""
    flying = np.asarray(flying, dtype=bool).reshape(-1)
    follower = LineFollower(points, speeds, vehicle, params)
    sim = Simulator(track, flying.size, vehicle, EpisodeParams(round_robin_advance=0.0, max_steps=max_steps),
                    state_sensor=None)
    cars = np.arange(flying.size)
    start_on_line(sim, cars, follower, flying)
    st = sim.state
    max_error, min_wheels = np.zeros(flying.size), st.wheels_on.copy()
    while (st.status == IN_PROGRESS).any():
        steer, speed = follower.act(sim.poses(), st.speed, st.steer, (st.cmd_steer, st.cmd_speed))
        stepped = sim.step(steer, speed)
        _, lateral, _ = follower.project(sim.poses())
        max_error = np.where(stepped, np.maximum(max_error, np.abs(lateral)), max_error)
        min_wheels = np.where(stepped, np.minimum(min_wheels, st.wheels_on), min_wheels)
    return LineDrive(lap_time=st.lap_time.copy(), status=st.status.copy(), max_lateral_error=max_error,
                     min_wheels_on=min_wheels)
