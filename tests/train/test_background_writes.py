"""The model folder's writes on a background thread (laplab.train.background): order, waits, failures."""

from __future__ import annotations

import os
import threading
import time
from dataclasses import replace

import pytest
import torch

from laplab.env.metadata import ModelMetadata
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import model_folder
from laplab.train.background import MAX_PENDING_CHECKPOINTS, WRITER_NICENESS, BackgroundListeners
from laplab.train.checkpoint_read import read_resume_state
from laplab.train.config import TrainConfig
from laplab.train.jobs import create_training, take_lock
from laplab.train.recorder import ModelFolderRecorder
from laplab.train.trainer import checkpoint_writer, load_checkpoint, resume_writer

pytestmark = pytest.mark.usefixtures("laplab_home")  # tests/train/conftest.py

SMALL_HP = {"num_episodes_between_training": 4, "batch_size": 32, "num_epochs": 3}


def small_config(**changes) -> TrainConfig:
    hyper = {**TrainConfig().hyper().to_dict(), **SMALL_HP}
    return replace(TrainConfig(), hyperparameters=hyper, model_metadata=ModelMetadata().to_dict(), max_time_s=120,
                   **changes)


class Log:
    """A listener that records (event, payload, thread name), optionally slowly or failing."""

    def __init__(self, delay: float = 0.0, fail_on: object = None):
        self.seen: list[tuple[str, object, str]] = []
        self.delay, self.fail_on = delay, fail_on

    def _record(self, event, payload):
        time.sleep(self.delay)
        if payload == self.fail_on:
            raise OSError(28, "No space left on device")
        self.seen.append((event, payload, threading.current_thread().name))

    def on_episodes(self, payload):
        self._record("on_episodes", payload)

    def on_checkpoint(self, payload):
        self._record("on_checkpoint", payload)


def test_events_are_written_in_order_on_the_writer_thread_and_wait_returns_when_all_are():
    log = Log(delay=0.01)
    writer = BackgroundListeners([log])
    for k in range(5):
        writer.on_episodes(k)
        writer.on_iteration(k)  # Log has no on_iteration: skipped
    writer.wait()
    assert [(event, payload) for event, payload, _ in log.seen] == [("on_episodes", k) for k in range(5)]
    assert {thread for _, _, thread in log.seen} == {"laplab-model-writer"}
    writer.close()
    writer.on_episodes(9)  # after close: written in the caller's thread
    assert log.seen[-1] == ("on_episodes", 9, threading.current_thread().name)


def test_prepare_runs_first_on_the_writer_thread_as_the_job_starts():
    class Prepared(Log):
        def prepare(self):
            time.sleep(0.05)  # e.g. compiling the simtrace renderer
            self.seen.append(("prepare", None, threading.current_thread().name))

    log = Prepared()
    writer = BackgroundListeners([log])
    writer.on_episodes(1)
    writer.close()
    assert [(event, thread) for event, _, thread in log.seen] == [("prepare", "laplab-model-writer"),
                                                                  ("on_episodes", "laplab-model-writer")]


def test_a_failed_write_drops_what_follows_and_is_raised_once_in_the_callers_thread():
    log = Log(fail_on=2)
    writer = BackgroundListeners([log])
    for k in range(4):
        writer.on_episodes(k)
    with pytest.raises(OSError, match="No space left"):
        writer.wait()
    assert [payload for _, payload, _ in log.seen] == [0, 1]  # 3 came after the failure: not written
    writer.wait()  # raised once: the job already ended with it
    writer.close()


def test_the_next_event_raises_a_failure_of_the_writer():
    log = Log(fail_on=0)
    writer = BackgroundListeners([log])
    writer.on_episodes(0)
    writer._tasks.join()
    with pytest.raises(OSError):
        writer.on_checkpoint(1)
    writer.close()


