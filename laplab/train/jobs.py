"""Training jobs over model folders: create (immutable names), train, resume, clone."""

from __future__ import annotations

import json
import os
import secrets
import shutil
from dataclasses import replace
from pathlib import Path

from laplab.env.vector import DEFAULT_REWARD
from laplab.reward.loader import RewardFunction, load_reward_function
from laplab.reward.validate import validate_reward_function
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import ModelFolder, model_folder, validate_model_name
from laplab.store.lock import LOCK_FILE_NAME, ModelBusyError, ModelLock
from laplab.train.config import TrainConfig
from laplab.train.model_files import check_model_files, write_model_files
from laplab.train.errors import JobError
from laplab.track.geometry import Track
from laplab.track.registry import load_track
from laplab.train.archive import check_reward_trusted, check_trainable
from laplab.train.background import BackgroundListeners
from laplab.train.checkpoint_read import read_checkpoint, read_resume_state
from laplab.train.collaborators import WorkerLauncher
from laplab.train.recorder import ModelFolderRecorder, RobomakerLogRecorder
from laplab.train.trainer import Trainer, load_weights_only


def reward_file(config: TrainConfig) -> Path:
    return Path(config.reward_path) if config.reward_path else DEFAULT_REWARD


def job_track(config: TrainConfig) -> Track:
    """The job's track, loaded once (the trainer, validation and evaluation laps all take it); refuses a
    race type whose objects or bots do not fit on any of the job's tracks."""
    track = load_track(config.track)
    for name, _ in config.training_tracks():
        other = track if name == config.track else load_track(name)
        config.race_type.check_track(other.length, other.name)
    return track


def load_and_validate_reward(config: TrainConfig, track: Track, path: Path | None = None) -> RewardFunction:
    """Load the job's reward function and run the validation sweep on ``track``; raises RewardFunctionError."""
    action_space = config.model_metadata.action_space
    reward_fn = load_reward_function(path or reward_file(config), max_speed=action_space.max_speed)
    report = validate_reward_function(reward_fn, track, action_space.sweep_actions(), isolate=True,
                                      race=config.race_type)
    if not report.passed:
        raise report.error
    return reward_fn


def create_training(name: str, config: TrainConfig, init_weights: dict | None = None,
                    listeners: tuple = (), device: str = "cpu", launcher: WorkerLauncher | None = None) -> Trainer:
    """Validate everything, create the model folder and return a :class:`Trainer` for it, holding
    the folder's lock (and the workers ``launcher`` started) until :meth:`Trainer.close`.

    Refuses an existing name (a model is immutable). Nothing is written before validation passes
    (``launcher.check`` included). ``listeners`` are subscribed after the folder's recorders (e.g. an
    object store's sync); ``launcher`` (None: collection in-process) starts the rollout workers, once
    the folder exists, before the trainer is built (:mod:`laplab.train.collaborators`).
    """
    validate_model_name(name)
    folder = model_folder(name)
    if folder.exists():
        raise JobError(f"a model named {name!r} already exists at {folder.root}; models are immutable: "
                       f"pick another name, `laplab clone {name} NEW` to continue from it, or "
                       f"`laplab train --resume {name}` if its training was interrupted.")
    track = job_track(config)
    reward_fn = load_and_validate_reward(config, track)
    if launcher is not None:
        launcher.check(config, reward_fn)
    # The folder is written beside its final place and renamed into it: a job killed at any moment
    # leaves a complete model folder or none (an unfinished one is a hidden .create-* folder).
    folder.root.parent.mkdir(parents=True, exist_ok=True)
    staging = ModelFolder(folder.root.parent / f".create-{name}-{secrets.token_hex(4)}")
    try:
        staging.create()
        write_model_files(staging, config, reward_file(config).read_text())
        lock = take_lock(staging)  # the lock file moves with the folder (same inode)
        try:
            os.rename(staging.root, folder.root)  # atomic; fails when the name was taken meanwhile
        except OSError:
            lock.release()
            raise JobError(f"a model named {name!r} was just created at {folder.root} by another job; "
                           "pick another name.") from None
    except BaseException:
        shutil.rmtree(staging.root, ignore_errors=True)
        raise
    lock.root = folder.root
    return _start(folder, config, reward_fn, track, lock, init_weights=init_weights, listeners=listeners,
                  device=device, launcher=launcher, discard=lambda: shutil.rmtree(folder.root, ignore_errors=True))


