"""How a console job ended, in words: the paragraph for a job that died without writing its result,
and what an interrupted training had left of its max time (for its resume)."""

from __future__ import annotations

import json
import re

from laplab.jobs.db import Job
from laplab.jobs.runner import job_folder

TRAIN_KINDS = ("train", "clone", "resume")

INTERRUPTED_BY_SHUTDOWN = ("the server stopped while this job ran; it kept its last checkpoint: resume it to "
                           "continue with the time it had left")


def time_left_s(job: Job) -> float | None:
    """What an interrupted training job had left of its max time at its last checkpoint (the trainer's
    ``time_left_s`` of its last iteration; its whole budget before its first), or None when unknown."""
    budget = job.params.get("max_time_s")
    left = float(budget) if budget else None
    try:
        with open(job_folder(job.id) / "events.jsonl", encoding="utf-8", errors="replace") as events:
            for line in events:
                if line.startswith('{"type": "iteration"'):
                    left = float(json.loads(line)["report"]["time_left_s"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return left


def death_reason(job: Job, returncode: int, limits) -> str:
    """The paragraph of the CLI's supervisor (:func:`laplab.jobs.diagnosis.describe_death`) for a job
    that ended without writing its result: how it died, its last iteration, the reward function's line
    from the job's crash log; no server paths."""
    import signal

    from laplab.jobs.confinement import JobLimits
    from laplab.jobs.diagnosis import describe_death
    from laplab.jobs.runner import CRASH_LOG
    folder = job_folder(job.id)
    number = -returncode if returncode < 0 else returncode - 128 if 128 < returncode < 160 else None
    if number is not None and number not in signal.Signals._value2member_map_:
        number = None
    iteration = None
    try:
        for line in (folder / "events.jsonl").read_text(errors="replace").splitlines():
            if '"iteration"' in line and '"report"' in line:
                iteration = json.loads(line)["report"].get("iteration", iteration)
    except (OSError, ValueError, KeyError):
        pass
    try:
        crash = (folder / CRASH_LOG).read_text(errors="replace")
    except OSError:
        crash = ""
    reports = {"model": job.model, "what": "training job" if job.kind in TRAIN_KINDS else f"{job.kind} job"}
    if iteration is not None:
        reports["iteration"] = iteration
    message = describe_death(reports, None if number is not None else returncode, number, crash,
                             limits or JobLimits.console(), None, "job")
    return message.replace(" (--cpu-limit)", "") + " The model keeps its last checkpoint."


def without_paths(message: str | None) -> str | None:
    """A job's error as its page shows it: the reward function named ``reward_function.py`` (not the
    sandbox's or the server's path to it), the console's folder as ``$LAPLAB_HOME``."""
    if not message:
        return message
    from laplab.jobs.db import laplab_home
    message = re.sub(r"[^\s'\"(]*/reward_function\.py", "reward_function.py", message)
    return message.replace(str(laplab_home()), "$LAPLAB_HOME")
