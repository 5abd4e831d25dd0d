"""Rollout workers on Ray for a training job, given to its trainer when it is built.

:class:`RayWorkers` checks the job (enough workers for its tracks and episodes, the reward function
on every track) before its folder is written, then gives worker i the track ``tracks[i % len(tracks)]``
(as deepracer-for-cloud's ``DR_TRAIN_MULTI_CONFIG``) and its share of the iteration's episodes and
starts the workers: the trainer's collector; a multi-track job also evaluates on every track.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Callable

from laplab.cluster.collector import RayCollector
from laplab.cluster.evaluate import MultiTrackEvaluator
from laplab.cluster.status import workers_file, write_workers
from laplab.cluster.worker import WorkerSetup, split_cars, worker_seed
from laplab.train.errors import JobError


def uses_ray(workers: int, ray_address: str | None) -> bool:
    """Several workers or a cluster: collection on Ray; else the in-process path (no Ray import)."""
    return workers > 1 or bool(ray_address)


def check_workers(config, workers: int) -> None:
    """A clear error for a worker count this job cannot use."""
    tracks = config.training_tracks()
    episodes = config.hyper().num_episodes_between_training
    if len(tracks) > workers:
        raise JobError(f"{len(tracks)} training tracks need at least {len(tracks)} rollout workers (each worker "
                       f"drives one track, as DR_TRAIN_MULTI_CONFIG): add --workers {len(tracks)}")
    if workers > episodes:
        raise JobError(f"--workers {workers} is more than the {episodes} episodes of an iteration "
                       f"(hyperparameter num_episodes_between_training): every worker needs at least one")


def worker_setups(config, reward_source: str, reward_path: str, workers: int,
                  reward_timeout_s: float = 5.0, reward_wait_timeout_s: float = 60.0) -> list[WorkerSetup]:
    """One setup per worker: its track (round-robin over the job's tracks), cars and seed."""
    tracks = config.training_tracks()
    shares = split_cars(config.hyper().num_episodes_between_training, workers)
    setups, offset = [], 0
    data = config.to_dict()
    cores = max(1, (os.cpu_count() or 1) // workers)  # a machine's cores shared by its workers
    for index, cars in enumerate(shares):
        track, reverse = tracks[index % len(tracks)]
        setups.append(WorkerSetup(data, index, track, reverse, cars, offset, worker_seed(config.seed, index),
                                  reward_source, reward_path, reward_timeout_s, reward_wait_timeout_s,
                                  cores))
        offset += cars
    return setups


def validate_reward_on_tracks(config, reward_fn) -> None:
    """The reward validation sweep on every training track but the first (already done)."""
    from laplab.reward.validate import validate_reward_function
    from laplab.track.registry import load_track
    actions = config.model_metadata.action_space.sweep_actions()
    for name, reverse in config.training_tracks()[1:]:
        report = validate_reward_function(reward_fn, load_track(name, reverse=reverse), actions, isolate=True,
                                          race=config.race_type)
        if not report.passed:
            raise report.error


def logged_notify(folder, say: Callable[[str], None]) -> Callable[[str], None]:
    """A ``notify`` for the workers of the job writing ``folder`` (a
    :class:`~laplab.store.layout.ModelFolder`): each message (a restart) to ``say`` and,
    time-stamped, to the folder's ``logs/workers.log``."""
    log = folder.root / "logs" / "workers.log"

    def notify(message: str) -> None:
        say(message)
        log.parent.mkdir(parents=True, exist_ok=True)
        with open(log, "a") as handle:
            handle.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {message}\n")
    return notify


def _quiet(message: str) -> None:
    """Says nothing (the default of :class:`RayWorkers`' ``notify`` and ``announce``)."""


@dataclass(frozen=True)
class RayWorkers:
    """How a training job's rollout workers start: a :class:`~laplab.train.collaborators.WorkerLauncher`
    for :func:`laplab.train.jobs.create_training` and :func:`~laplab.train.jobs.resume_training`.

    The job's ``config.workers`` workers run on the cluster at ``ray_address`` (None: a local Ray);
    a job with one worker and no address collects in-process and Ray is not imported. ``announce``
    hears the line saying the workers start; ``notify`` each restart (also time-stamped in the
    folder's ``logs/workers.log``); ``reward_timeout_s`` and ``reward_wait_timeout_s`` limit the
    workers' reward calls as the job's own watchdog does (:class:`laplab.reward.watchdog.WatchdogLimits`);
    ``ray_for_one``: a one-worker job collects on Ray too (benchmarks measure Ray's overhead so).
    """

    ray_address: str | None = None
    notify: Callable[[str], None] = _quiet
    announce: Callable[[str], None] = _quiet
    reward_timeout_s: float = 5.0
    reward_wait_timeout_s: float = 60.0
    ray_for_one: bool = False

    def check(self, config, reward_fn) -> None:
        """Enough workers for the job's tracks and not more than its episodes; the reward function
        validated on every track (the first one already is), before the job writes anything."""
        if config.workers > 1 or len(config.training_tracks()) > 1:
            check_workers(config, config.workers)
        validate_reward_on_tracks(config, reward_fn)

    def start(self, config, reward_fn, folder, iteration: int) -> tuple[RayCollector | None,
                                                                         MultiTrackEvaluator | None]:
        """Start the workers of the job in ``folder`` (at ``iteration``; their state goes to its
        ``logs/workers.json``, :mod:`laplab.cluster.status`, for the model page): the trainer's
        collector (its owner closes it) and, for a multi-track job, an evaluator on every track.
        (None, None) for an in-process job."""
        workers = config.workers
        if not (self.ray_for_one or uses_ray(workers, self.ray_address)):
            return None, None
        tracks = config.training_tracks()
        evaluator = MultiTrackEvaluator(config, reward_fn, tracks) if len(tracks) > 1 else None
        setups = worker_setups(config, reward_fn.source, str(reward_fn.path), workers, self.reward_timeout_s,
                               self.reward_wait_timeout_s)
        status_path = workers_file(folder.root)
        self.announce(f"starting {workers} rollout worker{'s' if workers > 1 else ''} on "
                      f"{'the Ray cluster at ' + self.ray_address if self.ray_address else 'a local Ray'}")
        collector = RayCollector(setups, logged_notify(folder, self.notify), self.ray_address,
                                 lambda records: write_workers(status_path, records, iteration)).start()
        return collector, evaluator


def resolve_device(name: str) -> str:
    """``cpu`` or ``cuda`` (the learner's torch device); a clear error when no GPU is usable."""
    if name == "cpu":
        return name
    if name != "cuda" and not name.startswith("cuda:"):
        raise JobError(f"--device must be cpu or cuda, got {name!r}")
    import torch
    if not torch.cuda.is_available():
        raise JobError("--device cuda: torch sees no usable GPU here (torch.cuda.is_available() is False; the "
                       "CPU wheel of torch, no NVIDIA driver, or CUDA_VISIBLE_DEVICES hides it); train with "
                       "--device cpu")
    return name
