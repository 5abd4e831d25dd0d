"""Race types in the simulator: obstacle placement, bots, collisions, the objects_* params, STATE summary."""

from __future__ import annotations

import math

import numpy as np
import pytest

from laplab.reward.params import ParamsBuilder
from laplab.sim.collision import rectangles_overlap, summary_size
from laplab.sim.obstacles import BOT_CAR, BOX
from laplab.sim.race_field import LANE, lane_pose
from laplab.sim.race_type import RaceType, RaceTypeError, parse_object_positions
from laplab.sim.simulator import Simulator
from laplab.sim.state import CRASHED, IN_PROGRESS, EpisodeParams
from laplab.track.registry import load_track

TRACK = load_track("classic_2018")
FIXED = EpisodeParams(round_robin_advance=0.0, spread_starts=False)

# DeepRacer's example object-avoidance reward function, from its documentation, unchanged.
DEEPRACER_OA_EXAMPLE = '''
def reward_function(params):
    \'\'\'
    Example of rewarding the agent to stay inside two borders
    and penalizing getting too close to the objects in front
    \'\'\'
    all_wheels_on_track = params['all_wheels_on_track']
    distance_from_center = params['distance_from_center']
    track_width = params['track_width']
    objects_distance = params['objects_distance']
    _, next_object_index = params['closest_objects']
    objects_left_of_center = params['objects_left_of_center']
    is_left_of_center = params['is_left_of_center']

    # Initialize reward with a small number but not zero
    # because zero means off-track or crashed
    reward = 1e-3

    # Reward if the agent stays inside the two borders of the track
    if all_wheels_on_track and (0.5 * track_width - distance_from_center) >= 0.05:
        reward_lane = 1.0
    else:
        reward_lane = 1e-3

    # Penalize if the agent is too close to the next object
    reward_avoid = 1.0

    # Distance to the next object
    distance_closest_object = objects_distance[next_object_index]
    # Decide if the agent and the next object is on the same lane
    is_same_lane = objects_left_of_center[next_object_index] == is_left_of_center

    if is_same_lane:
        if 0.5 <= distance_closest_object < 0.8:
            reward_avoid *= 0.5
        elif 0.3 <= distance_closest_object < 0.5:
            reward_avoid *= 0.2
        elif distance_closest_object < 0.3:
            reward_avoid = 1e-3 # Likely crashed

    # Calculate reward by putting different weights on
    # the two aspects above
    reward += 1.0 * reward_lane + 4.0 * reward_avoid

    return reward
'''


def race_sim(race: RaceType, cars: int = 1, seed: int = 0) -> Simulator:
    sim = Simulator(TRACK, cars, episode=FIXED, race=race, seed=seed)
    sim.reset()
    return sim


def pose_behind(sim: Simulator, arc: float, frac: float) -> np.ndarray:
    geo = sim.arrays[0]
    return np.array(lane_pose(arc, frac, 0.0, geo.centerline, geo.arc_length, geo.left_width, geo.right_width))


# --- collision geometry -------------------------------------------------------------------------------

def test_rectangles_overlap_closed_form():
    # two unit squares (half sizes 0.5) side by side: overlap below a 1 m centre distance, apart above
    assert rectangles_overlap(0, 0, 0, 0.5, 0.5, 0.99, 0, 0, 0.5, 0.5)
    assert not rectangles_overlap(0, 0, 0, 0.5, 0.5, 1.01, 0, 0, 0.5, 0.5)
    # a square turned 45 deg reaches sqrt(2)/2 along x: its corner touches the other at 0.5 + 0.7071
    reach = 0.5 + math.sqrt(0.5)
    assert rectangles_overlap(0, 0, 0, 0.5, 0.5, reach - 0.01, 0, math.pi / 4, 0.5, 0.5)
    assert not rectangles_overlap(0, 0, 0, 0.5, 0.5, reach + 0.01, 0, math.pi / 4, 0.5, 0.5)
    # diagonal offset: axis-aligned squares that share no x-range do not overlap even if y-ranges do
    assert not rectangles_overlap(0, 0, 0, 1.0, 0.1, 0.0, 0.3, 0, 1.0, 0.1)
    assert rectangles_overlap(0, 0, 0, 1.0, 0.1, 0.0, 0.19, 0, 1.0, 0.1)
    # a long thin rectangle across another (a plus sign): overlap though no corner is inside the other
    assert rectangles_overlap(0, 0, 0, 1.0, 0.05, 0, 0, math.pi / 2, 1.0, 0.05)