def create_training_in_place(name: str, config: TrainConfig, init_weights: dict | None = None,
                             launcher: WorkerLauncher | None = None) -> Trainer:
    """:func:`create_training` for a model folder made empty beforehand (the console's confined jobs
    see only that folder, so they cannot write beside it and rename). Refuses a folder with files."""
    validate_model_name(name)
    folder = model_folder(name)
    if folder.exists() and any(p.name != LOCK_FILE_NAME for p in folder.root.iterdir()):
        raise JobError(f"a model named {name!r} already exists at {folder.root}; models are immutable.")
    track = job_track(config)
    reward_fn = load_and_validate_reward(config, track)
    if launcher is not None:
        launcher.check(config, reward_fn)
    folder.create()
    lock = take_lock(folder)
    try:
        write_model_files(folder, config, reward_file(config).read_text())
    except BaseException:
        lock.release()
        raise
    return _start(folder, config, reward_fn, track, lock, init_weights=init_weights, launcher=launcher,
                  discard=lambda: _empty(folder))


def _empty(folder: ModelFolder) -> None:
    """Remove what a job wrote in ``folder``, all but its lock file (the folder is left as it was given)."""
    for path in folder.root.iterdir():
        if path.name == LOCK_FILE_NAME:
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def _start(folder: ModelFolder, config: TrainConfig, reward_fn: RewardFunction, track: Track, lock: ModelLock, *,
           init_weights: dict | None = None, resume_from: dict | None = None, listeners: tuple = (),
           device: str = "cpu", launcher: WorkerLauncher | None = None, discard=None) -> Trainer:
    """The trainer of a job whose folder is written and locked: its workers started by ``launcher``,
    the folder's recorders (then ``listeners``) subscribed, checkpoint 0 written for a new job. On any
    failure the workers are stopped, ``discard()`` (a new job's: remove what it wrote, so that a model
    folder is whole, with checkpoint 0, or absent) runs and then the lock is released."""
    iteration = int(resume_from["iteration"]) if resume_from is not None else 0
    episodes = int(resume_from["episodes"]) if resume_from is not None else 0
    collector = recorders = None
    try:
        collector, evaluator = launcher.start(config, reward_fn, folder, iteration) if launcher else (None, None)
        # the folder's files are written on one background thread while the next iteration runs
        recorders = BackgroundListeners((ModelFolderRecorder(folder, iteration, episodes, config.workers),
                                         RobomakerLogRecorder(folder, config)))
        trainer = Trainer(config, reward_fn, track, resume_from=resume_from, device=device, folder=folder, lock=lock,
                          listeners=(recorders, *listeners), collector=collector, evaluator=evaluator)
        if init_weights is not None:
            load_weights_only(trainer.learner, init_weights)
        if resume_from is None:  # a new job (or one killed before its first checkpoint)
            trainer.save_initial_checkpoint()
    except BaseException:
        try:
            try:
                if recorders is not None:
                    recorders.close()  # its thread ends (a failed checkpoint 0 was raised already)
            finally:
                if collector is not None:
                    collector.close()
        finally:
            if discard is not None:
                discard()
            lock.release()
        raise
    return trainer


def take_lock(folder, what: str = "trained") -> ModelLock:
    """The model folder's job lock, or :class:`JobError` naming the job that holds it."""
    try:
        return ModelLock(folder.root, what).acquire()
    except ModelBusyError as exc:
        raise JobError(str(exc)) from None


