"""A graceful server stop marks running jobs `interrupted` (resumable), and their resume gets only
the time they had left. Real servers over one $LAPLAB_HOME, real training jobs."""

from __future__ import annotations

import json
import time

from laplab.jobs.db import JobStore

TINY = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}
BUDGET_S = 300


def _last_time_left(home, job_id: int) -> float:
    left = None
    for line in (home / "jobs" / str(job_id) / "events.jsonl").read_text().splitlines():
        event = json.loads(line)
        if event["type"] == "iteration":
            left = event["report"]["time_left_s"]
    return left


def test_a_server_stop_interrupts_jobs_and_resume_grants_the_time_left(tmp_path, serve_console):
    with serve_console(tmp_path, workers=1) as console:
        created = console.admin.post("/api/models", json={"name": "stopped-by-server", "max_time_s": BUDGET_S,
                                                          "hyperparameters": TINY})
        assert created.status_code == 201, created.text
        job_id = created.json()["job"]["id"]
        deadline = time.monotonic() + 240
        while not console.admin.get("/api/models/stopped-by-server").json()["iterations"]:
            assert time.monotonic() < deadline, "no iteration within 240 s"
            time.sleep(0.2)
    store = JobStore(tmp_path / "laplab.db")
    try:
        job = store.job(job_id)
    finally:
        store.close()
    assert job.status == "interrupted", job
    assert "resume" in job.error and "\n" not in job.error
    left = _last_time_left(tmp_path, job_id)
    assert left is not None and 0 < left < BUDGET_S

    with serve_console(tmp_path, workers=1) as console:
        model = console.admin.get("/api/models/stopped-by-server").json()
        assert model["status"] == "interrupted", model["status"]
        resumed = console.admin.post("/api/models/stopped-by-server/resume", json={})
        assert resumed.status_code == 202, resumed.text
        granted = console.app.state.store.job(resumed.json()["job"]["id"]).params["max_time_s"]
        assert abs(granted - left) < 1e-6, (granted, left)  # not the whole budget again
        console.admin.post("/api/models/stopped-by-server/stop")


def test_jobs_share_the_grace_period_of_a_server_stop(tmp_path, monkeypatch):
    """Jobs that ignore the stop request (e.g. still starting up) are killed ``grace_s`` after it, all
    together: a server with three of them stops in one grace period, not three."""
    import subprocess
    import sys

    from laplab.jobs.runner import LocalProcessRunner
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    runner = LocalProcessRunner(sandbox=False)
    deaf = [subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"], start_new_session=True)
            for _ in range(3)]
    runner._processes.update(enumerate(deaf, start=1))
    started = time.monotonic()
    runner.shutdown(grace_s=2.0)
    took = time.monotonic() - started
    assert all(process.returncode == -9 for process in deaf), [p.returncode for p in deaf]
    assert 2.0 <= took < 5.0, took  # one by one, they took 3 x 2 s
