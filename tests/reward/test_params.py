"""The reward function's params dict on hand-placed cars, against closed-form answers on a circle.

The circle track (centre-line radius 3 m, width 1 m, 400 segments, counter-clockwise, waypoint 0 at
(3, 0)) makes every key computable by hand: a point at polar (r, theta) is |r - 3| from the centre
line, left of it (driving CCW) when r < 3, and theta / 2 pi of the lap from waypoint 0.
A car is placed by writing its pose into ``sim.state`` and stepping once with speed 0 (a car at rest
commanded to stay at rest does not move), which recomputes every derived field.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from laplab.reward.params import PARAMS_KEYS, ParamsBuilder, heading_deg
from laplab.sim.simulator import Simulator
from laplab.sim.state import EpisodeParams
from laplab.vehicle.params import CLASSIC

DEEPRACER = CLASSIC  # laplab's classic car: the closed forms below (one step from rest) hold for it

RADIUS, WIDTH, SEGMENTS = 3.0, 1.0, 400
OFFSET = DEEPRACER.reference_offset
TOL = 1e-3  # m: the 400-gon differs from the circle by < 1e-4 m

FLOAT_KEYS = ("x", "y", "heading", "distance_from_center", "progress", "steps", "speed", "steering_angle",
              "track_width", "track_length", "projection_distance")
BOOL_KEYS = ("all_wheels_on_track", "is_left_of_center", "is_offtrack", "is_crashed", "is_reversed",
             "object_in_camera")


@pytest.fixture()
def sim(circle_track):
    simulator = Simulator(circle_track, 2, CLASSIC, episode=EpisodeParams(start_ndist=0.0, round_robin_advance=0.0))
    simulator.reset()
    return simulator


def place(sim: Simulator, car: int, x: float, y: float, yaw: float) -> None:
    """Put car ``car`` at rest at pose (x, y, yaw) and let the kernel derive the rest (one step at speed 0)."""
    st = sim.state
    st.x[car], st.y[car], st.yaw[car], st.speed[car], st.steer[car] = x, y, yaw, 0.0, 0.0
    others = np.arange(sim.num_cars) != car
    saved = [a[others].copy() for a in st]
    sim.step(np.zeros(sim.num_cars), np.zeros(sim.num_cars))
    for a, b in zip(st, saved):  # the other car did not move either, but keep its step count too
        a[others] = b


def polar_pose(radius: float, theta: float, clockwise: bool = False) -> tuple[float, float, float]:
    """Pose on a circle of ``radius`` at angle ``theta``, facing along it (CCW, or CW when asked)."""
    yaw = theta - math.pi / 2 if clockwise else theta + math.pi / 2
    return radius * math.cos(theta), radius * math.sin(theta), yaw


def reference_polar(x: float, y: float, yaw: float) -> tuple[float, float, float, float]:
    """(ref x, ref y, radius, angle in [0, 2 pi)) of the reference point of pose (x, y, yaw)."""
    rx, ry = x + OFFSET * math.cos(yaw), y + OFFSET * math.sin(yaw)
    return rx, ry, math.hypot(rx, ry), math.atan2(ry, rx) % (2 * math.pi)


def polygon_projection(px: float, py: float) -> tuple[int, float, float]:
    """(segment, arc length m, distance m) of a point projected onto the 400-gon centre line, by hand:
    the segment is the one whose angular sector holds the point (exact away from the vertices)."""
    step = 2 * math.pi / SEGMENTS
    k = int((math.atan2(py, px) % (2 * math.pi)) // step)
    a = RADIUS * np.array([math.cos(k * step), math.sin(k * step)])
    b = RADIUS * np.array([math.cos((k + 1) * step), math.sin((k + 1) * step)])
    chord = b - a
    t = min(max(float(np.dot([px, py] - a, chord) / np.dot(chord, chord)), 0.0), 1.0)
    foot = a + t * chord
    return k, (k + t) * float(np.linalg.norm(chord)), float(np.hypot(px - foot[0], py - foot[1]))


def test_every_key_with_its_type(sim):
    params = ParamsBuilder(sim).build()
    assert len(params) == 2
    for p in params:
        assert tuple(p) == PARAMS_KEYS and len(set(PARAMS_KEYS)) == 26
        for key in FLOAT_KEYS:
            assert type(p[key]) is float, key
        for key in BOOL_KEYS:
            assert type(p[key]) is bool, key
        assert type(p["closest_waypoints"]) is list and all(type(i) is int for i in p["closest_waypoints"])
        assert type(p["waypoints"]) is list
        assert all(type(w) is tuple and len(w) == 2 and all(type(c) is float for c in w) for w in p["waypoints"])
        assert p["closest_objects"] == [0, 0]
        for key in ("objects_location", "objects_left_of_center", "objects_speed", "objects_heading",
                    "objects_distance", "objects_distance_from_center"):
            assert p[key] == [], key
        assert p["object_in_camera"] is False and p["is_crashed"] is False


@pytest.mark.parametrize("radius, theta", [(3.0, 1.0), (2.75, 2.0), (3.3, 4.0), (2.6, 5.9)])
def test_values_of_a_placed_car(sim, circle_track, radius, theta):
    builder = ParamsBuilder(sim)
    start = builder.build([0])[0]
    # reset put the origin on waypoint 0, (3, 0), facing along segment 0 (the chord, not the tangent)
    assert (sim.state.x[0], sim.state.y[0]) == (RADIUS, 0.0)
    assert sim.state.yaw[0] == pytest.approx(math.pi / 2 + math.pi / SEGMENTS, abs=1e-12)
    _, start_arc, _ = polygon_projection(*reference_polar(RADIUS, 0.0, sim.state.yaw[0])[:2])
    assert start["projection_distance"] == pytest.approx(start_arc, abs=1e-9)

    hops = np.linspace(0.0, theta, int(math.ceil(theta / 2.0)) + 1)[1:]  # under half a lap per step
    for hop in hops:
        pose = polar_pose(radius, hop)
        place(sim, 0, *pose)
    p = builder.build([0])[0]
    rx, ry, r_ref, angle = reference_polar(*pose)
    length = circle_track.length
    assert p["x"] == pytest.approx(rx, abs=1e-12) and p["y"] == pytest.approx(ry, abs=1e-12)
    assert p["heading"] == pytest.approx(math.degrees(math.atan2(math.sin(pose[2]), math.cos(pose[2]))), abs=1e-9)
    assert -180.0 < p["heading"] <= 180.0
    segment, arc, distance = polygon_projection(rx, ry)
    assert p["distance_from_center"] == pytest.approx(distance, abs=1e-9)
    assert p["distance_from_center"] == pytest.approx(abs(r_ref - RADIUS), abs=TOL)
    assert p["is_left_of_center"] is (r_ref < RADIUS)  # CCW: the inside of the circle is on the left
    assert p["projection_distance"] == pytest.approx(arc, abs=1e-9)
    assert p["projection_distance"] == pytest.approx(length * angle / (2 * math.pi), abs=0.01)
    # DeepRacer counts progress from the start pose's own centre-line point: waypoint 0 (arc 0)
    assert p["progress"] == pytest.approx(100 * arc / length, abs=1e-7)
    assert p["steps"] == float(len(hops))
    assert p["track_width"] == pytest.approx(WIDTH, abs=TOL)
    assert p["track_length"] == pytest.approx(length, abs=1e-12)
    assert p["closest_waypoints"] == [segment, segment + 1]
    assert p["all_wheels_on_track"] is True and p["is_offtrack"] is False and p["is_reversed"] is False
    assert p["speed"] == 0.0 and p["steering_angle"] == 0.0


def test_waypoints_are_the_centre_line_with_the_closing_point(sim, circle_track):
    p = ParamsBuilder(sim).build([0])[0]
    assert len(p["waypoints"]) == circle_track.num_waypoints == SEGMENTS + 1
    np.testing.assert_array_equal(np.array(p["waypoints"]), circle_track.centerline)
    assert p["waypoints"][0] == p["waypoints"][-1] == (RADIUS, 0.0)


def test_speed_and_steering_are_the_commanded_values(sim):
    """From rest, one step of (30 deg, 2 m/s): the wheels reach 24 deg and the car 0.27 m/s, but the
    params report the command, as DeepRacer does."""
    sim.step(np.full(2, math.radians(30.0)), np.array([2.0, 3.5]))
    p0, p1 = ParamsBuilder(sim).build()
    assert sim.state.speed[0] == pytest.approx(DEEPRACER.max_acceleration * DEEPRACER.dt)
    assert math.degrees(sim.state.steer[0]) == pytest.approx(24.0)
    assert p0["speed"] == 2.0 and p1["speed"] == 3.5
    assert p0["steering_angle"] == pytest.approx(30.0, abs=1e-12)
    assert p0["steps"] == 1.0
    sim.step(np.full(2, math.radians(-12.5)), np.full(2, 1.0))
    p0 = ParamsBuilder(sim).build([0])[0]
    assert p0["steering_angle"] == pytest.approx(-12.5, abs=1e-12) and p0["steps"] == 2.0


def test_wheels_partly_off_the_track(sim):
    place(sim, 0, *polar_pose(RADIUS + 0.45, 1.0))  # right (outer) wheels 0.531 m out: past the 0.5 m border
    p = ParamsBuilder(sim).build([0])[0]
    assert sim.state.wheels_on[0] == 2
    assert p["all_wheels_on_track"] is False and p["is_offtrack"] is False


def test_off_track(sim):
    place(sim, 0, *polar_pose(RADIUS + 1.0, 1.0))
    p = ParamsBuilder(sim).build([0])[0]
    assert p["is_offtrack"] is True and p["all_wheels_on_track"] is False
    assert p["distance_from_center"] == pytest.approx(math.hypot(RADIUS + 1.0, OFFSET) - RADIUS, abs=TOL)


@pytest.mark.parametrize("radius", [2.7, 3.25])
def test_values_on_the_reversed_track(sim, circle_track, radius):
    """Driven clockwise, the left of the car is the outside of the circle and waypoint 0 of the reversed
    list is the same point; arc length grows clockwise."""
    sim.reset(ndist=np.zeros(2), direction=np.ones(2, dtype=np.int64))
    theta = 2.0
    pose = polar_pose(radius, theta, clockwise=True)
    place(sim, 1, *pose)
    p = ParamsBuilder(sim).build([1])[0]
    rx, ry, r_ref, angle = reference_polar(*pose)
    assert p["is_reversed"] is True
    assert p["is_left_of_center"] is (r_ref > RADIUS)
    _, arc, distance = polygon_projection(rx, ry)
    assert p["distance_from_center"] == pytest.approx(distance, abs=1e-9)
    assert p["projection_distance"] == pytest.approx(circle_track.length - arc, abs=1e-9)
    reversed_waypoints = circle_track.centerline[::-1]
    np.testing.assert_array_equal(np.array(p["waypoints"]), reversed_waypoints)
    prev, nxt = p["closest_waypoints"]
    assert nxt == prev + 1
    # the projection lies between the two waypoints: their angles bracket the reference point's
    angles = np.unwrap(np.arctan2(reversed_waypoints[[prev, nxt], 1], reversed_waypoints[[prev, nxt], 0]))
    assert angles[1] < angles[0]  # clockwise
    assert angles[1] - 1e-9 <= np.unwrap([angles[0], angle])[1] <= angles[0] + 1e-9
    assert p["track_width"] == pytest.approx(WIDTH, abs=TOL)
    # from the start, 2 rad counter-clockwise is more than half a lap back when driving clockwise:
    # simapp's compute_current_prog counts it backwards, as negative progress
    assert p["progress"] == pytest.approx(-100 * arc / circle_track.length, abs=1e-7)


def test_closest_waypoints_follow_arc_length_not_euclidean_distance(sim, circle_track):
    """Reference point projected 90 % of the way along segment 10: the previous waypoint is 10 though
    waypoint 11 is nearer."""
    step = 2 * math.pi / SEGMENTS
    angle = 10.9 * step
    rx, ry = RADIUS * math.cos(angle), RADIUS * math.sin(angle)
    yaw = angle + math.pi / 2
    place(sim, 0, rx - OFFSET * math.cos(yaw), ry - OFFSET * math.sin(yaw), yaw)
    p = ParamsBuilder(sim).build([0])[0]
    assert p["closest_waypoints"] == [10, 11]
    nearest = int(np.argmin(np.linalg.norm(circle_track.centerline - [p["x"], p["y"]], axis=1)))
    assert nearest == 11


def test_mutating_params_does_not_leak_into_the_next_call(sim):
    builder = ParamsBuilder(sim)
    first = builder.build([0])[0]
    pristine = list(first["waypoints"])
    first["waypoints"].reverse()
    first["waypoints"].append((99.0, 99.0))
    first["waypoints"][0] = (-1.0, -1.0)
    first["closest_waypoints"].append(7)
    first["closest_objects"][0] = 5
    first["objects_location"].append((1.0, 1.0))
    first["x"] = 123.0
    second = builder.build([0])[0]
    assert second["waypoints"] == pristine
    assert second["closest_waypoints"] == first["closest_waypoints"][:2] and len(second["closest_waypoints"]) == 2
    assert second["closest_objects"] == [0, 0] and second["objects_location"] == []
    assert second["x"] != 123.0
    both = builder.build()
    assert both[0]["waypoints"] is not both[1]["waypoints"]


def test_heading_helper_range():
    assert heading_deg(math.pi) == 180.0
    assert heading_deg(-math.pi) == 180.0
    assert heading_deg(3 * math.pi / 2) == pytest.approx(-90.0)
    assert heading_deg(0.25) == pytest.approx(math.degrees(0.25))
