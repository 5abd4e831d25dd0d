"""Gymnasium adapters: the env checker, spaces, SAME_STEP autoreset, info, lap times, rewards, actions.

Importing laplab.env registers ``laplab/TimeTrial-v0`` with Gymnasium.
"""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode

from laplab.env import ENV_ID, TimeTrialEnv, TimeTrialVectorEnv
from laplab.sim.state import EpisodeParams

CONTINUOUS = {"action_space": {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 4.0}},
              "action_space_type": "continuous", "sensor": ["STATE"]}
# car-killing action 2: full lock at full speed
DISCRETE = {"action_space": [{"steering_angle": 0, "speed": 0.5}, {"steering_angle": -15, "speed": 1.0},
                             {"steering_angle": 30, "speed": 4.0}], "sensor": ["STATE"]}
OBS_SIZE = 27  # STATE sensor: 7 + 2 x 10 look-ahead points


def continuous_action(steer_rad: np.ndarray, speed: float) -> np.ndarray:
    """(N, 2) actions in [-1, 1] for the CONTINUOUS ranges."""
    steer = np.clip(np.degrees(steer_rad) / 30.0, -1, 1)
    return np.stack([steer, np.full_like(steer, (speed - 0.5) / 3.5 * 2 - 1)], axis=1).astype(np.float32)


# ---------------------------------------------------------------- single env


@pytest.mark.parametrize("kwargs", [{}, {"model_metadata": CONTINUOUS, "track": "oval"}])
def test_env_checker_passes(kwargs):
    env = gym.make(ENV_ID, **kwargs)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*(infinity|different from the unwrapped).*")
        check_env(env)
        check_env(env.unwrapped)
    assert isinstance(env.unwrapped, TimeTrialEnv)


def test_single_env_spaces_reset_and_step():
    env = TimeTrialEnv(track="oval")
    assert env.action_space == gym.spaces.Discrete(21)  # laplab's default: 7 steering x 3 speeds
    assert env.observation_space.shape == (OBS_SIZE,) and env.observation_space.dtype == np.float32
    obs, info = env.reset(seed=1)
    assert obs in env.observation_space
    assert info == {"episode_status": "in_progress", "progress": 0.0, "steps": 0}
    obs, reward, terminated, truncated, info = env.step(2)
    assert obs in env.observation_space and obs[0] > 0  # moving
    # the default reward (lap_pace): the pace so far squared plus up to 0.1 for the centre
    expected = (info["params"]["progress"] / 1.0) ** 2 + 0.1 * (1 - info["params"]["distance_from_center"]
                                                                 / (0.5 * info["params"]["track_width"]))
    assert isinstance(reward, float) and reward == pytest.approx(expected) and reward > 0.09
    assert (terminated, truncated) == (False, False)
    assert set(info) == {"episode_status", "progress", "steps", "params"}
    assert info["steps"] == 1 and info["params"]["steps"] == 1.0 and info["progress"] == info["params"]["progress"]
    assert "lap_time" not in info


def test_step_after_the_end_needs_a_reset():
    env = TimeTrialEnv(track="oval", model_metadata=DISCRETE)
    env.reset(options={"start_ndist": 0.0})
    terminated = False
    for _ in range(60):
        _, _, terminated, _, info = env.step(2)
        if terminated:
            break
    assert terminated and info["episode_status"] == "off_track" and info["params"]["is_offtrack"] is True
    with pytest.raises(RuntimeError, match="reset"):
        env.step(0)
    _, info = env.reset()
    assert info["episode_status"] == "in_progress"


def test_truncation_at_max_steps():
    env = TimeTrialEnv(track="oval", episode=EpisodeParams(max_steps=4))
    env.reset()
    ends = [env.step(2)[2:4] for _ in range(4)]
    assert ends == [(False, False)] * 3 + [(False, True)]


def test_reset_options_choose_the_start():
    env = TimeTrialEnv(track="oval")
    env.reset(options={"start_ndist": 0.5})
    np.testing.assert_allclose([env.sim.state.x[0], env.sim.state.y[0]], env.track.point_at(0.5 * env.track.length))
    env.reset(options={"start_ndist": 0.5, "direction": 1})
    assert env.sim.state.direction[0] == 1
    assert env.step(2)[4]["params"]["is_reversed"] is True