def test_at_most_max_pending_checkpoints_wait_to_be_written():
    release = threading.Event()

    class Blocked:
        def on_checkpoint(self, payload):
            release.wait(10)

    writer = BackgroundListeners([Blocked()])
    for k in range(MAX_PENDING_CHECKPOINTS):
        writer.on_checkpoint(k)
    third = threading.Thread(target=writer.on_checkpoint, args=(MAX_PENDING_CHECKPOINTS,))
    third.start()
    third.join(0.3)
    assert third.is_alive()  # it waits for a slot
    release.set()
    third.join(10)
    assert not third.is_alive()
    writer.close()


def test_a_checkpoint_holds_the_weights_of_when_it_was_made(tmp_path):
    trainer = create_training("snapshot", small_config(max_episodes=4))
    with trainer:
        learner = trainer.learner
        write = checkpoint_writer(learner, 1, 2, 3, None)
        write_resume = resume_writer(learner)
        before = {k: v.clone() for k, v in learner.weights_state()["model"].items()}
        with torch.no_grad():
            for parameter in learner.model.parameters():
                parameter.add_(1.0)  # training goes on while the checkpoint waits to be written
        write(tmp_path / "ckpt")
        write_resume(tmp_path / "resume")
    saved = load_checkpoint(tmp_path / "ckpt")["learner"]["model"]
    assert all(torch.equal(saved[k], before[k]) for k in before)


def test_the_files_are_complete_when_run_returns(monkeypatch):
    slow = ModelFolderRecorder.on_checkpoint

    def slow_checkpoint(self, checkpoint):  # a disk slower than the training
        time.sleep(0.3)
        slow(self, checkpoint)

    monkeypatch.setattr(ModelFolderRecorder, "on_checkpoint", slow_checkpoint)
    trainer = create_training("complete", small_config(max_episodes=12))
    with trainer:
        result = trainer.run()
        folder = model_folder("complete")
        last = CheckpointStore(folder).last()
        assert last.name.startswith(f"{result.iterations}_Step-{result.env_steps}")
        assert folder.list_training_iterations() == list(range(result.iterations))
        name, state = read_resume_state(folder)
        assert "optimizer" in state["learner"] and state["iteration"] == result.iterations
    assert trainer._listeners[0]._thread is None  # close() ended the writer thread


def test_a_failed_checkpoint_write_ends_the_job_and_keeps_the_last_complete_checkpoint(monkeypatch):
    save = CheckpointStore.save

    def full_disk_at_iteration_2(self, payload, *, iteration, **kwargs):
        if iteration == 2:
            raise OSError(28, "No space left on device")
        return save(self, payload, iteration=iteration, **kwargs)

    monkeypatch.setattr(CheckpointStore, "save", full_disk_at_iteration_2)
    trainer = create_training("full-disk", small_config(max_episodes=10**6))
    with pytest.raises(OSError, match="No space left"):
        with trainer:
            trainer.run()
    folder = model_folder("full-disk")
    store = CheckpointStore(folder)
    assert store.last().name.startswith("1_Step-") and store.names()[-1] == store.last().name
    name, state = read_resume_state(folder)  # the last complete checkpoint resumes
    assert name.startswith("1_Step-") and state["iteration"] == 1 and "optimizer" in state["learner"]
    take_lock(folder).release()  # the job ended: its lock is released
    assert trainer._listeners[0]._thread is None


@pytest.mark.skipif(not hasattr(os, "getpriority") or not os.path.exists("/proc/self/task"),
                    reason="thread priorities: Linux")
def test_the_writer_runs_at_a_lower_cpu_priority():
    seen = []

    class Nice:
        def on_episodes(self, _):
            seen.append(os.getpriority(os.PRIO_PROCESS, 0))  # 0: this thread, on Linux

    writer = BackgroundListeners([Nice()])
    writer.on_episodes(None)
    writer.close()
    assert seen == [min(os.getpriority(os.PRIO_PROCESS, 0) + WRITER_NICENESS, 19)]