def test_driving_into_a_box_crashes_and_is_crashed():
    sim = race_sim(RaceType("object_avoidance", object_positions=((0.3, 1),)))
    box_arc = 0.3 * TRACK.length
    frac = sim.field.frac[0, 0]
    sim.place([0], pose_behind(sim, box_arc - 1.0, frac)[None], speed=1.0)
    builder = ParamsBuilder(sim)
    for _ in range(30):
        sim.step(np.zeros(1), np.ones(1))
        if sim.state.status[0] != IN_PROGRESS:
            break
    assert sim.state.status[0] == CRASHED
    assert sim.last_hit[0] == 0
    assert builder.build()[0]["is_crashed"] is True


def test_a_car_in_the_other_lane_passes_the_box():
    sim = race_sim(RaceType("object_avoidance", object_positions=((0.3, 1),)))
    arc = 0.3 * TRACK.length
    sim.place([0], pose_behind(sim, arc - 1.0, -sim.field.frac[0, 0])[None], speed=1.0)
    for _ in range(30):
        sim.step(np.zeros(1), np.ones(1))
    assert sim.state.status[0] != CRASHED


# --- placement ----------------------------------------------------------------------------------------

def test_fixed_positions_are_deepracers_lanes():
    sim = race_sim(RaceType("object_avoidance", object_positions=((0.25, 1), (0.5, -1))))
    inner_left = 1.0 if TRACK.is_ccw else -1.0
    np.testing.assert_allclose(sim.field.arc[0], [0.25 * TRACK.length, 0.5 * TRACK.length])
    np.testing.assert_allclose(sim.field.frac[0], [LANE * inner_left, -LANE * inner_left])
    assert (sim.obstacles.kind[0] == BOX).all()
    np.testing.assert_allclose(sim.obstacles.half_length[0], 0.2)
    np.testing.assert_allclose(sim.obstacles.half_width[0], 0.15)
    np.testing.assert_allclose(sim.obstacles.height[0], 0.25)


def test_randomised_placement_keeps_its_minimum_distance_and_lanes():
    race = RaceType("object_avoidance", objects=4, randomize_objects=True, min_object_distance=2.0)
    sim = race_sim(race, cars=64, seed=3)
    arcs = np.sort(sim.field.arc, axis=1)
    assert (np.diff(arcs, axis=1) >= 2.0 - 1e-9).all()
    assert (arcs[:, 0] >= 2.0 - 1e-9).all() and (arcs[:, -1] <= TRACK.length - 1.0 + 1e-9).all()
    assert set(np.unique(np.abs(sim.field.frac))) == {LANE}
    assert len({tuple(np.round(row, 6)) for row in sim.field.arc}) > 32  # differs per episode
    sim.reset()  # a new episode draws new places
    assert not np.allclose(np.sort(sim.field.arc, axis=1), arcs)


def test_evenly_spaced_objects_alternate_lanes_inner_first():
    sim = race_sim(RaceType("object_avoidance", objects=3))
    np.testing.assert_allclose(sim.field.arc[0], np.linspace(2.0, TRACK.length - 1.0, 3))
    inner = LANE * (1.0 if TRACK.is_ccw else -1.0)
    np.testing.assert_allclose(sim.field.frac[0], [inner, -inner, inner])


# --- bots ---------------------------------------------------------------------------------------------

