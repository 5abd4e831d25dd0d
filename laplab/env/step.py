"""One batched episode step, shared by the Gymnasium envs, training collection and evaluation trials.

``actions -> commands -> Simulator.step -> params -> rewards -> terminated / truncated -> simtrace rows``
is :meth:`EpisodeStepper.step`, returning a :class:`StepResult`. Simtrace rows of any cars are
built by :func:`simtrace_rows`, the one place that maps the simulator's state onto simtrace columns.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import numpy as np

from laplab.env.action_space import ActionSpace
from laplab.reward.params import ParamsBuilder, rewards_for
from laplab.sim.simulator import Simulator
from laplab.sim.state import IN_PROGRESS, STATUS_NAMES, TIME_UP

_STATUS_TEXT = np.array(STATUS_NAMES)


class StepResult(NamedTuple):
    """What one batched step did; arrays are (N,) over every car of the simulator.

    - ``stepped``: the cars that were in progress before the step (the others did not move).
    - ``rewards``: the reward function's value per stepped car (0 elsewhere, or without a function).
    - ``terminated``: stepped cars whose episode ended (lap complete, off track, reversed,
      immobilized, crashed); ``truncated``: stepped cars cut by the step cap (``time_up``).
    - ``params``: when asked for, the params dict of each stepped car (None for the others).
    - ``trace``: when asked for, the simtrace columns of the stepped cars (``episode`` = car index).
    """

    stepped: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    params: list[dict | None] | None
    trace: dict[str, np.ndarray] | None

    @property
    def done(self) -> np.ndarray:
        return self.terminated | self.truncated


def trace_actions(action_space: ActionSpace, env_actions: np.ndarray) -> np.ndarray:
    """The simtrace ``action`` column of K env actions: the index (discrete), else (K, 2) of
    (steering deg, speed m/s)."""
    if action_space.is_discrete:
        return np.asarray(env_actions).reshape(-1).astype(np.int64)
    steer_deg, speed = action_space.to_physical(env_actions)
    return np.stack([steer_deg, speed], axis=1)


def simtrace_rows(sim: Simulator, cars: np.ndarray, action: np.ndarray, reward: np.ndarray, *,
                  episode: np.ndarray | None = None, steps: np.ndarray | None = None,
                  tstamp: np.ndarray | None = None, done: np.ndarray | None = None,
                  episode_status: np.ndarray | None = None, **extra: np.ndarray) -> dict[str, np.ndarray]:
    """Simtrace columns of K rows, one per car of ``cars`` (K,), from the simulator's current state.

    ``action`` (K,) or (K, 2) and ``reward`` (K,) are the rows' own. By default ``episode`` is the car
    index, ``steps`` the car's step count, ``tstamp`` its episode time (s), ``done`` whether its episode
    has ended and ``episode_status`` its status name; callers with their own clock or numbering
    (evaluation trials) pass them. ``extra`` columns are appended as given (K,).
    """
    st = sim.state
    cars = np.asarray(cars, dtype=np.int64)
    k = cars.size
    seg = st.segment[cars]
    closest = np.mod(np.where(st.seg_t[cars] <= 0.5, seg, seg + 1), sim.track.num_waypoints - 1)
    status = st.status[cars]
    car_steps = st.steps[cars]
    rows = {
        "episode": cars if episode is None else np.asarray(episode, dtype=np.int64),
        "steps": car_steps if steps is None else np.asarray(steps, dtype=np.int64),
        "X": st.ref_x[cars], "Y": st.ref_y[cars], "yaw": np.degrees(st.yaw[cars]),
        "steer": np.degrees(st.cmd_steer[cars]), "throttle": st.cmd_speed[cars], "action": action,
        "reward": np.asarray(reward, dtype=np.float64),
        "done": status != IN_PROGRESS if done is None else done,
        "all_wheels_on_track": st.wheels_on[cars] == 4, "progress": st.progress[cars],
        "closest_waypoint": closest.astype(np.int64), "track_len": np.full(k, sim.track.length),
        "tstamp": car_steps * sim.dt if tstamp is None else np.asarray(tstamp, dtype=np.float64),
        "episode_status": _STATUS_TEXT[status] if episode_status is None else episode_status,
    }
    rows.update(extra)
    return rows


class EpisodeStepper:
    """Steps the cars of one :class:`Simulator` under a model's action space and a reward function.

    ``reward_fn`` (params -> float) may be None (rewards 0); it may raise
    :class:`~laplab.reward.errors.RewardFunctionError`, which propagates.
    """

    def __init__(self, sim: Simulator, action_space: ActionSpace,
                 reward_fn: Callable[[dict], float] | None = None):
        self.sim, self.action_space, self.reward_fn = sim, action_space, reward_fn
        self.params_builder = ParamsBuilder(sim)

    def commands(self, actions: Any, cars: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(steer rad (N,), speed m/s (N,)) for env ``actions`` of all cars, or of ``cars`` only (the
        others get zero commands)."""
        steer, speed = self.action_space.to_commands(actions)
        if cars is None:
            return steer, speed
        full_steer, full_speed = np.zeros(self.sim.num_cars), np.zeros(self.sim.num_cars)
        full_steer[cars], full_speed[cars] = steer, speed
        return full_steer, full_speed

    def step(self, actions: Any, cars: np.ndarray | None = None, *, keep_params: bool = False,
             trace: bool = False) -> StepResult:
        """One decision for every car in progress.

        ``actions``: env actions (indices, or points of [-1, 1]^2) of all N cars, or of the cars
        ``cars`` (K,) when given. ``keep_params``: return the params dicts (built even without a reward
        function). ``trace``: return the stepped cars' simtrace rows.
        """
        sim, num = self.sim, self.sim.num_cars
        steer, speed = self.commands(actions, cars)
        stepped = sim.step(steer, speed)
        moved = np.flatnonzero(stepped)
        rewards = np.zeros(num)
        params_list = None
        if moved.size and (self.reward_fn is not None or keep_params):
            if self.reward_fn is not None:
                values, params = rewards_for(self.params_builder, self.reward_fn, moved, keep=keep_params)
                rewards[moved] = values
            else:
                params = self.params_builder.build(moved)
            if keep_params:
                params_list = [None] * num
                for car, p in zip(moved.tolist(), params):
                    params_list[car] = p
        elif keep_params:
            params_list = [None] * num
        status = sim.state.status
        done = stepped & (status != IN_PROGRESS)
        truncated = done & (status == TIME_UP)
        rows = None
        if trace:
            full = np.asarray(actions)
            if cars is not None:
                full = np.zeros((num, *full.shape[1:]), dtype=full.dtype)
                full[cars] = actions
            rows = simtrace_rows(sim, moved, trace_actions(self.action_space, full[moved]), rewards[moved])
        return StepResult(stepped, rewards, done & ~truncated, truncated, params_list, rows)
