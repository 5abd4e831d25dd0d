"""The shipped example reward functions on hand-built params: values that make sense.

States are built by hand on the conftest stadium (6 m straights, 2 m radius ends, width 1 m,
~0.1 m waypoints, counter-clockwise, waypoint 0 mid bottom straight heading +x): a car at
waypoint ``index`` shifted ``lateral`` m to the left (negative: right) of the centre line.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from laplab.reward.examples import example_names, example_path
from laplab.reward.loader import load_reward_function

STRAIGHT_INDEX = 0  # mid bottom straight: 3 m of straight ahead
CORNER_INDEX = 60   # about the apex of the right-hand half circle
WIDTH = 1.0


@pytest.fixture(scope="module")
def route(stadium_route):
    """(N, 6) stadium route, closing row included."""
    return stadium_route(width=WIDTH)


def make_state(route, index=STRAIGHT_INDEX, lateral=0.0, speed=2.0, steering=0.0, heading_offset=0.0) -> dict:
    """DeepRacer params for a car ``lateral`` m left of waypoint ``index``, heading along the track."""
    centre = route[:, :2]
    count = len(centre) - 1
    ahead = centre[index + 1] - centre[index]
    direction = math.atan2(ahead[1], ahead[0])
    x, y = centre[index] + lateral * np.array([-math.sin(direction), math.cos(direction)])
    heading = math.degrees(direction) + heading_offset
    return {
        "all_wheels_on_track": abs(lateral) < 0.5 * WIDTH - 0.1, "x": float(x), "y": float(y),
        "heading": (heading + 180.0) % 360.0 - 180.0, "distance_from_center": abs(lateral),
        "is_left_of_center": lateral > 0, "progress": 100.0 * index / count, "steps": float(index + 1),
        "speed": speed, "steering_angle": steering, "track_width": WIDTH,
        "track_length": float(np.sum(np.hypot(*np.diff(centre, axis=0).T))),
        "waypoints": [tuple(map(float, p)) for p in centre], "closest_waypoints": [index, index + 1],
        "is_offtrack": abs(lateral) > 0.5 * WIDTH + 0.1, "is_crashed": False, "is_reversed": False,
        "projection_distance": 0.1 * index,
    }


def load(name):
    return load_reward_function(example_path(name))


def test_every_example_loads_and_returns_floats_in_range(route):
    assert set(example_names()) >= {"follow_centerline", "stay_inside_borders", "prevent_zigzag",
                                     "speed_on_straights", "follow_raceline", "legacy_2018"}
    for name in example_names():
        reward_fn = load(name)
        assert reward_fn.is_legacy == (name == "legacy_2018")
        assert reward_fn.function.__doc__ and '"""' in reward_fn.source.splitlines()[0]
        for index in (0, 35, CORNER_INDEX, 150, len(route) - 2):
            for lateral in (-0.7, -0.3, 0.0, 0.3, 0.7):
                for speed, steering in ((0.5, -30.0), (4.0, 0.0), (2.0, 30.0)):
                    value = reward_fn(make_state(route, index, lateral, speed, steering))
                    assert 0.0 < value <= 2.0, (name, index, lateral, speed, steering, value)


def test_unknown_example_name_is_a_clear_error():
    with pytest.raises(ValueError, match="known: .*follow_centerline"):
        example_path("follow_the_leader")


def test_follow_centerline_bands(route):
    reward_fn = load("follow_centerline")
    for side in (1.0, -1.0):
        values = [reward_fn(make_state(route, lateral=side * d)) for d in (0.0, 0.2, 0.4, 0.6)]
        assert values == [1.0, 0.5, 0.1, 1e-3]


def test_stay_inside_borders(route):
    reward_fn = load("stay_inside_borders")
    assert reward_fn(make_state(route, lateral=0.3)) == reward_fn(make_state(route, lateral=-0.3)) == 1.0
    assert reward_fn(make_state(route, lateral=0.0)) == 1.0
    assert reward_fn(make_state(route, lateral=-0.7)) == 1e-3  # off track
    edge = make_state(route, lateral=0.47)
    edge["all_wheels_on_track"] = True
    assert reward_fn(edge) == 1e-3  # inside, but closer than 5 cm to the border


def test_prevent_zigzag_penalises_hard_steering_both_ways(route):
    reward_fn = load("prevent_zigzag")
    calm = reward_fn(make_state(route, steering=5.0))
    assert calm == 1.0
    assert reward_fn(make_state(route, steering=20.0)) == reward_fn(make_state(route, steering=-20.0)) == 0.8
    assert reward_fn(make_state(route, lateral=0.2, steering=-25.0)) == pytest.approx(0.4)


def test_speed_on_straights_fast_on_straights_moderate_in_corners(route):
    reward_fn = load("speed_on_straights")
    max_turn_ahead = reward_fn.function.__globals__["max_turn_ahead"]
    waypoints = make_state(route)["waypoints"]
    assert max_turn_ahead(waypoints, STRAIGHT_INDEX + 1) < 1.0
    assert max_turn_ahead(waypoints, CORNER_INDEX) > 30.0
    on_straight = [reward_fn(make_state(route, STRAIGHT_INDEX, speed=v)) for v in (1.0, 2.5, 4.0)]
    assert on_straight == sorted(on_straight) and on_straight[0] < on_straight[-1]
    in_corner = {v: reward_fn(make_state(route, CORNER_INDEX, speed=v)) for v in (1.0, 2.0, 4.0)}
    assert in_corner[2.0] > in_corner[1.0] and in_corner[2.0] > in_corner[4.0]
    centred, aside = (reward_fn(make_state(route, STRAIGHT_INDEX, lateral, 4.0)) for lateral in (0.0, 0.3))
    assert centred > aside
    assert reward_fn(make_state(route, STRAIGHT_INDEX, lateral=0.7, speed=4.0)) == 1e-3


