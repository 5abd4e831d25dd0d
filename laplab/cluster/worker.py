"""A rollout worker: one batched simulator that drives its share of an iteration's episodes.

:class:`RolloutWorker` is a plain class (a Ray actor in :mod:`laplab.cluster.collector`, which runs
it in its own process). It builds its own track, :class:`~laplab.sim.simulator.Simulator`,
:class:`~laplab.env.observations.ObservationBuilder` and :class:`~laplab.env.step.EpisodeStepper`,
compiles the reward function from its source text itself (the reward is untrusted code: it runs in
the worker's process, under the reward watchdog's time limit when the worker runs in its process's
main thread), and acts with a CPU copy of the learner's policy network, loaded from the weights the
learner broadcasts each iteration.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from laplab.reward.errors import RewardFunctionError


@dataclass(frozen=True)
class WorkerSetup:
    """What one worker needs: ``config`` (a TrainConfig as a dict), ``index`` (0-based), its
    ``track`` / ``reverse``, ``num_cars`` (its episodes per iteration), ``start_offset`` (how many
    episodes of the iteration come before its own, so the round-robin starts are consecutive across
    workers), ``seed``, the reward function's ``reward_source`` text and ``reward_path`` (named in
    errors), the watchdog's limits (s), and ``cores``: the worker's share of its machine's cores,
    the threads of its simulator and of a camera network (a vector network acts fastest on one)."""

    config: dict
    index: int
    track: str
    reverse: bool
    num_cars: int
    start_offset: int
    seed: int
    reward_source: str
    reward_path: str
    reward_timeout_s: float = 5.0
    reward_wait_timeout_s: float = 60.0
    cores: int = 1

    @property
    def track_label(self) -> str:
        return f"{self.track}@reversed" if self.reverse else self.track


@dataclass
class WorkerResult:
    """One worker's share of an iteration: ``batch`` (a TaggedEpisodeBatch) acted with
    ``policy_version``; ``acted_steps`` (exploring policy calls, for the epsilon schedule); or
    ``reward_error`` (the RewardFunctionError's paragraph) when the reward function failed."""

    index: int
    policy_version: int
    batch: Any = None
    acted_steps: int = 0
    reward_error: str | None = None
    pid: int = 0
    where: dict | None = None  # the worker's process facts (RolloutWorker.where)
    busy_s: float = 0.0  # the worker's wall time in collect (s): driving plus loading the weights and packing


class RolloutWorkerError(RewardFunctionError):
    """A worker's RewardFunctionError, carried back as its message (the learner shows it as is)."""

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message

    def __str__(self) -> str:
        return self.message


def policy_weights(learner) -> dict:
    """What a worker needs to act like ``learner``: its policy network's weights (numpy arrays on the
    CPU) and its exploration schedule's position. Numpy, not torch tensors: Ray ships numpy arrays
    without pickling their data (a STATE network's 1.7 MB went out and in 3x faster than as tensors)."""
    weights = {k: v.detach().cpu().numpy() for k, v in learner.policy_network.state_dict().items()}
    return {"algorithm": learner.algorithm, "weights": weights, "env_steps": int(getattr(learner, "env_steps", 0))}


class RolloutWorker:
    """Collects ``setup.num_cars`` episodes per call of :meth:`collect` (see the module docstring)."""

    def __init__(self, setup: WorkerSetup):
        from laplab.env.observations import ObservationBuilder
        from laplab.env.step import EpisodeStepper
        from laplab.reward.loader import _compile_reward  # source text, errors naming the user's file
        from laplab.sim.simulator import Simulator
        from laplab.track.registry import load_track
        from laplab.train.config import TrainConfig
        from laplab.train.trainer import build_learner
        from laplab.vehicle.params import DEEPRACER, vehicle_preset

        self.setup = setup
        config = TrainConfig.from_dict(setup.config)
        self.config = config
        track = load_track(setup.track)
        params = config.episode_params()
        params = replace(params, reverse=setup.reverse,
                         start_ndist=(params.start_ndist + params.round_robin_advance * setup.start_offset) % 1.0)
        self.sim = Simulator(track, setup.num_cars, vehicle_preset(config.car), params, race=config.race_type,
                             seed=setup.seed)
        randomization = None
        if config.domain_randomization:
            from laplab.sensors.randomize import DOMAIN_RANDOMIZATION
            randomization = DOMAIN_RANDOMIZATION
        self.observations = ObservationBuilder(self.sim, config.spec, seed=setup.seed, randomization=randomization)
        max_speed = config.model_metadata.action_space.max_speed
        self.reward_fn = _compile_reward(setup.reward_source, setup.reward_path, "reward_function",
                                         float(max_speed), DEEPRACER.max_steering_deg)
        self.stepper = EpisodeStepper(self.sim, config.spec.action_space, self.reward_fn)
        threads = setup.cores if config.spec.camera is not None else 1
        self.torch_threads = config.num_threads or threads
        self.learner = build_learner(replace(config, num_threads=self.torch_threads), setup.seed)
        self._where: dict | None = None

    def ping(self) -> int:
        """The worker's process id (it is alive)."""
        return os.getpid()

    def where(self) -> dict:
        """Where the worker runs: ``host`` (name), ``node_ip``, ``node_id`` (Ray's), ``pid``, ``actor_id``."""
        import socket
        facts = {"host": socket.gethostname(), "pid": os.getpid(), "node_ip": None, "node_id": None, "actor_id": None}
        ray = sys.modules.get("ray")
        if ray is None or not ray.is_initialized():  # a plain object, not an actor: asking Ray would start one
            return facts
        try:
            context = ray.get_runtime_context()
            facts.update(node_id=context.get_node_id(), actor_id=context.get_actor_id(),
                         node_ip=ray.util.get_node_ip_address())
        except Exception:  # noqa: BLE001 - facts Ray cannot give stay None
            pass
        return facts

    def _progress_hook(self, board, policy_version: int, post_poses: bool):
        """Tell ``board`` (a ProgressBoard actor) the episodes done, at most every REPORT_INTERVAL_S,
        and with ``post_poses`` the cars' poses, at most every POSES_INTERVAL_S."""
        if board is None:
            return None
        from laplab.cluster.status import POSES_INTERVAL_S, REPORT_INTERVAL_S
        from laplab.sim.state import episodes_done_and_steps
        last = [time.monotonic(), -float("inf")]  # the last report, the last poses posted (the first step posts)

        def hook(poses, sim_time) -> None:
            now = time.monotonic()
            if now - last[0] >= REPORT_INTERVAL_S:
                last[0] = now
                board.report.remote(self.setup.index, policy_version, *episodes_done_and_steps(self.sim.state))
            if post_poses and now - last[1] >= POSES_INTERVAL_S:
                last[1] = now
                field = self.sim.field  # a race's boxes and bots, for the live view to draw
                board.post_poses.remote(self.setup.index, policy_version, np.asarray(poses, np.float32), sim_time,
                                        field.obstacles if field is not None else None)
        return hook

    def collect(self, policy: dict, policy_version: int, episodes_before: int, board=None,
                post_poses: bool = False) -> WorkerResult:
        """Drive one episode per car with the broadcast ``policy`` (see :func:`policy_weights`);
        tell ``board`` (a :class:`~laplab.cluster.status.ProgressBoard` actor, optional) how far it is
        and, with ``post_poses``, where its cars are (for a live view)."""
        called = time.perf_counter()
        import numba
        import torch

        from laplab.cluster.batches import tag
        from laplab.reward.watchdog import RewardWatchdog, WatchdogLimits
        from laplab.train.collect import collect_episodes
        numba.set_num_threads(min(self.setup.cores, numba.config.NUMBA_NUM_THREADS))  # per calling thread
        learner = self.learner
        if policy["algorithm"] != learner.algorithm:
            raise ValueError(f"worker {self.setup.index} runs {learner.algorithm}, got {policy['algorithm']} weights")
        # torch.tensor copies: the arrays Ray hands out are read-only views of its object store
        learner.policy_network.load_state_dict({k: torch.tensor(v) for k, v in policy["weights"].items()})
        if hasattr(learner, "env_steps"):
            learner.env_steps = policy["env_steps"]
        before = int(getattr(learner, "env_steps", 0))
        self.sim.restart_schedule(episodes_before)

        threads = self.torch_threads

        def act(obs):
            # torch's thread count is per OpenMP thread, and off the process's main thread (where Ray runs
            # actor methods) each numba-parallel simulator step sets it back to every core: a vector
            # network then acted 4x slower, on 2 threads beside numba's pool
            if torch.get_num_threads() != threads:
                torch.set_num_threads(threads)
            step = learner.act(obs, False)
            return step.action, step.env_action, step.log_prob, step.value

        limits = WatchdogLimits(self.setup.reward_timeout_s, self.setup.reward_wait_timeout_s)
        try:
            with RewardWatchdog(limits):
                batch = collect_episodes(self.stepper, self.observations, act, learner.values,
                                         on_poses=self._progress_hook(board, policy_version, post_poses))
        except RewardFunctionError as exc:
            return WorkerResult(self.setup.index, policy_version, reward_error=str(exc), pid=os.getpid())
        acted = int(getattr(learner, "env_steps", 0)) - before
        tagged = tag(batch, self.setup.index, self.setup.track_label, policy_version)
        if self._where is None:
            self._where = self.where()
        return WorkerResult(self.setup.index, policy_version, tagged, acted, pid=os.getpid(), where=self._where,
                            busy_s=time.perf_counter() - called)


def split_cars(episodes: int, workers: int) -> list[int]:
    """``episodes`` shared out among ``workers`` as evenly as possible (the first get one more)."""
    base, extra = divmod(int(episodes), int(workers))
    return [base + (1 if i < extra else 0) for i in range(workers)]


def worker_seed(seed: int, index: int, restarts: int = 0) -> int:
    """Each worker (and each restart of it) samples its own random stream."""
    return int(np.random.SeedSequence([seed, index, restarts]).generate_state(1)[0])
