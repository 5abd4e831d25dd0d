"""A batch of N cars on one track: starts, resets and the 15 Hz step (state kept in arrays)."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from laplab.sensors.state_vector import StateSensorParams
from laplab.sim.kernel import empty_obs, observe_kernel, place_kernel, step_kernel
from laplab.sim.collision import summary_size
from laplab.sim.obstacles import Obstacles, no_obstacles
from laplab.sim.race_type import HEAD_TO_MODEL, RaceType
from laplab.sim.state import IN_PROGRESS, EpisodeParams, SimState, empty_state
from laplab.track.geometry import Track
from laplab.track.params_geometry import ParamsGeometry, params_geometry
from laplab.track.projection import TrackArrays, project_points, track_arrays
from laplab.vehicle.dynamics import dynamics_constants
from laplab.vehicle.params import DEEPRACER, VehicleParams


class Simulator:
    """N cars driving one track, each in its own episode.

    ``state`` (a :class:`SimState` of (N,) arrays) and ``obs`` ((N, D) float32 STATE observations, D = 0
    without the STATE sensor) are preallocated and updated in place by :meth:`step` and :meth:`reset`.

    ``race`` (a :class:`~laplab.sim.race_type.RaceType`; None: time trial) puts boxes, bot cars or the
    other cars of a head-to-model group on the track: :attr:`obstacles` holds them, (N, K) per car,
    placed at every reset and moved every step; a car whose body hits one ends its episode
    ``crashed``; the STATE vector gains a summary of the nearest ones
    (:func:`laplab.sim.collision.write_summary`). ``seed`` seeds their random placement and lane
    changes. Head-to-model: cars ``g * group .. (g + 1) * group - 1`` race each other.
    """

    def __init__(self, track: Track, num_cars: int = 1, vehicle: VehicleParams = DEEPRACER,
                 episode: EpisodeParams = EpisodeParams(), state_sensor: StateSensorParams | None = StateSensorParams(),
                 race: RaceType | None = None, seed: int | None = None):
        if num_cars < 1:
            raise ValueError(f"num_cars must be >= 1, got {num_cars}")
        self.num_cars = int(num_cars)
        self.vehicle, self.episode, self.state_sensor = vehicle, episode, state_sensor
        self.race = race if race is not None else RaceType()
        self.tracks: tuple[Track, Track] = (track, track.reversed())
        self.arrays: tuple[TrackArrays, TrackArrays] = tuple(track_arrays(t) for t in self.tracks)
        self.state: SimState = empty_state(self.num_cars)
        self.field = self._obstacle_field(seed) if self.race.has_objects else None
        self._summary_at = state_sensor.size if state_sensor else 0
        extra = summary_size() if (self.field is not None and state_sensor) else 0
        self.obs = empty_obs(self.num_cars, (state_sensor.size if state_sensor else 0) + extra)
        self.last_hit = np.full(self.num_cars, -1, dtype=np.int64)  # slot each car hit on its last step
        # cars that collide with nothing and are no obstacle to others (DeepRacer's blinking car serving a penalty)
        self.ghost = np.zeros(self.num_cars, dtype=np.bool_)
        self._no_obstacles = no_obstacles(self.num_cars)
        self._look = (state_sensor.lookahead_count, state_sensor.spacing) if state_sensor else (1, 1.0)
        self._vc = dynamics_constants(vehicle) + (float(vehicle.dt), float(vehicle.reference_offset),
                                                  0.5 * vehicle.wheel_track, float(vehicle.max_speed),
                                                  float(vehicle.max_steering))
        self._rules = (int(episode.max_steps), int(episode.reversed_steps), int(episode.immobilized_steps),
                       float(episode.immobilized_distance))
        self._episodes_done = np.zeros(self.num_cars, dtype=np.int64)
        self.state.status[:] = -1  # not started

    def _obstacle_field(self, seed):
        from laplab.sim.race_field import ObstacleField
        race, v = self.race, self.vehicle
        self.race.check_track(self.tracks[0].length, self.tracks[0].name)
        if race.kind == HEAD_TO_MODEL and self.num_cars % (race.slots + 1):
            raise ValueError(f"head-to-model races of {race.slots + 1} cars need a multiple of {race.slots + 1} cars, "
                             f"got {self.num_cars}")
        body = (0.5 * v.body_length - v.rear_overhang, 0.5 * v.body_length, 0.5 * v.body_width)
        return ObstacleField(race, self.arrays, tuple(t.is_ccw for t in self.tracks), self.num_cars, v.dt, body, seed)

    @property
    def obstacles(self) -> Obstacles:
        """What is on the track besides each car: (N, K) slots, world frame, current (K = 0 in a time trial)."""
        return self.field.obstacles if self.field is not None else self._no_obstacles

    @property
    def track(self) -> Track:
        return self.tracks[0]

    @property
    def dt(self) -> float:
        return self.vehicle.dt

    @cached_property
    def params_geometry(self) -> tuple[ParamsGeometry, ParamsGeometry]:
        """What DeepRacer's ``closest_waypoints``, ``track_width`` and ``is_left_of_center`` need, per
        direction (built on first use: only reward params read it)."""
        return tuple(params_geometry(t) for t in self.tracks)

    def track_of(self, car: int) -> Track:
        """The track in the direction car ``car`` is driving."""
        return self.tracks[int(self.state.direction[car])]

    def poses(self) -> np.ndarray:
        """(N, 3) model-origin poses (x, y, yaw)."""
        return np.stack([self.state.x, self.state.y, self.state.yaw], axis=1)

    def next_start(self, cars: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Start fraction of the lap and direction of the next episode of each car in ``cars``."""
        ep = self.episode
        order = self._episodes_done[cars] + (cars if ep.spread_starts else 0)
        ndist = np.mod(ep.start_ndist + ep.round_robin_advance * order, 1.0)
        direction = np.full(cars.shape, int(ep.reverse), dtype=np.int64)
        if ep.alternate_direction:
            direction ^= (self._episodes_done[cars] % 2).astype(np.int64)
        return ndist, direction

    def restart_schedule(self, episodes_done: int = 0) -> None:
        """Set every car's count of finished episodes, which places the next round-robin starts
        (0: the schedule starts over, as ``reset(seed=...)`` of the envs does; a resumed training job
        continues from the episodes it has run)."""
        self._episodes_done[:] = int(episodes_done)

    def reset(self, mask: np.ndarray | None = None, ndist: np.ndarray | None = None,
              direction: np.ndarray | None = None) -> None:
        """Start new episodes for the cars in ``mask`` (all when None).

        Each car is placed with its origin on the centre line at ``ndist`` (fraction of the lap, default
        from the round-robin schedule), facing along it, at rest. Its progress counts from that point, as
        DeepRacer's does: the first step finds the reference point already 0.14 m along (on a straight).
        """
        cars = np.arange(self.num_cars) if mask is None else np.flatnonzero(mask)
        if cars.size == 0:
            return
        auto_ndist, auto_dir = self.next_start(cars)
        ndist = auto_ndist if ndist is None else np.broadcast_to(np.asarray(ndist, dtype=np.float64), cars.shape)
        direction = auto_dir if direction is None else np.broadcast_to(np.asarray(direction, np.int64), cars.shape)
        st = self.state
        st.direction[cars] = direction
        for d in (0, 1):
            sel = cars[direction == d]
            if sel.size:
                self._place(sel, d, ndist[direction == d])
        self._episodes_done[cars] += 1
        st.episode[cars] += 1
        if self.field is not None:  # cars may move beside an obstacle: their rows are written again
            self.field.reset(cars, st.direction[cars])
            self._start_beside_obstacles(cars)
            self.field.update(st, np.arange(self.num_cars) if self.race.kind == HEAD_TO_MODEL else cars, self.ghost)
            self._observe(cars)

    def _start_beside_obstacles(self, cars: np.ndarray) -> None:
        """DeepRacer's start rule: a car whose start has an obstacle within 1 m (along the track) starts
        in the other lane; head-to-model cars start side by side, inner and outer lane in turn."""
        from laplab.sim.race_field import LANE, lane_poses
        st, field = self.state, self.field
        if self.race.kind == HEAD_TO_MODEL:
            frac = np.where((cars % field.group) % 2 == 0, LANE, -LANE) * field.inner_sign[st.direction[cars]]
        else:
            length = self.track.length
            gap = np.abs(wrapped_travel(field.arc[cars] - st.start_arc[cars, None], length))
            near = gap.argmin(axis=1)
            blocked = gap[np.arange(cars.size), near] < 1.0
            cars = cars[blocked]
            lane = field.frac[cars, near[blocked]]
            frac = np.where(lane > 0, -LANE, LANE)
        for d in (0, 1):
            sel = st.direction[cars] == d
            if not sel.any():
                continue
            sub, geo = cars[sel], self.arrays[d]
            poses = lane_poses(st.start_arc[sub], frac[sel], geo.centerline, geo.arc_length, geo.left_width,
                               geo.right_width)
            poses[:, 2] = st.yaw[sub]
            st.x[sub], st.y[sub] = poses[:, 0], poses[:, 1]
            proj = self._project_reference(sub, d, poses)
            st.travel[sub] = wrapped_travel(proj.arc_length - st.start_arc[sub], self.tracks[d].length)

    def _observe(self, cars: np.ndarray) -> None:
        """Recompute the STATE observation rows of ``cars`` from their current state."""
        mask = np.zeros(self.num_cars, dtype=np.bool_)
        mask[cars] = True
        observe_kernel(self.state, self.arrays[0], self.arrays[1], self._vc, self.obs, *self._look, mask)
        self._summarise(np.asarray(cars, dtype=np.int64))

    def _summarise(self, cars: np.ndarray) -> None:
        if self.field is None or self.obs.shape[1] == self._summary_at or cars.size == 0:
            return
        from laplab.sim.collision import SUMMARY_COUNT, write_summary
        ob = self.field.obstacles
        write_summary(self.obs, self._summary_at, cars, self.state, ob.x, ob.y, ob.kind, self.field.speed,
                      float(self.vehicle.max_speed), SUMMARY_COUNT)

    def _project_reference(self, cars: np.ndarray, direction: int, poses: np.ndarray):
        """Set the reference point of ``cars`` (all driving ``direction``) at ``poses`` (K, 3) and its
        projection (arc, segment, position in the segment, lateral offset); returns the projection."""
        from laplab.vehicle.dynamics import reference_point
        st, track = self.state, self.tracks[direction]
        ref = reference_point(poses, self.vehicle)
        proj = project_points(self.arrays[direction], ref)
        seg_len = np.maximum(np.diff(track.arc_length)[proj.segment], 1e-12)
        st.ref_x[cars], st.ref_y[cars] = ref[:, 0], ref[:, 1]
        st.arc[cars], st.segment[cars], st.lateral[cars] = proj.arc_length, proj.segment, proj.lateral
        # the closing point is reported at arc 0 but lies at the end (t = 1) of the last segment
        start = track.arc_length[proj.segment]
        arc = np.where(proj.arc_length < start, proj.arc_length + track.length, proj.arc_length)
        st.seg_t[cars] = np.clip((arc - start) / seg_len, 0.0, 1.0)
        return proj

    def _place(self, cars: np.ndarray, direction: int, ndist: np.ndarray) -> None:
        """Start episodes of ``cars`` (all driving ``direction``) at rest at ``ndist`` of the lap, their
        STATE rows written (:func:`place_kernel`)."""
        start_arc = np.mod(ndist, 1.0) * self.tracks[direction].length
        place_kernel(self.state, np.ascontiguousarray(cars, dtype=np.int64), np.ascontiguousarray(start_arc),
                     self.arrays[direction], self._vc, self.obs, *self._look)

    def place(self, cars: np.ndarray, poses: np.ndarray, *, speed=0.0, steer=0.0, cmd_speed=None,
              cmd_steer=None, steps=None, start_arc=None) -> None:
        """Put cars at given poses (K, 3) within their current episodes and recompute what follows.

        For hand-built states (tests, reward validation): sets pose and speeds, then the reference
        point's projection, progress since the episode's start (0..100, forward travel), wheels on
        track, and ``off_track`` status when no wheel is on the track. ``start_arc`` (m) moves where
        the cars' episodes started (progress counts from there).
        """
        from laplab.sim.state import OFF_TRACK
        from laplab.track.projection import points_on_track
        from laplab.vehicle.dynamics import wheel_centers

        cars = np.asarray(cars, dtype=np.int64).reshape(-1)
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        st = self.state
        st.x[cars], st.y[cars], st.yaw[cars] = poses[:, 0], poses[:, 1], poses[:, 2]
        st.speed[cars], st.steer[cars] = speed, steer
        st.cmd_speed[cars] = speed if cmd_speed is None else cmd_speed
        st.cmd_steer[cars] = steer if cmd_steer is None else cmd_steer
        if steps is not None:
            st.steps[cars] = steps
        if start_arc is not None:
            st.start_arc[cars] = start_arc
        wheels = wheel_centers(poses, self.vehicle)
        for d in (0, 1):
            sel = st.direction[cars] == d
            if not sel.any():
                continue
            sub, track, arrays = cars[sel], self.tracks[d], self.arrays[d]
            proj = self._project_reference(sub, d, poses[sel])
            st.travel[sub] = np.mod(proj.arc_length - st.start_arc[sub], track.length)
            st.progress[sub] = 100.0 * st.travel[sub] / track.length
            hints = np.repeat(proj.segment, 4)
            on = points_on_track(arrays, wheels[sel].reshape(-1, 2), hints).reshape(-1, 4)
            st.wheels_on[sub] = on.sum(axis=1)
        st.status[cars] = np.where(st.wheels_on[cars] == 0, OFF_TRACK, IN_PROGRESS)
        self._observe(cars)

    def set_steps(self, cars: np.ndarray, steps: np.ndarray) -> None:
        """Set the step counters of ``cars`` (hand-built states: as if they had driven there)."""
        self.state.steps[np.asarray(cars, dtype=np.int64)] = steps

    def set_travel(self, cars: np.ndarray, travel: np.ndarray) -> None:
        """Set the distance ``cars`` have travelled since their start (m, (K,)) and their progress from
        it, and clear the reversed / immobilized counters (a car put back after an incident)."""
        cars = np.asarray(cars, dtype=np.int64).reshape(-1)
        st, length = self.state, self.track.length
        st.travel[cars] = travel
        st.progress[cars] = np.clip(100.0 * st.travel[cars] / length, 0.0, 100.0)
        st.reverse_count[cars] = 0
        st.immobile_count[cars] = 0

    def continue_lap(self, cars: np.ndarray) -> None:
        """Cars that just completed a lap drive on into the next one (a flying start): one lap is taken
        off their travel, progress follows, and their episodes are in progress again."""
        cars = np.asarray(cars, dtype=np.int64).reshape(-1)
        st, length = self.state, self.track.length
        st.travel[cars] -= length
        st.progress[cars] = np.clip(100.0 * st.travel[cars] / length, 0.0, 100.0)
        st.status[cars] = IN_PROGRESS

    def end_episodes(self, cars: np.ndarray, status: int) -> None:
        """End the episodes of ``cars`` with ``status`` (a code of :mod:`laplab.sim.state`), e.g.
        ``time_up`` when a caller's clock runs out."""
        self.state.status[np.asarray(cars, dtype=np.int64)] = status

    def step(self, cmd_steer: np.ndarray, cmd_speed: np.ndarray) -> np.ndarray:
        """Advance every in-progress car by one decision (1/15 s).

        ``cmd_steer`` (N,) rad and ``cmd_speed`` (N,) m/s. Returns the (N,) bool mask of the cars that
        were stepped (those in progress before the call).
        """
        stepped = self.state.status == IN_PROGRESS
        field = self.field
        if field is not None and self.race.kind != HEAD_TO_MODEL:
            moving = np.flatnonzero(stepped)
            field.advance(moving)
            if field.moving:
                field.update(self.state, moving)
        step_kernel(self.state, np.ascontiguousarray(cmd_steer, dtype=np.float64),
                    np.ascontiguousarray(cmd_speed, dtype=np.float64), self.arrays[0], self.arrays[1],
                    self._vc, self._rules, self.obs, *self._look)
        if field is not None:
            self._collide(stepped)
        return stepped

    def let_obstacles_drive(self, cars: np.ndarray, seconds: np.ndarray) -> None:
        """Move the bots of ``cars`` on by ``seconds`` (K,) while the cars stand (an evaluation penalty)."""
        field = self.field
        if field is None or not field.moving or self.race.kind == HEAD_TO_MODEL:
            return
        cars = np.asarray(cars, dtype=np.int64)
        steps = np.ceil(np.asarray(seconds, dtype=np.float64) / self.dt - 1e-9).astype(np.int64)
        for k in range(int(steps.max(initial=0))):
            field.advance(cars[steps > k])
        field.update(self.state, cars)
        self._summarise(cars)

    def _collide(self, stepped: np.ndarray) -> None:
        """After a step: other models' cars move to their new poses, cars that hit an obstacle crash,
        and the STATE summaries follow."""
        from laplab.sim.collision import COLLISION_MARGIN, SUMMARY_COUNT, collide_and_summarise
        field, st = self.field, self.state
        if self.race.kind == HEAD_TO_MODEL:
            field.update(st, np.arange(self.num_cars), self.ghost)
        count = SUMMARY_COUNT if self.obs.shape[1] > self._summary_at else 0
        collide_and_summarise(st, stepped & ~self.ghost, field.obstacles, COLLISION_MARGIN,
                              (field.body_offset, field.body_half_length, field.body_half_width), self.last_hit,
                              self.obs, self._summary_at, field.speed, float(self.vehicle.max_speed), count)


def wrapped_travel(delta: np.ndarray, length: float) -> np.ndarray:
    """Arc-length differences (m) wrapped into [-length / 2, length / 2): the shorter way round."""
    return np.mod(np.asarray(delta, dtype=np.float64) + 0.5 * length, length) - 0.5 * length