def test_bots_drive_their_lane_and_change_lanes():
    race = RaceType("head_to_bot", bots=1, bot_speed=1.0, lane_change=True, lane_change_min_s=1.0,
                    lane_change_max_s=1.0, lane_change_distance=1.0)
    sim = race_sim(race)
    start_arc, start_frac = sim.field.arc[0, 0], sim.field.frac[0, 0]
    assert sim.obstacles.kind[0, 0] == BOT_CAR
    fracs = []
    for _ in range(45):  # 3 s
        sim.step(np.zeros(1), np.zeros(1))
        if sim.state.status[0] != IN_PROGRESS:
            sim.state.status[0] = IN_PROGRESS  # keep the episode (and the bot) going
        fracs.append(sim.field.frac[0, 0])
    np.testing.assert_allclose(sim.field.arc[0, 0] - start_arc, 3.0, atol=1e-9)
    fracs = np.array(fracs)
    assert np.allclose(fracs[:14], start_frac)  # no change in the first second
    assert np.isclose(fracs[-1], -start_frac)  # changed over the next metre
    assert np.all(np.abs(np.diff(fracs)) < 0.2)  # smoothly


def test_bots_reset_with_the_episode():
    sim = race_sim(RaceType("head_to_bot", bots=2, bot_speed=2.0))
    first = sim.field.arc.copy()
    for _ in range(10):
        sim.step(np.zeros(1), np.zeros(1))
    assert (sim.field.arc > first).all()
    sim.reset()
    np.testing.assert_allclose(sim.field.arc, first)


# --- params -------------------------------------------------------------------------------------------

def test_object_params_against_hand_placed_objects():
    race = RaceType("object_avoidance", object_positions=((0.2, 1), (0.4, -1), (0.6, 1)))
    sim = race_sim(race)
    length = TRACK.length
    # the car in the outer lane 1 m behind object 1 (at 0.4 of the lap)
    sim.place([0], pose_behind(sim, 0.4 * length - 1.0, sim.field.frac[0, 1])[None])
    p = ParamsBuilder(sim).build()[0]
    assert p["closest_objects"] == [0, 1]
    np.testing.assert_allclose(p["objects_distance"], [0.2 * length, 0.4 * length, 0.6 * length], atol=0.02)
    inner_left = TRACK.is_ccw
    assert p["objects_left_of_center"] == [inner_left, not inner_left, inner_left]
    for (x, y), j in zip(p["objects_location"], range(3)):
        assert (x, y) == (sim.obstacles.x[0, j], sim.obstacles.y[0, j])
    assert all(0.1 < d < 0.5 for d in p["objects_distance_from_center"])
    assert p["objects_speed"] == [0.0, 0.0, 0.0] and p["objects_heading"] == [0.0, 0.0, 0.0]
    assert p["object_in_camera"] is True
    # facing backwards the next object is behind the camera
    x, y, yaw = pose_behind(sim, 0.4 * length - 1.0, sim.field.frac[0, 1])
    sim.place([0], np.array([[x, y, yaw + math.pi]]))
    assert ParamsBuilder(sim).build()[0]["object_in_camera"] is False


def test_closest_objects_wrap_round_the_lap():
    sim = race_sim(RaceType("object_avoidance", object_positions=((0.3, 1), (0.6, -1))))
    sim.place([0], pose_behind(sim, 0.8 * TRACK.length, 0.0)[None])
    assert ParamsBuilder(sim).build()[0]["closest_objects"] == [1, 0]


def test_bot_params_report_speed_and_heading_in_radians():
    sim = race_sim(RaceType("head_to_bot", bots=2, bot_speed=1.5))
    p = ParamsBuilder(sim).build()[0]
    assert p["objects_speed"] == [1.5, 1.5]
    np.testing.assert_allclose(p["objects_heading"], np.arctan2(np.sin(sim.obstacles.yaw[0]), np.cos(sim.obstacles.yaw[0])))


