"""A rollout worker acts with the torch threads it was built for, in whichever thread calls it: Ray
may run an actor's methods in another thread than its ``__init__``, and torch's thread count is per
calling thread (with two threads, a STATE network acted 4x slower beside numba's pool)."""

from __future__ import annotations

import threading
from dataclasses import replace

import pytest

torch = pytest.importorskip("torch")

from laplab.cluster.launch import worker_setups  # noqa: E402
from laplab.cluster.worker import RolloutWorker, policy_weights  # noqa: E402
from laplab.env.vector import DEFAULT_REWARD  # noqa: E402
from laplab.train.config import TrainConfig  # noqa: E402
from laplab.train.trainer import build_learner  # noqa: E402


def test_collect_sets_the_workers_torch_threads_in_the_calling_thread():
    config = replace(TrainConfig(), track="oval", max_episodes=2,
                     hyperparameters={**TrainConfig().hyper().to_dict(), "num_episodes_between_training": 2})
    setup = worker_setups(config, DEFAULT_REWARD.read_text(), str(DEFAULT_REWARD), 1)[0]
    worker = RolloutWorker(setup)
    policy = policy_weights(build_learner(config, 0))
    seen, act = {"threads": set()}, worker.learner.act

    def spy(*args, **kwargs):
        seen["threads"].add(torch.get_num_threads())
        return act(*args, **kwargs)

    worker.learner.act = spy

    def call():
        torch.set_num_threads(2)  # what a fresh thread may start with
        seen["episodes"] = len(worker.collect(policy, 0, 0).batch.status)

    thread = threading.Thread(target=call)
    thread.start()
    thread.join(120)
    assert seen == {"threads": {1}, "episodes": 2}
    import sys
    assert "ray" not in sys.modules or not sys.modules["ray"].is_initialized()  # a plain object starts no Ray


def test_a_learner_without_a_thread_count_gets_the_processs_cores_whatever_came_before(monkeypatch):
    """A camera learner built after a one-thread vector learner in the same process (a notebook, a
    bench) gets its cores back; ``$OMP_NUM_THREADS`` still caps it (console jobs set 1)."""
    import os

    from laplab.agents.torch_runtime import limit_torch_threads
    cores = len(os.sched_getaffinity(0))
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    limit_torch_threads(1)
    limit_torch_threads(None)
    assert torch.get_num_threads() == cores
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    limit_torch_threads(None)
    assert torch.get_num_threads() == 1
