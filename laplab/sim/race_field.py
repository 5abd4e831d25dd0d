"""The obstacles of a race, per car and episode: placement, bot motion, lane changes, other models' cars.

:class:`ObstacleField` keeps, for each of N cars, K slots (boxes, bot cars, or the other cars of its
head-to-model group) as arc length along the centre line of the car's driving direction and a lane
fraction (the signed offset as a share of that side's width: +0.5 is the left lane's centre, midway
between centre line and left border, -0.5 the right lane's; DeepRacer's inner and outer lanes are
these midlines). It fills the shared :class:`~laplab.sim.obstacles.Obstacles` (N, K) in place.

Placement follows simapp's ``obstacles_agent_ctrl`` / ``bot_cars_agent_ctrl``: fixed positions
(fraction of the lap, lane), else evenly spaced from the minimum distance to 1 m before the lap's
end on alternating lanes (inner first); randomised: each one, in shuffled order, drawn uniformly
between its neighbours +- the minimum distance, on a random lane. Bots drive their lane at a set
speed from where they were placed at the episode's start; with lane changes, each one switches to
the other lane over ``lane_change_distance`` m, a uniform ``lane_change_min_s``..``max_s`` s after the
previous change ended (the first after that long from the start).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from laplab.sim.kernel import PARALLEL_THRESHOLD
from laplab.sim.obstacles import BOT_CAR, BOX, EMPTY, MODEL_CAR, Obstacles, no_obstacles
from laplab.sim.race_type import HEAD_TO_BOT, HEAD_TO_MODEL, OBJECT_AVOIDANCE, RaceType

# DeepRacer's box obstacle (simapp models/box_obstacle: 0.4 x 0.3 x 0.25 m, brown #7b614f)
BOX_SIZE = (0.4, 0.3, 0.25)  # length along the track, width, height, m
CAR_HEIGHT = 0.16  # m, a DeepRacer car's body with its shell
LANE = 0.5  # lane fraction of DeepRacer's inner / outer lane


@nb.njit(cache=True)
def lane_pose(arc, frac, dfrac_ds, centerline, arc_length, left_w, right_w):
    """(x, y, yaw) of the point ``arc`` m along a centre line (wrapped) at lane fraction ``frac``;
    ``dfrac_ds`` (1/m) turns the heading while the fraction changes (a lane change)."""
    length = arc_length[-1]
    s = arc - math.floor(arc / length) * length
    seg = min(max(np.searchsorted(arc_length, s, side="right") - 1, 0), centerline.shape[0] - 2)
    seg_len = arc_length[seg + 1] - arc_length[seg]
    t = (s - arc_length[seg]) / seg_len if seg_len > 0 else 0.0
    dx, dy = centerline[seg + 1, 0] - centerline[seg, 0], centerline[seg + 1, 1] - centerline[seg, 1]
    norm = math.hypot(dx, dy)
    ux, uy = (dx / norm, dy / norm) if norm > 0 else (1.0, 0.0)
    width = (left_w[seg] + t * (left_w[seg + 1] - left_w[seg])) if frac > 0 else \
        (right_w[seg] + t * (right_w[seg + 1] - right_w[seg]))
    offset = frac * width
    x = centerline[seg, 0] + t * dx - uy * offset
    y = centerline[seg, 1] + t * dy + ux * offset
    half = 0.5 * (left_w[seg] + right_w[seg])
    return x, y, math.atan2(uy, ux) + math.atan(dfrac_ds * half)


@nb.njit(cache=True)
def lane_poses(arc, frac, centerline, arc_length, left_w, right_w):
    """(K, 3) :func:`lane_pose` of K points (no lane change)."""
    out = np.empty((arc.shape[0], 3))
    for k in range(arc.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = lane_pose(arc[k], frac[k], 0.0, centerline, arc_length, left_w, right_w)
    return out


@nb.njit(cache=True)
def advance_bots(cars, time, arc, frac, frac_from, frac_to, change_start, next_change, speed, dt,
                 lane_change, change_dist, uniform, change_min, change_max):
    """Move the bots of ``cars`` one step along their lanes, starting and finishing lane changes
    (``uniform`` (N, K): draws in [0, 1) for the next change times). Returns dfrac/ds (N, K)."""
    slope = np.zeros(arc.shape)
    for n in range(cars.shape[0]):
        i = cars[n]
        time[i] += dt
        for k in range(arc.shape[1]):
            arc[i, k] += speed * dt
            if lane_change and time[i] >= next_change[i, k] and frac_from[i, k] == frac_to[i, k] \
                    and frac[i, k] != 0.0:
                frac_to[i, k] = -frac[i, k]
                change_start[i, k] = arc[i, k]
                next_change[i, k] = time[i] + change_dist / speed + change_min + uniform[i, k] * (change_max - change_min)
            if frac_from[i, k] != frac_to[i, k]:
                u = (arc[i, k] - change_start[i, k]) / change_dist
                if u >= 1.0:
                    frac[i, k] = frac_to[i, k]
                    frac_from[i, k] = frac_to[i, k]
                else:
                    u = max(u, 0.0)
                    ease = u * u * (3.0 - 2.0 * u)
                    frac[i, k] = frac_from[i, k] + ease * (frac_to[i, k] - frac_from[i, k])
                    slope[i, k] = (frac_to[i, k] - frac_from[i, k]) * 6.0 * u * (1.0 - u) / change_dist
    return slope


def spread(count: int, length: float, gap: float, randomize: bool, rng: np.random.Generator) -> np.ndarray:
    """Arc lengths (m) of ``count`` objects on a lap of ``length`` m, DeepRacer's way: evenly from
    ``gap`` to 1 m before the end, then (``randomize``) each, in shuffled order, uniform between its
    neighbours +- ``gap``."""
    start, end = gap, length - 1.0
    dists = np.linspace(start, end, count)
    if randomize:
        for i in rng.permutation(count):
            lo = start if i == 0 else dists[i - 1] + gap
            hi = end if i == count - 1 else dists[i + 1] - gap
            if lo < hi:
                dists[i] = rng.uniform(lo, hi)
    return dists


class ObstacleField:
    """The obstacles of every car of a simulator under one :class:`RaceType` (see the module docstring).

    ``arrays``: the simulator's (forward, reversed) TrackArrays; ``inner_left``: per direction, whether
    DeepRacer's inner lane is on the left; ``group``: cars per head-to-model race (car i races the
    other cars of ``i // group``).
    """

    def __init__(self, race: RaceType, arrays, inner_left: tuple[bool, bool], num_cars: int, dt: float,
                 body: tuple[float, float, float], seed: int | None = None):
        self.race, self.arrays, self.dt = race, arrays, float(dt)
        self.inner_sign = np.array([1.0 if left else -1.0 for left in inner_left])
        self.num_cars, self.slots = int(num_cars), race.slots
        self.group = race.slots + 1 if race.kind == HEAD_TO_MODEL else 1
        self.rng = np.random.default_rng(seed)
        self.body_offset, self.body_half_length, self.body_half_width = body
        shape = (self.num_cars, self.slots)
        self.obstacles: Obstacles = no_obstacles(self.num_cars, self.slots)
        self.arc, self.frac = np.zeros(shape), np.zeros(shape)
        self.frac_from, self.frac_to = np.zeros(shape), np.zeros(shape)
        self.change_start, self.next_change = np.zeros(shape), np.zeros(shape)
        self.slope, self.speed = np.zeros(shape), np.zeros(shape)
        self.time = np.zeros(self.num_cars)
        self._fill_kind_and_size()

    @property
    def moving(self) -> bool:
        return self.race.kind in (HEAD_TO_BOT, HEAD_TO_MODEL)

    def _fill_kind_and_size(self) -> None:
        ob, race = self.obstacles, self.race
        car = (self.body_half_length, self.body_half_width, CAR_HEIGHT)
        if race.kind == OBJECT_AVOIDANCE and race.object_type == "box":
            kind, size = BOX, (0.5 * BOX_SIZE[0], 0.5 * BOX_SIZE[1], BOX_SIZE[2])
        else:
            kind = {OBJECT_AVOIDANCE: BOT_CAR, HEAD_TO_BOT: BOT_CAR, HEAD_TO_MODEL: MODEL_CAR}[race.kind]
            size = car
        ob.kind[:] = kind
        ob.half_length[:], ob.half_width[:], ob.height[:] = size
        if race.kind == HEAD_TO_BOT:
            self.speed[:] = race.bot_speed

    def _lanes(self, count: int, randomize: bool, lane_name: str = "alternate") -> np.ndarray:
        """(count,) lane fractions in inner-lane units (+1 inner, -1 outer, 0 centre)."""
        if randomize and lane_name == "alternate":
            return self.rng.choice((1.0, -1.0), size=count)
        if lane_name == "alternate":
            return np.where(np.arange(count) % 2 == 0, 1.0, -1.0)
        return np.full(count, {"inner": 1.0, "outer": -1.0, "center": 0.0}[lane_name])

    def reset(self, cars: np.ndarray, direction: np.ndarray) -> None:
        """Place the obstacles of ``cars`` (K,) for new episodes; ``direction`` (K,) their driving directions."""
        race = self.race
        if race.kind == HEAD_TO_MODEL or cars.size == 0:
            return
        length = self.arrays[0].length
        random = race.randomize_objects if race.kind == OBJECT_AVOIDANCE else race.randomize_bots
        if race.kind == OBJECT_AVOIDANCE and race.object_positions:
            arcs = np.array([p[0] for p in race.object_positions]) * length
            lanes = np.array([float(p[1]) for p in race.object_positions])
        elif race.kind == OBJECT_AVOIDANCE:
            arcs = spread(race.objects, length, race.min_object_distance, False, self.rng)
            lanes = self._lanes(race.objects, False)
        else:
            arcs = spread(race.bots, length, race.min_bot_distance, False, self.rng)
            lanes = self._lanes(race.bots, False, race.bot_lane)
        if random and not (race.kind == OBJECT_AVOIDANCE and race.object_positions):  # drawn per car
            count, gap = (race.objects, race.min_object_distance) if race.kind == OBJECT_AVOIDANCE else \
                (race.bots, race.min_bot_distance)
            arcs = np.stack([spread(count, length, gap, True, self.rng) for _ in range(cars.size)])
            lanes = np.stack([self._lanes(count, True, "alternate" if race.kind == OBJECT_AVOIDANCE else race.bot_lane)
                              for _ in range(cars.size)])
        self.arc[cars] = arcs
        frac = LANE * lanes * self.inner_sign[direction][:, None]
        self.frac[cars] = self.frac_from[cars] = self.frac_to[cars] = frac
        self.time[cars] = 0.0
        self.slope[cars] = 0.0
        if race.kind == HEAD_TO_BOT:
            self.next_change[cars] = race.lane_change_min_s + self.rng.random((cars.size, self.slots)) * (
                race.lane_change_max_s - race.lane_change_min_s)

    def advance(self, cars: np.ndarray) -> None:
        """Move the bots of ``cars`` (those stepped) by one step."""
        race = self.race
        if race.kind != HEAD_TO_BOT or cars.size == 0:
            return
        uniform = self.rng.random(self.arc.shape)
        self.slope = advance_bots(cars, self.time, self.arc, self.frac, self.frac_from, self.frac_to,
                                  self.change_start, self.next_change, float(race.bot_speed), self.dt,
                                  bool(race.lane_change), float(race.lane_change_distance), uniform,
                                  float(race.lane_change_min_s), float(race.lane_change_max_s))

    def update(self, state, cars: np.ndarray, ghost: np.ndarray | None = None) -> None:
        """Write the world poses of the obstacles of ``cars`` into :attr:`obstacles` (head-to-model:
        the bodies of the other cars of each group, from the simulator's ``state``; a car in ``ghost``
        (N,) bool, or whose episode ended, is no obstacle)."""
        if ghost is None:
            ghost = np.zeros(self.num_cars, dtype=np.bool_)
        ob = self.obstacles
        if self.race.kind == HEAD_TO_MODEL:
            _group_bodies(cars, self.group, state.x, state.y, state.yaw, state.speed, state.status, ghost,
                          self.body_offset, ob.x, ob.y, ob.yaw, ob.kind, self.speed)
            return
        args = (cars, state.direction, self.arc, self.frac, self.slope, self.arrays[0], self.arrays[1], ob.x, ob.y,
                ob.yaw)
        if cars.size >= PARALLEL_THRESHOLD:
            _poses_parallel(8 * nb.get_num_threads(), cars.size, *args)
        else:
            _poses(0, cars.size, *args)


@nb.njit(cache=True, parallel=True)
def _poses_parallel(chunks, n, cars, direction, arc, frac, slope, fwd, rev, ox, oy, oyaw):
    size = (n + chunks - 1) // chunks
    for c in nb.prange(chunks):
        _poses(min(c * size, n), min((c + 1) * size, n), cars, direction, arc, frac, slope, fwd, rev, ox, oy, oyaw)


@nb.njit(cache=True)
def _poses(lo, hi, cars, direction, arc, frac, slope, fwd, rev, ox, oy, oyaw):
    for n in range(lo, hi):
        i = cars[n]
        geo = fwd if direction[i] == 0 else rev
        for k in range(arc.shape[1]):
            x, y, yaw = lane_pose(arc[i, k], frac[i, k], slope[i, k], geo.centerline, geo.arc_length,
                                  geo.left_width, geo.right_width)
            ox[i, k], oy[i, k], oyaw[i, k] = x, y, yaw


@nb.njit(cache=True)
def _group_bodies(cars, group, x, y, yaw, speed, status, ghost, body_offset, ox, oy, oyaw, okind, ospeed):
    # slot j of car i: the j-th other car of its group; a car whose race ended leaves the track
    for n in range(cars.shape[0]):
        i = cars[n]
        first = (i // group) * group
        j = 0
        for other in range(first, first + group):
            if other == i:
                continue
            c, s = math.cos(yaw[other]), math.sin(yaw[other])
            ox[i, j], oy[i, j], oyaw[i, j] = x[other] + body_offset * c, y[other] + body_offset * s, yaw[other]
            okind[i, j] = MODEL_CAR if status[other] == 0 and not ghost[other] else EMPTY
            ospeed[i, j] = speed[other]
            j += 1

