"""Console jobs get the protections of CLI jobs (laplab.jobs.supervisor): the per-step reward
watchdog, the os._exit guard and the reward output cap, through the same JobLimits and the same
child-process set-up (laplab.jobs.confinement). Real servers, real confined worker processes."""

from __future__ import annotations

import time

from laplab.jobs.confinement import JobLimits

TINY = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}
# the validation sweep runs in a forked child of the job (multiprocessing's), which must pass: the
# counters count the calls of the job's own process, its training, from the first
SLEEPER = ("import multiprocessing\n"
           "import time\n"
           "CALLS = [0]\n"
           "def reward_function(params):\n"
           "    if multiprocessing.parent_process() is None:\n"
           "        CALLS[0] += 1\n"
           "    if CALLS[0] > 20:\n"
           "        time.sleep(10 ** 6)\n"
           "    return 1.0\n")

PRINTER_THEN_EXIT = ("import multiprocessing\n"
                     "import os\n"
                     "CALLS = [0]\n"
                     "def reward_function(params):\n"
                     "    if multiprocessing.parent_process() is None:\n"
                     "        CALLS[0] += 1\n"
                     "    if CALLS[0] > 0:\n"
                     "        print('reward call', CALLS[0])\n"
                     "    if CALLS[0] > 300:\n"
                     "        os._exit(3)\n"
                     "    return 1.0\n")


def test_a_sleeping_reward_is_stopped_by_the_step_watchdog_and_os_exit_is_caught(tmp_path, serve_console):
    # the wall-clock watchdog would wait 600 + 600 s: only the per-step reward watchdog ends this in time
    limits = JobLimits.console(reward_wait_timeout_s=3.0, reward_output_lines=20)
    with serve_console(tmp_path, workers=2, limits=limits) as console:
        for name, source in (("sleeper", SLEEPER), ("quitter", PRINTER_THEN_EXIT)):
            created = console.admin.post("/api/models", json={"name": name, "reward_function": source,
                                                              "max_time_s": 600, "hyperparameters": TINY})
            assert created.status_code == 201, created.text
        started = time.monotonic()
        sleeper = console.wait_for(console.admin, "sleeper", ("failed", "ready"), timeout_s=240)
        assert time.monotonic() - started < 240
        assert sleeper["status"] == "failed", sleeper
        error = sleeper["error"]
        assert "wall-clock" not in error and "3 s" in error and "line 8" in error, error
        assert "Traceback" not in error
        # no paths of the server or of the sandbox
        assert str(tmp_path) not in error and "/tmp/laplab" not in error and "reward_function.py" in error

        quitter = console.wait_for(console.admin, "quitter", ("failed", "ready"), timeout_s=240)
        assert quitter["status"] == "failed", quitter
        assert "os._exit(3)" in quitter["error"] and "line 10" in quitter["error"], quitter["error"]
        assert str(tmp_path) not in quitter["error"] and "/tmp/laplab" not in quitter["error"]
        job_log = (tmp_path / "jobs" / str(quitter["job"]["id"]) / "log.txt").read_text()
        shown = job_log.count("reward call")
        assert 0 < shown <= 21, shown  # the cap (the notice line counts no call)
        assert "printed more than 20 lines" in job_log
        kept = (tmp_path / "models" / "quitter" / "logs" / "reward-output.log").read_text()
        assert kept.count("reward call") >= 300
