"""Collection on Ray: N rollout workers (actors) and the learner in the driver.

Each iteration the learner puts its policy weights in Ray's object store once (``ray.put``), tagged
with the policy version (the number of updates the weights have had: the trainer's iteration); the
workers drive their share of ``num_episodes_between_training`` episodes with exactly those weights
and return their episodes tagged with that version. The learner merges them and refuses any episode
of another version (PPO stays on-policy; SAC is kept synchronous the same way).

Faults: a worker whose process dies (killed, out of memory, a reward function that calls
``os._exit``) is replaced by a new actor (same share, same track, a new seed) and its share of the
iteration is collected again; every restart is announced to ``notify``. A worker that dies
:data:`MAX_RESTARTS_PER_ITERATION` times in one iteration ends the job (the last checkpoint stays).
A reward function that *raises* is no fault of the worker: it ends the job with the usual
RewardFunctionError paragraph.

While they collect, the workers tell a :class:`~laplab.cluster.status.ProgressBoard` how many of
their episodes are done; ``collect(..., on_progress=...)`` hears the iteration's total about once a
second. The workers' state (node, pid, restarts, episodes) goes to ``on_status`` whenever it changes
(:mod:`laplab.cluster.status`: the model folder's ``logs/workers.json``). With ``on_poses`` (a live
view) the workers driving the job's first track post their cars' poses to the board and the learner
hands them on about 15 times a second (cars on a multi-track job's other tracks would be drawn on the
wrong outline, so they are left out).
"""

from __future__ import annotations

import logging
import os
import socket
import time
from typing import Callable, Sequence

import numpy as np

from laplab.cluster.batches import TaggedEpisodeBatch, merge_batches
from laplab.cluster.status import POSES_INTERVAL_S, ProgressBoard, WorkerRecord
from laplab.cluster.worker import (RolloutWorker, RolloutWorkerError, WorkerResult, WorkerSetup, policy_weights,
                                   worker_seed)
from laplab.train.collect import CollectionAborted
from laplab.train.errors import JobError

MAX_RESTARTS_PER_ITERATION = 3
_POLL_S = 0.2
PROGRESS_READ_S = 1.0  # the learner reads the workers' progress board at most this often
BOARD_START_S = 60.0  # the progress board's process starts within this, or the job runs without it
BOARD_ANSWER_S = 5.0
CLIENT_ATTEMPTS = 3  # Ray Client connections tried when the head fails to start the client's server


class WorkerFailure(JobError):
    """A rollout worker kept dying; the job stops with its last checkpoint."""


class StalePolicyError(RuntimeError):
    """Episodes acted with another policy version than the one being trained (a bug if ever raised)."""


def require_policy_version(batch: TaggedEpisodeBatch, version: int) -> None:
    """Refuse a batch unless every episode (every transition of it) was acted with ``version``."""
    versions = np.asarray(batch.policy_version)
    if versions.shape != batch.status.shape or (versions != version).any():
        stale = sorted(set(versions.tolist()) - {version})
        raise StalePolicyError(f"a learner update of policy version {version} got episodes of version(s) {stale}")


def check_reachable(address: str, timeout_s: float = 3.0,
                    otherwise: str = "train without --ray-address to use a local Ray") -> None:
    """A clear :class:`JobError` when nothing listens at ``address`` (``host:port`` or
    ``ray://host:port``); Ray itself would wait for minutes. ``auto`` is left to Ray."""
    if address == "auto":
        return
    target = address.split("://", 1)[-1]
    host, _, port = target.rpartition(":")
    if not host or not port.isdigit():
        raise JobError(f"--ray-address {address!r}: write HOST:PORT of the cluster's head node "
                       "(the address `ray start --head` prints, e.g. 192.168.1.10:6379) or auto")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise JobError(f"cannot reach the Ray cluster at {address} ({exc.strerror or exc}); start its head "
                       f"node with `ray start --head` on that machine (or {otherwise}).") from None


