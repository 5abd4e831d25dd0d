"""``TimeTrialEnv``: one DeepRacer car in a time trial, as a Gymnasium ``Env``."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from laplab.env.metadata import ModelMetadata
from laplab.env.render import RENDER_FPS, RENDER_MODES
from laplab.env.vector import DEFAULT_REWARD, RewardSpec, _reset_episodes, _setup_episodes
from laplab.sim.state import IN_PROGRESS, LAP_COMPLETE, STATUS_NAMES, EpisodeParams
from laplab.track.geometry import Track
from laplab.track.registry import DEFAULT_TRACK
from laplab.vehicle.params import DEEPRACER, VehicleParams


class TimeTrialEnv(gym.Env):
    """One car driving a DeepRacer time trial; registered as ``laplab/TimeTrial-v0``.

    Action space: ``Discrete(k)`` (index into model_metadata.json's discrete ``action_space``) or
    ``Box(-1, 1, (2,))`` (steering, speed) scaled to its continuous ranges.

    Observation space: the model's sensors; ``STATE`` by default, a float32 vector described in
    :mod:`laplab.sensors.state_vector`. Cameras give ``(C, 120, 160)`` uint8 grey frames, channels
    first (C = cameras x ``stack_size``); several sensors give a Dict keyed by sensor name.

    Rewards: ``reward_function(params)`` on a fresh DeepRacer params dict each step (default:
    laplab's default, the ``lap_pace`` example; ``None``: reward 0).

    Starting state: at rest, origin on the centre line, facing along it, at the start fraction of the
    lap given by ``options["start_ndist"]`` or else by the round-robin schedule of ``episode``
    (advancing 0.05 of a lap per episode; ``reset(seed=...)`` restarts the schedule).

    Episode end: terminated on ``lap_complete``, ``off_track``, ``reversed`` or ``immobilized``;
    truncated at ``episode.max_steps`` (status ``time_up``).

    Info: ``params`` (the dict the reward function saw), ``episode_status``, ``progress`` (%),
    ``steps``, and ``lap_time`` (s) when the lap completes.

    Rendering: ``render_mode="rgb_array"`` makes :meth:`render` return an (H, W, 3) uint8 picture,
    ``render_view="topdown"`` (default: the track from above) or ``"camera"`` (the front camera in
    colour, 480x640); ``metadata["render_fps"]`` 15, one frame per step.
    """

    metadata = {"render_modes": RENDER_MODES, "render_fps": RENDER_FPS}

    def __init__(self, track: Track | str = DEFAULT_TRACK, reward_function: RewardSpec = DEFAULT_REWARD,
                 model_metadata: ModelMetadata | dict | str | None = None, vehicle: VehicleParams = DEEPRACER,
                 episode: EpisodeParams = EpisodeParams(), stack_size: int = 1, seed: int | None = None,
                 randomization=None, render_mode: str | None = None, render_view: str = "topdown"):
        _setup_episodes(self, 1, track, reward_function, model_metadata, vehicle, episode, stack_size, seed,
                        randomization, render_mode, render_view)
        self.observation_space = self._observations.single_space
        self.action_space = self.action_spec.gym_space()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        _reset_episodes(self.sim, seed, options)
        return self._observe(), self._info()

    def step(self, action):
        if self.sim.state.status[0] != IN_PROGRESS:
            raise RuntimeError("step() called on a finished episode; call reset() first")
        result = self._stepper.step(np.asarray(action)[None], keep_params=True)
        info = self._info()
        info["params"] = result.params[0]
        if self.sim.state.status[0] == LAP_COMPLETE:
            info["lap_time"] = float(self.sim.state.lap_time[0])
        return (self._observe(), float(result.rewards[0]), bool(result.terminated[0]), bool(result.truncated[0]),
                info)

    def render(self):
        """The current picture (H, W, 3) uint8 for ``render_mode="rgb_array"``; None without a render mode."""
        return None if self._renderer is None else self._renderer.frame()

    def _observe(self):
        obs = self._observations.observe(slice(0, 1))
        return {k: v[0] for k, v in obs.items()} if isinstance(obs, dict) else obs[0]  # observe() gives new arrays

    def _info(self) -> dict:
        st = self.sim.state
        return {"episode_status": STATUS_NAMES[int(st.status[0])], "progress": float(st.progress[0]),
                "steps": int(st.steps[0])}
