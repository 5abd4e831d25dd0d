"""Each console job gets its share of the cores for its camera learner's torch threads: the console
runs one job per two cores by default, and a camera job spends most of its time learning."""

from __future__ import annotations

import os
import subprocess
import sys

from laplab.console import service
from laplab.jobs.db import Job
from laplab.jobs.runner import LocalProcessRunner


def _job() -> Job:
    return Job(1, "train", "m", 1, "queued", 0.0, {}, 0.0, None, None, None, None, None, None)


def test_the_cores_are_shared_among_the_jobs_that_run_at_once(monkeypatch):
    monkeypatch.setattr(service.os, "cpu_count", lambda: 8)
    assert service.default_workers() == 4
    assert [service.threads_per_job(w) for w in (1, 2, 4, 16)] == [8, 4, 2, 1]


def test_a_job_learns_on_its_share_of_the_cores(monkeypatch, tmp_path):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    env = LocalProcessRunner(sandbox=False, threads_per_job=2).environment(_job())
    assert env["OMP_NUM_THREADS"] == "2"
    probe = ("import torch; from laplab.agents.torch_runtime import limit_torch_threads; limit_torch_threads(); "
             "print(torch.get_num_threads())")
    threads = subprocess.run([sys.executable, "-c", probe], env={**env, "PYTHONPATH": os.pathsep.join(sys.path)},
                             capture_output=True, text=True, timeout=120, check=True).stdout.split()[-1]
    assert int(threads) == min(2, len(os.sched_getaffinity(0)))


def test_the_servers_own_thread_setting_wins(monkeypatch, tmp_path):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert LocalProcessRunner(sandbox=False, threads_per_job=2).environment(_job())["OMP_NUM_THREADS"] == "1"


def test_the_console_gives_each_job_its_share(monkeypatch, tmp_path):
    from laplab.console.app import create_app
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    monkeypatch.setattr(service.os, "cpu_count", lambda: 4)
    app = create_app(None, sandbox=False, warm_cache=False)
    assert (app.state.service.workers, app.state.service.runner.threads_per_job) == (2, 2)
    app = create_app(4, sandbox=False, warm_cache=False)
    assert app.state.service.runner.threads_per_job == 1