def connect_ray(address: str | None, workers: int) -> bool:
    """Join the cluster at ``address``, or start a quiet local Ray (no dashboard) with at least one
    CPU per worker. Returns True when this call started (and so must stop) Ray."""
    try:
        import ray
    except ImportError:
        raise JobError("rollout workers (--workers above 1, or --ray-address) run on Ray, which is not installed: "
                       "pip install -e \".[train,cluster]\" (ray[default]==2.60.0), or train with --workers 1") from None
    if ray.is_initialized():
        return False
    quiet = {"logging_level": logging.ERROR, "log_to_driver": False, "configure_logging": True}
    if address:
        check_reachable(address)
    client = bool(address) and address.startswith("ray://")
    if client:
        use_ray_token()  # Ray Client sends the token only when told to
    try:
        for attempt in range(CLIENT_ATTEMPTS if client else 1):
            try:
                if address:
                    ray.init(address=address, **quiet)
                else:
                    ray.init(num_cpus=max(workers + 1, os.cpu_count() or 1), include_dashboard=False, **quiet)
                break
            except ConnectionAbortedError:  # the head could not start this client's server in time (a busy head)
                if attempt + 1 == CLIENT_ATTEMPTS:
                    raise
                ray.shutdown()
                time.sleep(2.0)
    except Exception as exc:  # Ray's own start-up errors: a paragraph, not a traceback
        where = f"join the Ray cluster at {address}" if address else "start a local Ray"
        hint = "an overloaded machine can make Ray's start time out; try again, or use fewer --workers"
        if client:
            hint = ("is its client server up, and the same Ray and Python here and there? A cluster with token "
                    "authentication (Ray's default) needs its token here: RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or "
                    "~/.ray/auth_token (`ray get-auth-token` on the head prints it)")
        raise JobError(f"could not {where}: {_reason(exc)} ({hint})") from None
    return True


def use_ray_token() -> None:
    """Make this process's Ray authenticate with the token of :func:`ray_auth_environment`."""
    variables = ray_auth_environment()
    if not variables or all(os.environ.get(k) == v for k, v in variables.items()):
        return
    os.environ.update(variables)
    try:  # Ray reads its settings once; read them again, as Ray does when it turns token mode on itself
        from ray._raylet import Config
        Config.initialize("")
    except (ImportError, AttributeError):
        pass