def curvatures(points: np.ndarray) -> np.ndarray:
    """(N,) unsigned curvature, 1/m, of a closed polyline (N, 2) through each point's neighbours."""
    a, b, c = np.roll(points, 1, axis=0), points, np.roll(points, -1, axis=0)
    cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    sides = np.hypot(*(b - a).T) * np.hypot(*(c - b).T) * np.hypot(*(a - c).T)
    return 2.0 * np.abs(cross) / np.maximum(sides, 1e-12)


def loop_length(points: np.ndarray) -> float:
    return float(np.sum(np.hypot(*(np.roll(points, -1, axis=0) - points).T)))


def test_follow_raceline_cuts_corners_and_rewards_speed(route):
    reward_fn = load("follow_raceline")
    module = reward_fn.function.__globals__
    state = make_state(route, CORNER_INDEX)
    line = module["raceline_for"](state["waypoints"], WIDTH)
    assert len(line) == len(route) and line[0] == line[-1]
    offsets = np.hypot(*(np.array(line) - route[:, :2]).T)
    assert offsets.max() <= 0.35 * WIDTH + 1e-9
    assert loop_length(np.array(line[:-1])) < 0.97 * loop_length(route[:-1, :2])
    # at the apex the line lies inside the corner: nearer the arc's centre (3, 0) than the centre line
    assert np.hypot(*(np.array(line[CORNER_INDEX]) - [3.0, 0.0])) < 2.0 - 0.25
    inside = reward_fn(make_state(route, CORNER_INDEX, lateral=0.3))
    outside = reward_fn(make_state(route, CORNER_INDEX, lateral=-0.3))
    assert inside > outside
    fast, slow = (reward_fn(make_state(route, CORNER_INDEX, 0.3, speed=v)) for v in (4.0, 1.0))
    assert fast > slow
    assert reward_fn(make_state(route, CORNER_INDEX, lateral=0.7)) == 1e-3
    assert module["raceline_for"](state["waypoints"], WIDTH) is line  # cached per track


def test_follow_raceline_on_a_real_track(reference_tracks_dir):
    route = np.load(reference_tracks_dir / "reInvent2019_track.npy")  # repeats one interior waypoint
    compute = load("follow_raceline").function.__globals__["compute_raceline"]
    started = time.perf_counter()
    line = np.array(compute([tuple(map(float, p)) for p in route[:, :2]], 1.067))
    assert time.perf_counter() - started < 2.0
    assert line.shape == (len(route), 2)
    assert np.hypot(*(line - route[:, :2]).T).max() <= 0.35 * 1.067 + 1e-9
    distinct = np.flatnonzero(np.hypot(*np.diff(route[:, :2], axis=0).T) > 0)
    centre, raceline = route[distinct, :2], line[distinct]
    assert loop_length(raceline) < 0.95 * loop_length(centre)
    assert curvatures(raceline).max() < 0.8 * curvatures(centre).max()
    assert np.percentile(curvatures(raceline), 95) < 0.8 * np.percentile(curvatures(centre), 95)


def test_legacy_2018_example_uses_converted_units(route):
    reward_fn = load("legacy_2018")
    fast, slow = reward_fn(make_state(route, speed=4.0)), reward_fn(make_state(route, speed=1.0))
    assert fast == 1.0 and slow == pytest.approx(0.625)  # throttle 1.0 and 0.25
    assert reward_fn(make_state(route, speed=4.0, heading_offset=60.0)) == 0.5  # heading off by 60 deg
    assert reward_fn(make_state(route, speed=4.0, heading_offset=-20.0)) == 1.0
    assert reward_fn(make_state(route, speed=4.0, steering=-20.0)) == pytest.approx(0.8)  # |steering| 2/3
    assert reward_fn(make_state(route, lateral=0.7)) == 1e-3
    assert reward_fn(make_state(route, CORNER_INDEX, speed=4.0)) == 1.0  # heading follows the curve


@pytest.mark.parametrize("name", example_names())
def test_every_example_passes_validation_on_a_track(name, stadium_track):
    from laplab.reward.validate import validate_reward_function
    report = validate_reward_function(load(name), stadium_track)
    assert report.passed, report.error
    assert report.calls > 100 and 0.0 < report.minimum <= report.mean < report.maximum


def test_lap_pace_rewards_a_faster_lap_and_nothing_off_track():
    reward_fn = load_reward_function(example_path("lap_pace"))
    base = {"is_offtrack": False, "all_wheels_on_track": True, "progress": 50.0, "track_width": 0.76,
            "distance_from_center": 0.1}
    fast = reward_fn({**base, "steps": 40.0})
    slow = reward_fn({**base, "steps": 160.0})
    assert fast > 4 * slow > 0  # pace squared: 4x the pace earns 16x the pace term
    assert reward_fn({**base, "steps": 40.0, "all_wheels_on_track": False}) == 1e-3
    assert reward_fn({**base, "steps": 40.0, "is_offtrack": True}) == 1e-3