def resume_training(name: str, max_time_s: float | None = None, max_episodes: int | None = None,
                    trust_reward: bool = False, workers: int | None = None, device: str = "cpu",
                    listeners: tuple = (), launcher: WorkerLauncher | None = None) -> Trainer:
    """A Trainer that continues ``name`` from its last checkpoint (iteration count continues),
    holding the folder's lock (and the workers ``launcher`` started) until :meth:`Trainer.close`.

    ``max_time_s`` (a new budget for this session) and ``max_episodes`` (a new total) override the
    stored stop conditions; ``workers`` (rollout workers, any count) overrides the stored one and is
    recorded in laplab.json once ``launcher`` accepts it. An imported model's reward function runs
    only once trusted (``trust_reward``, recorded: see :mod:`laplab.train.archive`)."""
    folder = model_folder(name)
    if not folder.exists():
        raise JobError(f"no model named {name!r} to resume (looked in {folder.root}).")
    lock = take_lock(folder)
    try:
        check_trainable(folder, f"laplab train --resume {name}")
        check_reward_trusted(folder, trust_reward, f"laplab train --resume {name}")
        config = check_model_files(folder, what="resume")
        if max_time_s is not None:
            config = replace(config, max_time_s=max_time_s)
        if max_episodes is not None:
            config = replace(config, max_episodes=max_episodes)
        stored_workers = config.workers
        if workers is not None:
            config = replace(config, workers=workers)
        track = job_track(config)
        reward_fn = load_and_validate_reward(config, track, folder.reward_function)
        if launcher is not None:
            launcher.check(config, reward_fn)
        checkpoints = CheckpointStore(folder)
        if checkpoints.names():
            _, state = read_resume_state(folder)
        elif checkpoints.last() is not None:  # the index names one whose file is gone: never start over silently
            raise JobError(f"cannot resume model {name!r}: {folder.deepracer_checkpoints} names the last checkpoint "
                           f"{checkpoints.last().name!r}, but {folder.model_dir} holds no checkpoint file (were they "
                           f"deleted?). Restore the checkpoint files, or `laplab train --name NEW` to start over.")
        else:  # killed before its first checkpoint was written: start again from scratch
            state = None
        if config.workers != stored_workers:
            folder.write_laplab_config(config.to_dict())
        if folder.error_file.exists():
            folder.error_file.unlink()
    except BaseException:
        lock.release()
        raise
    return _start(folder, config, reward_fn, track, lock, resume_from=state, listeners=listeners, device=device,
                  launcher=launcher)


def clone_config(source: str, overrides: dict, trust_reward: bool = False) -> tuple[TrainConfig, dict]:
    """The config of a clone of ``source`` with ``overrides`` applied, and the weights to start from.

    Without a new ``reward_path`` the clone runs the source's reward function, which must be trusted
    if the source was imported (``trust_reward`` records it).

    The action space and the sensors cannot change (DeepRacer's rule): a different
    model_metadata.json is refused with a message naming what differs.
    """
    folder = model_folder(source)
    if not folder.exists():
        raise JobError(f"no model named {source!r} to clone (looked in {folder.root}).")
    check_trainable(folder, f"laplab clone {source} NEW")
    base = check_model_files(folder, what="clone")
    if overrides.get("reward_path") is None:
        check_reward_trusted(folder, trust_reward, f"laplab clone {source} NEW")
        overrides = {**overrides, "reward_path": str(folder.reward_function)}
    new_meta = overrides.get("model_metadata")
    if new_meta is not None:
        old, new = base.model_metadata, replace(base, model_metadata=new_meta).model_metadata
        for what, a, b in (("action space", old.action_space, new.action_space), ("sensors", old.sensors, new.sensors),
                           ("neural network", old.neural_network, new.neural_network),
                           ("training algorithm", old.training_algorithm, new.training_algorithm)):
            if a != b:
                raise JobError(f"a clone keeps its source's {what}: {source!r} has {_show(a)}, the new "
                               f"model_metadata.json asks for {_show(b)}.")
    config = replace(base, **{k: v for k, v in overrides.items() if v is not None})
    name, state = read_checkpoint(folder, "best")
    return replace(config, cloned_from=f"{source} (checkpoint {name})"), state["learner"]


def _show(value) -> str:
    return json.dumps(value.to_json()) if hasattr(value, "to_json") else str(value)