def ray_auth_environment() -> dict[str, str]:
    """The variables that make Ray authenticate with the cluster's token (Ray's token authentication:
    ``RAY_AUTH_MODE=token`` and ``RAY_AUTH_TOKEN``), from ``RAY_AUTH_TOKEN``, the file at
    ``RAY_AUTH_TOKEN_PATH`` or ``~/.ray/auth_token``; {} when no token is at hand or
    ``RAY_AUTH_MODE`` says otherwise."""
    mode = os.environ.get("RAY_AUTH_MODE")
    if mode is not None and mode.lower() != "token":
        return {}
    token = os.environ.get("RAY_AUTH_TOKEN")
    if not token:
        from pathlib import Path
        path = Path(os.environ.get("RAY_AUTH_TOKEN_PATH") or Path.home() / ".ray" / "auth_token")
        try:
            token = path.read_text().strip()
        except OSError:
            return {}
    return {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": token} if token else {}


def _is_worker_death(exc: BaseException) -> bool:
    import ray.exceptions as rex
    dead = (rex.RayActorError, rex.WorkerCrashedError, rex.ObjectLostError, rex.OutOfMemoryError)
    return isinstance(exc, dead)


class RayCollector:
    """The trainer's collection step on Ray workers (a :class:`~laplab.train.collaborators.Collector`,
    made by :class:`laplab.cluster.launch.RayWorkers`; the trainer closes it). ``setups``: one
    :class:`WorkerSetup` per worker; ``notify(message)`` hears about restarts; ``on_status(records)``
    gets the workers' :class:`~laplab.cluster.status.WorkerRecord` list whenever it changes."""

    def __init__(self, setups: Sequence[WorkerSetup], notify: Callable[[str], None] = lambda message: None,
                 ray_address: str | None = None,
                 on_status: Callable[[list[WorkerRecord]], None] = lambda records: None):
        self.setups = list(setups)
        self.notify = notify
        self.on_status = on_status
        self.ray_address = ray_address
        self.actors: list = []
        self.board = None
        self.restarts = [0] * len(self.setups)  # over the job, per worker
        self.records = [WorkerRecord(s.index, s.track_label) for s in self.setups]
        self._started_ray = False
        self._actor_class = None
        # the last iteration's wall time by part (s): ``broadcast`` (the weights into the object store),
        # the slowest worker's ``driving`` and ``worker_other`` (loading the weights, packing the episodes),
        # ``transport`` (the calls, the wait and the episodes coming back: the rest of the wait) and ``merge``
        self.last_timing: dict[str, float] = {}

    # -- lifetime --------------------------------------------------------------------------------

    def start(self) -> "RayCollector":
        self._started_ray = connect_ray(self.ray_address, len(self.setups))  # first: a clear error without Ray
        import ray
        self._actor_class = ray.remote(num_cpus=1, max_restarts=0)(RolloutWorker)
        self.actors = [self._actor_class.remote(setup) for setup in self.setups]
        self._status()
        try:
            places = ray.get([actor.where.remote() for actor in self.actors])  # built: their simulators are up
        except Exception as exc:
            self.close()
            raise JobError(f"the rollout workers could not start: {_reason(exc)}") from None
        for record, where in zip(self.records, places):
            record.place(where)
            record.state = "alive"
        try:  # up before the first iteration asks it (a loaded machine takes seconds to start its process)
            self.board = ray.remote(num_cpus=0, max_restarts=0)(ProgressBoard).remote()
            ray.get(self.board.read.remote(-1), timeout=BOARD_START_S)
        except Exception:  # noqa: BLE001 - progress is a nicety: collection works without it
            self.board = None
        self._status()
        return self

    def close(self) -> None:
        import ray
        for actor in [*self.actors, *([self.board] if self.board is not None else [])]:
            try:
                ray.kill(actor, no_restart=True)
            except Exception:  # already gone
                pass
        if self.actors:
            for record in self.records:
                if record.state != "dead":
                    record.state = "stopped"
            self._status()
        self.actors, self.board = [], None
        if self._started_ray and ray.is_initialized():
            ray.shutdown()
        self._started_ray = False

    def __enter__(self) -> "RayCollector":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _status(self) -> None:
        try:
            self.on_status(self.records)
        except OSError:  # a full disk must not end the training: the file is for displays
            pass

    def pids(self) -> list[int]:
        """The process ids of the workers (for tests and displays)."""
        import ray
        return ray.get([actor.ping.remote() for actor in self.actors])

    def _replace(self, index: int, cause: str) -> None:
        import ray
        try:
            ray.kill(self.actors[index], no_restart=True)
        except Exception:
            pass
        self.restarts[index] += 1
        record = self.records[index]
        record.state, record.restarts, record.cause = "restarting", self.restarts[index], cause
        record.pid = record.actor_id = None
        setup = self.setups[index]
        from dataclasses import replace
        setup = replace(setup, seed=worker_seed(setup.seed, index, self.restarts[index]))
        self.actors[index] = self._actor_class.remote(setup)
        self._status()

    def _ask_board(self, method: str, version: int) -> dict:
        """The board's ``method(version)``: {} when it is slow to answer, and when it is gone (a lost
        board costs the progress line and the live view, not the job; it is not asked again)."""
        if self.board is None:
            return {}
        import ray
        try:
            return ray.get(getattr(self.board, method).remote(version), timeout=BOARD_ANSWER_S)
        except ray.exceptions.GetTimeoutError:
            return {}
        except Exception:  # noqa: BLE001 - see the docstring
            self.board = None
            return {}

    def _read_board(self, version: int) -> dict[int, tuple[int, int]]:
        """The workers' (episodes done, env steps) of this iteration so far."""
        return self._ask_board("read", version)

    # -- one iteration ---------------------------------------------------------------------------

    def _read_poses(self, version: int) -> tuple[np.ndarray, float, object] | None:
        """The cars on the first track now, (N, 3) x m, y m, yaw rad in worker order, the latest sim
        time (s) posted and their race obstacles (an Obstacles of (N, K) arrays, None in a time trial);
        None when no worker has posted (or the board is gone)."""
        posted = self._ask_board("read_poses", version)
        pieces = [posted[i] for i in sorted(posted) if self._on_first_track(i)]
        if not pieces:
            return None
        poses = np.concatenate([np.asarray(p[0]) for p in pieces])
        obstacles = [p[2] for p in pieces]
        if any(o is None for o in obstacles):
            joined = None
        else:
            from laplab.sim.obstacles import Obstacles
            joined = Obstacles(*(np.concatenate([np.asarray(o[f]) for o in obstacles])
                                 for f in range(len(Obstacles._fields))))
        return poses, max(p[1] for p in pieces), joined

    def _on_first_track(self, index: int) -> bool:
        return self.setups[index].track == self.setups[0].track

    def collect(self, trainer, should_abort: Callable[[], bool] = lambda: False,
                on_progress: Callable[[int, int], None] | None = None,
                on_poses: Callable[[np.ndarray, float], None] | None = None) -> TaggedEpisodeBatch:
        """Every worker's share of the iteration with the trainer's current weights (version
        ``trainer.iteration``), merged; raises CollectionAborted, RolloutWorkerError (the reward
        function raised) or WorkerFailure. ``on_progress(episodes done, env steps)`` hears how far
        the workers are, about once a second and when a worker delivers; ``on_poses(poses (N, 3),
        sim_time s)`` the cars on the first track, about 15 times a second."""
        import ray
        started = time.perf_counter()
        learner, version = trainer.learner, int(trainer.iteration)
        policy = ray.put(policy_weights(learner))  # once: every worker reads the same object
        broadcast = time.perf_counter() - started
        episodes_before = int(trainer.episodes)

        def submit(index: int):
            post = on_poses is not None and self._on_first_track(index)
            return self.actors[index].collect.remote(policy, version, episodes_before, self.board, post)

        pending = {submit(i): i for i in range(len(self.actors))}
        results: dict[int, WorkerResult] = {}
        deaths = [0] * len(self.actors)
        last_read = last_poses = time.monotonic()
        poll_s = POSES_INTERVAL_S if on_poses is not None else _POLL_S

        def report() -> None:
            counts = self._read_board(version)
            done = steps = 0
            for index, setup in enumerate(self.setups):
                if index in results:
                    done += setup.num_cars
                    steps += int(results[index].batch.env_steps)
                elif index in counts:
                    done += min(counts[index][0], setup.num_cars)
                    steps += counts[index][1]
            on_progress(done, steps)

        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=poll_s)
            if should_abort():
                raise CollectionAborted
            for ref in ready:
                index = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:
                    if not _is_worker_death(exc):
                        raise
                    deaths[index] += 1
                    if deaths[index] > MAX_RESTARTS_PER_ITERATION:
                        self.records[index].state, self.records[index].cause = "dead", _reason(exc)
                        self._status()
                        raise WorkerFailure(
                            f"rollout worker {index} ({self.setups[index].track_label}) died "
                            f"{deaths[index]} times in iteration {version + 1}; the job stops with its last "
                            f"checkpoint. Last cause: {_reason(exc)}") from None
                    self.notify(f"rollout worker {index} died in iteration {version + 1} ({_reason(exc)}); "
                                f"restarted it, collecting its {self.setups[index].num_cars} episodes again")
                    self._replace(index, _reason(exc))
                    pending[submit(index)] = index
                    continue
                if result.reward_error is not None:
                    raise RolloutWorkerError(result.reward_error)
                results[index] = result
            if on_progress is not None and pending and (ready or time.monotonic() - last_read >= PROGRESS_READ_S):
                last_read = time.monotonic()
                report()
            # and when a worker delivers: the live view then has every worker's last cars, however short
            if on_poses is not None and (ready or pending and time.monotonic() - last_poses >= POSES_INTERVAL_S):
                last_poses = time.monotonic()
                cars = self._read_poses(version)
                if cars is not None:
                    on_poses(cars[0], cars[1], obstacles=cars[2])
        collected = time.perf_counter()
        batch = merge_batches([results[i].batch for i in range(len(self.actors))])
        require_policy_version(batch, version)
        slowest = max(results.values(), key=lambda r: r.busy_s)
        self.last_timing = {"broadcast": broadcast, "driving": float(slowest.batch.wall_seconds),
                            "worker_other": slowest.busy_s - float(slowest.batch.wall_seconds),
                            "transport": collected - started - broadcast - slowest.busy_s,
                            "merge": time.perf_counter() - collected}
        if hasattr(learner, "env_steps"):  # the epsilon schedule advances as the workers acted
            learner.env_steps += sum(r.acted_steps for r in results.values())
        if on_progress is not None:
            on_progress(int(len(batch.status)), int(batch.env_steps))
        for index, result in results.items():
            record = self.records[index]
            record.place(result.where)
            record.state, record.iteration = "alive", version + 1
            record.episodes += len(result.batch.status)
        self._status()
        return batch


def _reason(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    first = next((line for line in text if line.strip()), type(exc).__name__)
    return f"{type(exc).__name__}: {first[:300]}"
