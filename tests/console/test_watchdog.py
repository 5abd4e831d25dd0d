"""The wall-clock watchdog: a job blocked without using CPU (a reward function asleep, or waiting
on a lock) is ended at its wall-clock limit with a clear error on the model's page; the server and
other jobs go on."""

from __future__ import annotations

from laplab.jobs.confinement import JobLimits
from laplab.jobs.db import Job
from laplab.jobs.runner import wall_limit_s

TINY = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}
# the validation sweep runs in a forked child of the job (multiprocessing's), which must pass; the job's
# own process sleeps in its 21st training call
SLEEPER = ("import multiprocessing\n"
           "import time\n"
           "CALLS = [0]\n"
           "def reward_function(params):\n"
           "    if multiprocessing.parent_process() is None:\n"
           "        CALLS[0] += 1\n"
           "    if CALLS[0] > 20:\n"
           "        time.sleep(10 ** 6)\n"
           "    return 1.0\n")


def _job(kind: str, **params) -> Job:
    return Job(1, kind, "m", 1, "queued", 0.0, params, 0.0, None, None, None, None, None, None)


def test_each_job_gets_a_wall_limit_from_its_own_budget():
    assert wall_limit_s(_job("train", max_time_s=600), 300) == 900
    assert wall_limit_s(_job("evaluate", trials=2, max_trial_time=100), 60) == 260
    assert wall_limit_s(_job("export", format="car"), 60) == 60
    assert wall_limit_s(_job("train", max_time_s=600, wall_limit_s=5), 300) == 5
    assert wall_limit_s(_job("resume"), 300) == float("inf")


# the job's budget (3 s) + this margin: long enough for a confined job to start and reach training on a
# loaded 2-core machine (~10 s), short enough not to idle the suite
WALL_MARGIN_S = 25


def test_a_job_that_sleeps_forever_is_ended_at_its_wall_clock_limit(tmp_path, serve_console):
    with serve_console(tmp_path, workers=1, limits=JobLimits.console(wall_margin_s=WALL_MARGIN_S)) as console:
        created = console.admin.post("/api/models", json={"name": "sleeper", "reward_function": SLEEPER,
                                                          "max_time_s": 3, "hyperparameters": TINY})
        assert created.status_code == 201, created.text
        model = console.wait_for(console.admin, "sleeper", ("failed", "ready"), timeout_s=240)
        assert model["status"] == "failed", model
        limit = 3 + WALL_MARGIN_S
        assert "wall-clock limit" in model["error"] and f"{limit} s" in model["error"], model["error"]
        job = model["job"]
        assert limit <= job["finished"] - job["started"] < limit + 60, job
        events = (tmp_path / "jobs" / str(job["id"]) / "events.jsonl").read_text()
        assert '"started"' in events  # it was training (asleep in its reward), not still starting up
        assert console.admin.get("/api/health").status_code == 200
