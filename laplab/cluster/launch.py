"""Turn a :class:`~laplab.train.trainer.Trainer` into a learner with rollout workers on Ray.

:func:`attach_workers` checks the job (enough workers for its tracks and episodes, the reward
function on every track), gives worker i the track ``tracks[i % len(tracks)]`` (as
deepracer-for-cloud's ``DR_TRAIN_MULTI_CONFIG``) and its share of the iteration's episodes, starts
the workers and plugs them into the trainer; a multi-track job also evaluates on every track.
"""

from __future__ import annotations

import os
import time
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


def logged_notify(trainer, say: Callable[[str], None]) -> Callable[[str], None]:
    """A ``notify`` for :func:`attach_workers`: each message (a restart) to ``say`` and, time-stamped,
    to the model folder's ``logs/workers.log``."""
    log = trainer.folder.root / "logs" / "workers.log"

    def notify(message: str) -> None:
        say(message)
        log.parent.mkdir(parents=True, exist_ok=True)
        with open(log, "a") as handle:
            handle.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {message}\n")
    return notify


def attach_workers(trainer, workers: int, ray_address: str | None = None,
                   notify: Callable[[str], None] = lambda message: None,
                   reward_timeout_s: float = 5.0, reward_wait_timeout_s: float = 60.0) -> RayCollector:
    """Start ``workers`` rollout workers (on the cluster at ``ray_address``, or a local Ray) and
    make them ``trainer``'s collection step. Returns the collector; ``close()`` it after the job.
    The workers' state goes to the model folder's ``logs/workers.json`` (:mod:`laplab.cluster.status`)."""
    config = trainer.config
    check_workers(config, workers)
    validate_reward_on_tracks(config, trainer.reward_fn)
    source = trainer.reward_fn.source
    path = str(getattr(trainer.reward_fn, "path", "<string>"))
    setups = worker_setups(config, source, path, workers, reward_timeout_s, reward_wait_timeout_s)
    on_status = (lambda records: None)
    if getattr(trainer, "folder", None) is not None:  # the model page's table (laplab.cluster.status)
        status_path, since = workers_file(trainer.folder.root), int(trainer.iteration)
        on_status = lambda records: write_workers(status_path, records, since)  # noqa: E731
    collector = RayCollector(setups, notify, ray_address, on_status).start()
    trainer.collector = collector
    if len(config.training_tracks()) > 1:
        trainer.evaluator = MultiTrackEvaluator(config, trainer.reward_fn, config.training_tracks())
    return collector


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
