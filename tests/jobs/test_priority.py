"""Issue 34: evaluation jobs (evaluations, race submissions, head-to-model races) yield the CPU to
trainings: the console starts them ``--evaluation-priority`` nice levels below (default 10), on
their threads and their session's autogroup; trainings and exports keep the server's priority."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from laplab.cli import main
from laplab.errors import UserError
from laplab.jobs.confinement import JobLimits, bubblewrap_works
from laplab.jobs.db import Job
from laplab.jobs.priority import (
    DEFAULT_EVALUATION_PRIORITY,
    IDLE,
    job_priority,
    parse_priority,
)
from laplab.jobs.runner import LocalProcessRunner, job_folder

SERVER_NICE = os.getpriority(os.PRIO_PROCESS, 0)


def _job(job_id: int, kind: str, model: str = "car") -> Job:
    params = {"max_time_s": 60.0} if kind in ("train", "clone") else {}
    return Job(job_id, kind, model, 1, "queued", 0.0, params, 0.0, None, None, None, None, None, None)


def _nice(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[16])  # field 19: nice


def _autogroup(pid: int) -> str:
    path = Path(f"/proc/{pid}/autogroup")
    return path.read_text().split()[-1] if path.exists() else "absent"


@pytest.mark.parametrize("given, expected", [(10, 10), ("0", 0), (" 19 ", 19), ("IDLE", IDLE), ("idle", IDLE)])
def test_a_priority_is_a_niceness_or_idle(given, expected):
    assert parse_priority(given) == expected


@pytest.mark.parametrize("bad", ["-1", "20", "fast", "", 2.5, True, None, "10.0"])
def test_a_bad_priority_is_one_paragraph_naming_the_setting(bad):
    with pytest.raises(UserError) as caught:
        parse_priority(bad)
    assert caught.value.field == "--evaluation-priority"
    assert "--evaluation-priority" in str(caught.value) and "0 to 19" in str(caught.value) and "\n" not in str(caught.value)
    with pytest.raises(UserError, match="JobLimits.evaluation_priority"):
        JobLimits(evaluation_priority=bad)


def test_serve_refuses_a_bad_priority_before_it_starts(capsys):
    assert main(["serve", "--evaluation-priority", "25", "--port", "1"]) == 2
    err = capsys.readouterr().err
    assert "--evaluation-priority '25' is not a CPU priority" in err and "Traceback" not in err


def test_an_evaluation_runs_its_priority_below_the_server():
    assert job_priority(10, base_niceness=0) == 10
    assert job_priority(10, base_niceness=15) == 19  # a Ray worker (nice 15) reaches the ceiling
    assert job_priority(0, base_niceness=5) is None and job_priority(IDLE) == IDLE
    assert DEFAULT_EVALUATION_PRIORITY == JobLimits().evaluation_priority == JobLimits.console().evaluation_priority


def test_only_evaluation_kinds_are_lowered():
    runner = LocalProcessRunner(JobLimits.console(evaluation_priority=7), sandbox=False)
    priorities = {kind: runner._limits_for(_job(1, kind)).cpu_priority
                  for kind in ("train", "clone", "resume", "export", "evaluate", "duel")}
    assert priorities == {"train": None, "clone": None, "resume": None, "export": None,
                          "evaluate": min(19, SERVER_NICE + 7), "duel": min(19, SERVER_NICE + 7)}
    same = LocalProcessRunner(JobLimits.console(evaluation_priority=0), sandbox=False)
    assert same._limits_for(_job(1, "evaluate")).cpu_priority is None
    idle = LocalProcessRunner(JobLimits.console(evaluation_priority="idle"), sandbox=False)
    assert idle._limits_for(_job(1, "duel")).cpu_priority == IDLE


def _started_line(job_id: int, timeout_s: float = 60.0) -> str:
    log = job_folder(job_id) / "log.txt"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for line in (log.read_text() if log.exists() else "").splitlines():
            if line.startswith(f"laplab job {job_id}:"):
                return line
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} never logged its start: {log.read_text() if log.exists() else ''}")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="niceness in /proc")
@pytest.mark.parametrize("sandbox", [False, pytest.param(True, marks=pytest.mark.skipif(
    not bubblewrap_works(), reason="bubblewrap is missing"))])
def test_the_spawned_evaluation_runs_below_the_training(sandbox):
    runner = LocalProcessRunner(JobLimits.console(), sandbox=sandbox)
    lowered = min(19, SERVER_NICE + DEFAULT_EVALUATION_PRIORITY)
    jobs = {1: "train", 2: "evaluate", 3: "duel"}
    try:
        pids = {job_id: runner.start(_job(job_id, kind, f"m{job_id}")) for job_id, kind in jobs.items()}
        # set before exec: the process (bubblewrap, when sandboxed) and its session's group
        assert [_nice(pids[j]) for j in jobs] == [SERVER_NICE, lowered, lowered]
        groups = [_autogroup(pids[j]) for j in jobs]
        if groups[0] != "absent":
            assert groups == ["0", str(lowered), str(lowered)]
        # and what the job itself sees, inside the sandbox too (its log's first line)
        lines = {job_id: _started_line(job_id) for job_id in jobs}
        assert f"(CPU: nice {SERVER_NICE}" in lines[1], lines[1]
        assert f"(CPU: nice {lowered}" in lines[2] and f"(CPU: nice {lowered}" in lines[3], lines
        if groups[0] != "absent":
            assert lines[1].endswith("group: nice 0))") and lines[2].endswith(f"group: nice {lowered}))"), lines
    finally:
        for job_id in jobs:
            runner.kill(job_id)
        runner.shutdown(0.0)


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="Linux SCHED_IDLE")
def test_idle_runs_every_thread_with_sched_idle(tmp_path):
    probe = (
        "import os, threading, json\n"
        "from laplab.jobs.priority import apply_priority, describe_priority\n"
        "early = threading.Event(); done = threading.Event(); seen = {}\n"
        "def worker():\n"
        "    early.set(); done.wait(); seen['t'] = (os.getpriority(os.PRIO_PROCESS, 0), os.sched_getscheduler(0))\n"
        "t = threading.Thread(target=worker); t.start(); early.wait()\n"
        "apply_priority('idle'); apply_priority('idle'); done.set(); t.join()\n"
        "print(json.dumps({'main': [os.getpriority(os.PRIO_PROCESS, 0), os.sched_getscheduler(0)], "
        "'thread': seen['t'], 'idle': os.SCHED_IDLE, 'words': describe_priority()}))\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True,
                         start_new_session=True, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    facts = json.loads(out.stdout.strip().splitlines()[-1])
    assert facts["main"] == [19, facts["idle"]] and list(facts["thread"]) == [19, facts["idle"]]  # a thread started before too
    assert "SCHED_IDLE" in facts["words"]