def test_lap_time_in_single_env(pure_pursuit):
    env = TimeTrialEnv(track="oval", model_metadata=CONTINUOUS)
    env.reset(options={"start_ndist": 0.0})
    for _ in range(400):
        action = continuous_action(pure_pursuit(env.sim, 0.9), 2.5)[0]  # DeepRacer's car answers late: look further
        _, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    assert info["episode_status"] == "lap_complete" and info["progress"] == 100.0
    assert (info["steps"] - 1) / 15 < info["lap_time"] <= info["steps"] / 15
    fastest = env.track.length / (2.5 * env.sim.vehicle.speed_ratio)  # on the centre line, at the car's own speed
    assert 0.98 * fastest < info["lap_time"] < env.track.length / 2.5 + 1.0


# ---------------------------------------------------------------- actions and rewards


def test_discrete_actions_command_their_table():
    env = TimeTrialEnv(track="oval", model_metadata=DISCRETE, reward_function=None)
    env.reset()
    for index, (steer, speed) in enumerate([(0, 0.5), (-15, 1.0), (30, 4.0)]):
        _, reward, *_, info = env.step(index)
        assert info["params"]["steering_angle"] == pytest.approx(steer, abs=1e-9)
        assert info["params"]["speed"] == speed
        assert reward == 0.0  # no reward function


def test_continuous_actions_scale_onto_the_ranges():
    env = TimeTrialEnv(track="oval", model_metadata=CONTINUOUS, reward_function=None)
    env.reset()
    for action, (steer, speed) in [((0.0, 0.0), (0.0, 2.25)), ((0.5, -1.0), (15.0, 0.5)),
                                   ((-1.0, 1.0), (-30.0, 4.0)), ((7.0, -9.0), (30.0, 0.5))]:  # clipped
        info = env.step(np.array(action, dtype=np.float32))[4]
        assert info["params"]["steering_angle"] == pytest.approx(steer, abs=1e-9)
        assert info["params"]["speed"] == pytest.approx(speed, abs=1e-9)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (2,), np.float32)


def test_reward_from_a_reward_function_string():
    source = ("import math\n"
              "def reward_function(params):\n"
              "    params['waypoints'].reverse()  # must not leak into later steps\n"
              "    return 2.0 * params['speed'] + params['progress'] / 1000 + math.sqrt(params['steps'])\n")
    env = TimeTrialVectorEnv(2, track="oval", reward_function=source, model_metadata=DISCRETE)
    env.reset()
    second_waypoint = tuple(env.track.centerline[1])
    for _ in range(3):
        _, rewards, _, _, info = env.step(np.array([0, 1]))
        for car, speed in enumerate((0.5, 1.0)):
            params = info["params"][car]
            assert rewards[car] == pytest.approx(2 * speed + params["progress"] / 1000 + math.sqrt(params["steps"]))
        assert info["params"][0]["waypoints"][1] == second_waypoint  # the reward reversed its own copy only
    assert env._stepper.params_builder.build([0])[0]["waypoints"][1] == second_waypoint


def test_reward_from_a_callable_sees_the_info_params():
    seen = []
    env = TimeTrialEnv(track="oval", reward_function=lambda p: seen.append(p) or -p["distance_from_center"])
    env.reset()
    _, reward, *_, info = env.step(2)
    assert seen[-1] is info["params"] and reward == -info["params"]["distance_from_center"]


# ---------------------------------------------------------------- vector env


def test_vector_env_spaces():
    env = TimeTrialVectorEnv(4, track="oval")
    assert env.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert env.num_envs == 4
    assert env.single_observation_space.shape == (OBS_SIZE,)
    assert env.observation_space.shape == (4, OBS_SIZE)
    assert env.single_action_space == gym.spaces.Discrete(21)
    assert env.action_space == gym.spaces.MultiDiscrete([21, 21, 21, 21])
    cont = TimeTrialVectorEnv(3, track="oval", model_metadata=CONTINUOUS)
    assert cont.single_action_space == gym.spaces.Box(-1, 1, (2,), np.float32)
    assert cont.action_space.shape == (3, 2)
    obs, info = cont.reset(seed=0)
    assert obs in cont.observation_space
    assert set(info) == {"episode_status", "progress", "steps", "lap_time"}
    assert list(info["episode_status"]) == ["in_progress"] * 3 and np.isnan(info["lap_time"]).all()
    obs, rewards, terminated, truncated, info = cont.step(cont.action_space.sample())
    assert obs in cont.observation_space and rewards.shape == (3,) and rewards.dtype == np.float64
    assert terminated.dtype == bool and truncated.dtype == bool
    assert set(info) == {"episode_status", "progress", "steps", "lap_time", "params"}
    np.testing.assert_array_equal(info["steps"], [1, 1, 1])


def test_make_vec_uses_the_vector_entry_point():
    env = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode="vector_entry_point", track="oval")
    assert isinstance(env.unwrapped, TimeTrialVectorEnv) and env.num_envs == 3