def test_time_trial_params_keep_their_defaults():
    sim = Simulator(TRACK, 1)
    sim.reset()
    p = ParamsBuilder(sim).build()[0]
    assert p["closest_objects"] == [0, 0] and p["objects_location"] == [] and p["object_in_camera"] is False


def test_deepracers_example_object_avoidance_reward_runs_unchanged():
    namespace: dict = {}
    exec(DEEPRACER_OA_EXAMPLE, namespace)
    reward_function = namespace["reward_function"]
    sim = race_sim(RaceType("object_avoidance", objects=3), cars=8)
    builder = ParamsBuilder(sim)
    for _ in range(20):
        sim.step(np.zeros(8), np.ones(8))
        rewards = [reward_function(p) for p in builder.build()]
        assert all(isinstance(r, float) and r > 0 for r in rewards)
        sim.reset(sim.state.status != IN_PROGRESS)


# --- STATE ----------------------------------------------------------------------------------------------

def test_state_vector_grows_only_with_objects():
    assert Simulator(TRACK, 1).obs.shape == (1, 27)
    sim = race_sim(RaceType("object_avoidance", object_positions=((0.3, 1),)))
    assert sim.obs.shape == (1, 27 + summary_size())
    sim.place([0], pose_behind(sim, 0.3 * TRACK.length - 1.0, sim.field.frac[0, 0])[None])
    summary = sim.obs[0, 27:]
    assert summary[2] == 1.0 and 0.1 < summary[0] < 0.3  # present, ~1 m ahead (/5 m)
    assert abs(summary[1]) < 0.05  # in the car's lane
    assert (summary[4:] == 0).all()  # one object only


# --- bad input ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, option", [
    (dict(kind="head_to_bot", bot_speed=5.0), "--bot-speed"),
    (dict(kind="head_to_bot", bot_speed=0.05), "--bot-speed"),
    (dict(kind="head_to_bot", bot_lane="middle"), "--bot-lane"),
    (dict(kind="object_avoidance", object_positions=((0.3, 2),)), "--object-positions"),
    (dict(kind="sumo"), "--race-type"),
    (dict(kind="head_to_model"), "--opponent"),
])
def test_bad_race_options_name_the_option(kwargs, option):
    with pytest.raises(RaceTypeError) as error:
        RaceType(**kwargs)
    assert error.value.field == option and option in str(error.value)


def test_more_objects_than_fit_are_refused():
    with pytest.raises(RaceTypeError, match="do not fit") as error:
        Simulator(TRACK, 1, race=RaceType("object_avoidance", objects=12, min_object_distance=2.0))
    assert error.value.field == "--objects"


def test_object_positions_parse_deepracer_form():
    assert parse_object_positions("0.23,-1;0.46,1") == ((0.23, -1), (0.46, 1))
    with pytest.raises(RaceTypeError):
        parse_object_positions("0.23")


def test_race_type_round_trips():
    race = RaceType("object_avoidance", object_positions=((0.2, 1),), randomize_objects=False)
    assert RaceType.from_dict(race.to_dict()) == race
    assert RaceType.from_dict(None) == RaceType()


def test_vector_env_with_boxes_ends_episodes_crashed_and_observes_the_summary():
    from laplab.env import TimeTrialVectorEnv
    race = RaceType("object_avoidance", objects=6, min_object_distance=1.5)
    env = TimeTrialVectorEnv(16, track=TRACK, reward_function=None, race=race, seed=0)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (16, 27 + summary_size()) and env.single_observation_space.shape == (39,)
    statuses = set()
    straight = np.full(16, 3)  # a discrete action near straight ahead
    for _ in range(150):
        obs, _, terminated, _, info = env.step(straight)
        statuses |= set(info["episode_status"][terminated].tolist())
    assert "crashed" in statuses
    frame_obstacles = env.sim.obstacles
    assert frame_obstacles.x.shape == (16, 6)
