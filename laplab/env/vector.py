"""``TimeTrialVectorEnv``: N DeepRacer cars in one batched simulator, as a Gymnasium VectorEnv."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode

from laplab.env.metadata import ModelMetadata, load_model_metadata, metadata_from_dict
from laplab.env.observations import ObservationBuilder
from laplab.env.render import RENDER_FPS, RENDER_MODES, FrameRenderer, check_render_options
from laplab.env.spec import model_spec
from laplab.env.step import EpisodeStepper
from laplab.sim.simulator import Simulator
from laplab.sim.state import LAP_COMPLETE, STATUS_NAMES, EpisodeParams
from laplab.track.geometry import Track
from laplab.track.registry import DEFAULT_TRACK, load_track
from laplab.vehicle.params import DEEPRACER, VehicleParams

_STATUS_OBJECTS = np.array(STATUS_NAMES, dtype=object)
EXAMPLES_DIR = Path(__file__).resolve().parents[1] / "reward" / "examples"
DEFAULT_REWARD = EXAMPLES_DIR / "lap_pace.py"  # laplab's default (docs/deviations.md)

RewardSpec = str | os.PathLike | Callable[[dict], float] | None


def resolve_reward_function(reward: RewardSpec, max_speed: float = DEEPRACER.max_speed):
    """A callable ``params -> float`` from a file path, a source string, a callable, or None (no reward)."""
    if reward is None or callable(reward):
        return reward
    from laplab.reward.loader import load_reward_function
    return load_reward_function(reward, max_speed=max_speed)


def resolve_metadata(metadata: ModelMetadata | dict | str | os.PathLike | None) -> ModelMetadata:
    if metadata is None:
        return ModelMetadata()
    if isinstance(metadata, ModelMetadata):
        return metadata
    if isinstance(metadata, dict):
        return metadata_from_dict(metadata, "model_metadata")
    return load_model_metadata(metadata)


def _setup_episodes(env, num_cars: int, track, reward_function, model_metadata, vehicle, episode, stack_size, seed,
                    randomization=None, render_mode=None, render_view="topdown", render_car=0, race=None) -> None:
    """What both envs hold: the model spec, track, simulator, action spec, reward function, stepper,
    observations and renderer."""
    check_render_options(render_mode, render_view)
    env.model_metadata = resolve_metadata(model_metadata)
    env.model_spec = model_spec(env.model_metadata, stack_size, race is not None and race.has_objects)
    env.track = track if isinstance(track, Track) else load_track(track)
    env.sim = Simulator(env.track, num_cars, vehicle, episode, race=race, seed=seed)
    env.action_spec = env.model_metadata.action_space
    env.reward_fn = resolve_reward_function(reward_function, env.action_spec.max_speed)
    env._stepper = EpisodeStepper(env.sim, env.action_spec, env.reward_fn)
    env._observations = ObservationBuilder(env.sim, env.model_spec, seed=seed, randomization=randomization)
    env.render_mode, env.render_view = render_mode, render_view
    env._renderer = FrameRenderer(env.sim, render_view, render_car) if render_mode is not None else None


def _reset_episodes(sim: Simulator, seed: int | None, options: dict[str, Any] | None) -> None:
    """Reset every car; a seed restarts the round-robin start schedule."""
    if seed is not None:
        sim.restart_schedule()
    options = options or {}
    sim.reset(ndist=options.get("start_ndist"), direction=options.get("direction"))


class TimeTrialVectorEnv(gym.vector.VectorEnv):
    """N cars on one track, each in its own DeepRacer time-trial episode.

    Action space: ``Discrete(k)`` per car for a discrete DeepRacer action space (index into the
    ``action_space`` list of model_metadata.json), or ``Box(-1, 1, (2,))`` (steering, speed) scaled to
    the continuous ranges.

    Observation space: the sensors of model_metadata.json (``STATE`` by default: see
    :mod:`laplab.sensors.state_vector`); one sensor gives a Box, several a Dict keyed by sensor name.
    Cameras give ``(C, 120, 160)`` uint8 grey frames, channels first (C = cameras x ``stack_size``);
    lidars their DeepRacer vector (:mod:`laplab.sensors.lidar`).

    Rewards: the user's ``reward_function(params)`` called once per car and step with a fresh params
    dict (``None``: no reward function, reward 0; default: laplab's default, the ``lap_pace`` example).

    Starting state: at rest on the centre line, at the round-robin start of
    :class:`~laplab.sim.state.EpisodeParams` (car i of the batch starts i x 0.05 of a lap further).

    Termination: ``lap_complete``, ``off_track``, ``reversed``, ``immobilized`` terminate; the step cap
    (``time_up``) truncates.

    Autoreset: ``SAME_STEP``. A finished car is reset within the same ``step`` call; its final
    observation is in ``info["final_obs"]`` and its final info in ``info["final_info"]`` (masked by
    ``info["_final_obs"]``). ``info`` always holds per-car arrays ``episode_status`` (str),
    ``progress`` (%), ``steps``, ``lap_time`` (s, NaN unless the lap completed this step) and, when a
    reward function runs, ``params`` (the list of params dicts it saw, None for idle cars).

    Race type: ``race`` (a :class:`laplab.sim.race_type.RaceType`; None: time trial) puts boxes or bot
    cars on the track (``crashed`` terminates; the STATE vector gains the nearest objects' summary).

    Rendering: ``render_mode="rgb_array"`` makes :meth:`render` return one (H, W, 3) uint8 picture:
    ``render_view="topdown"`` (default) every car on the track from above, ``"camera"`` the front
    camera of car ``render_car`` in colour (:mod:`laplab.env.render`); ``metadata["render_fps"]`` 15.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": RENDER_MODES, "render_fps": RENDER_FPS}

    def __init__(self, num_envs: int = 16, track: Track | str = DEFAULT_TRACK, reward_function: RewardSpec = DEFAULT_REWARD,
                 model_metadata: ModelMetadata | dict | str | None = None, vehicle: VehicleParams = DEEPRACER,
                 episode: EpisodeParams = EpisodeParams(), keep_params: bool = True, stack_size: int = 1,
                 seed: int | None = None, randomization=None, render_mode: str | None = None,
                 render_view: str = "topdown", render_car: int = 0, race=None):
        _setup_episodes(self, num_envs, track, reward_function, model_metadata, vehicle, episode, stack_size, seed,
                        randomization, render_mode, render_view, render_car, race)
        self.num_envs = int(num_envs)
        self.keep_params = keep_params
        self.single_observation_space = self._observations.single_space
        self.single_action_space = self.action_spec.gym_space()
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, self.num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset every car. ``options``: ``start_ndist`` (float or (N,)), ``direction`` (0/1 or (N,))."""
        super().reset(seed=seed)
        _reset_episodes(self.sim, seed, options)
        return self._observations.observe(), self._base_info()

    def step(self, actions):
        keep = self.keep_params and self.reward_fn is not None
        result = self._stepper.step(actions, keep_params=keep)
        done = result.done
        info = self._base_info(lap_mask=done & (self.sim.state.status == LAP_COMPLETE))
        if result.params is not None:
            info["params"] = result.params
        obs = self._observations.observe()
        if done.any():
            info["final_obs"] = obs
            info["_final_obs"] = done.copy()
            info["final_info"] = {k: v for k, v in info.items() if k not in ("final_obs", "_final_obs")}
            info["_final_info"] = done.copy()
            self.sim.reset(done)
            obs = self._observations.observe()
        return obs, result.rewards, result.terminated, result.truncated, info

    def render(self):
        """The current picture (H, W, 3) uint8 for ``render_mode="rgb_array"``; None without a render mode."""
        return None if self._renderer is None else self._renderer.frame()

    def _base_info(self, lap_mask: np.ndarray | None = None) -> dict:
        st = self.sim.state
        lap_time = np.full(self.num_envs, np.nan)
        if lap_mask is not None:
            lap_time[lap_mask] = st.lap_time[lap_mask]
        return {
            "episode_status": _STATUS_OBJECTS[st.status],
            "progress": st.progress.copy(),
            "steps": st.steps.copy(),
            "lap_time": lap_time,
        }