def test_same_step_autoreset():
    """Car 0 crashes off the track at full lock and full speed; cars 1 and 2 drive on slowly."""
    env = TimeTrialVectorEnv(3, track="oval", model_metadata=DISCRETE,
                             episode=EpisodeParams(start_ndist=0.0, round_robin_advance=0.0))
    obs, _ = env.reset()
    start_obs = obs[0].copy()
    actions = np.array([2, 0, 0])
    for step in range(1, 60):
        obs, _, terminated, truncated, info = env.step(actions)
        if terminated.any():
            break
        assert "final_obs" not in info
    np.testing.assert_array_equal(terminated, [True, False, False])
    np.testing.assert_array_equal(truncated, [False, False, False])
    np.testing.assert_array_equal(info["_final_obs"], [True, False, False])
    np.testing.assert_array_equal(info["_final_info"], [True, False, False])
    final = info["final_info"]
    assert final["episode_status"][0] == "off_track" and final["steps"][0] == step
    assert list(final["episode_status"][1:]) == ["in_progress", "in_progress"]
    assert final["params"][0]["is_offtrack"] is True
    # the returned observation of car 0 is its new episode's first; final_obs holds its last
    np.testing.assert_array_equal(obs[0], start_obs)
    assert not np.array_equal(info["final_obs"][0], obs[0])
    assert info["final_obs"][0][0] > 0.3  # still at speed when it left the track
    np.testing.assert_array_equal(info["final_obs"][1:], obs[1:])
    assert env.sim.state.steps[0] == 0 and env.sim.state.episode[0] == 2
    obs, _, terminated, _, info = env.step(np.array([0, 0, 0]))
    np.testing.assert_array_equal(info["steps"], [1, step + 1, step + 1])
    assert "final_obs" not in info and not terminated.any()


def test_truncation_in_the_vector_env():
    env = TimeTrialVectorEnv(2, track="oval", episode=EpisodeParams(max_steps=3))
    env.reset()
    for _ in range(3):
        _, _, terminated, truncated, info = env.step(np.array([2, 2]))
    np.testing.assert_array_equal(truncated, [True, True])
    np.testing.assert_array_equal(terminated, [False, False])
    assert list(info["final_info"]["episode_status"]) == ["time_up", "time_up"]
    np.testing.assert_array_equal(env.sim.state.steps, [0, 0])


def test_lap_time_in_the_vector_env(pure_pursuit):
    env = TimeTrialVectorEnv(2, track="oval", model_metadata=CONTINUOUS, reward_function=None,
                             episode=EpisodeParams(start_ndist=0.0))
    env.reset()
    speeds = np.array([2.5, 1.5])
    laps = {}
    for _ in range(400):
        steer = pure_pursuit(env.sim, 0.9)
        actions = np.vstack([continuous_action(steer[i:i + 1], speeds[i]) for i in range(2)])
        _, rewards, terminated, truncated, info = env.step(actions)
        assert not truncated.any() and (rewards == 0).all()
        for car in np.flatnonzero(terminated):
            assert info["final_info"]["episode_status"][car] == "lap_complete"
            assert car not in laps
            laps[car] = (info["lap_time"][car], info["final_info"]["steps"][car])
        assert np.isnan(info["lap_time"][~terminated]).all()
        if len(laps) == 2:
            break
    assert set(laps) == {0, 1}
    for car, (lap_time, steps) in laps.items():
        assert (steps - 1) / 15 < lap_time <= steps / 15
        fastest = env.track.length / (speeds[car] * env.sim.vehicle.speed_ratio)
        assert 0.98 * fastest < lap_time < env.track.length / speeds[car] + 1.0
    assert laps[0][0] < laps[1][0]


def test_large_batches_step_every_car():
    """64 cars go through the parallel kernel: all of them move and count their steps."""
    env = TimeTrialVectorEnv(64, track="oval", reward_function=None)
    obs, _ = env.reset()
    for _ in range(5):
        obs, _, _, _, info = env.step(np.full(64, 2))
    np.testing.assert_array_equal(info["steps"], np.full(64, 5))
    assert (obs[:, 0] > 0).all() and (info["progress"] > 0).all()


# ---------------------------------------------------------------- Stable-Baselines3


def test_stable_baselines3_ppo_runs():
    sb3 = pytest.importorskip("stable_baselines3")
    env = TimeTrialEnv(track="oval")
    model = sb3.PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=2, device="cpu", seed=0)
    model.learn(128)
    assert model.num_timesteps == 128
    action, _ = model.predict(env.reset()[0], deterministic=True)
    assert env.action_space.contains(int(action))
