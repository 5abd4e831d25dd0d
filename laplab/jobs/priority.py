"""CPU priority of console jobs: evaluations (evaluate jobs, race submissions, head-to-model races)
yield the CPU to trainings (``laplab serve --evaluation-priority``).

A priority is a niceness *relative to the trainings* (0..19: 0 runs evaluations as trainings run,
10 gives an evaluation about a tenth of a core's share against one training) or ``"idle"`` (Linux
SCHED_IDLE: the evaluation runs only on CPU time nothing else wants).

Linux puts each session in its own scheduling group when autogroups are on
(``/proc/sys/kernel/sched_autogroup_enabled``), and the console starts each job in its own session:
a niceness then weighs a job's threads only against each other, not against a training in another
session (measured: an evaluation at nice 10 still took half of a shared core). So a job's priority
is set twice: on every thread of its process (``setpriority`` / ``sched_setscheduler``: what counts
when autogroups are off or the jobs share a cgroup) and on its session's autogroup
(``/proc/self/autogroup``), which weighs the whole job against the other jobs. On a Ray node only the
threads are set: there the task shares its session with the node's raylet and every worker.
"""

from __future__ import annotations

import errno
import os
import time
from pathlib import Path

from laplab.errors import UserError

IDLE = "idle"
MAX_NICE = 19
DEFAULT_EVALUATION_PRIORITY = 10  # ~10 % of a core shared with a training (BENCHMARKS.md, session 19)
AUTOGROUP = Path("/proc/self/autogroup")

__all__ = ["DEFAULT_EVALUATION_PRIORITY", "IDLE", "apply_priority", "describe_priority", "job_priority",
           "parse_priority"]


def parse_priority(value, setting: str = "--evaluation-priority") -> int | str:
    """``value`` (``10``, ``"10"``, ``"idle"``) as a priority: an int 0..19 or ``"idle"``; anything
    else is a UserError naming ``setting``."""
    text = str(value).strip().lower()
    if text == IDLE:
        return IDLE
    try:
        nice = int(text) if not isinstance(value, (bool, float)) else None
    except ValueError:
        nice = None
    if nice is None or not 0 <= nice <= MAX_NICE:
        raise UserError(f"{setting} {value!r} is not a CPU priority: give a niceness from 0 to {MAX_NICE} that "
                        f"evaluation jobs (evaluations, race submissions, head-to-model races) run below the "
                        f"trainings (0: the same priority, {DEFAULT_EVALUATION_PRIORITY}: the default, about a tenth "
                        f"of a core against one training), or '{IDLE}' (Linux SCHED_IDLE: only CPU time nothing "
                        "else wants). A higher value keeps trainings at speed; evaluations then take longer on a "
                        "busy machine.", field=setting)
    return nice


def job_priority(relative: int | str, base_niceness: int | None = None) -> int | str | None:
    """The absolute priority of a job ``relative`` levels below a process at ``base_niceness``
    (default: this process's): a niceness (at most 19), ``"idle"``, or None (``relative`` 0: unchanged)."""
    relative = parse_priority(relative, "the job's CPU priority")
    if relative == IDLE:
        return IDLE
    if relative == 0:
        return None
    base = os.getpriority(os.PRIO_PROCESS, 0) if base_niceness is None else base_niceness
    return min(MAX_NICE, base + relative)


def _threads() -> list[int]:
    try:
        return [int(tid) for tid in os.listdir("/proc/self/task")]
    except OSError:
        return [0]  # no /proc: this thread only


def apply_priority(priority: int | str | None, autogroup: bool = True) -> None:
    """Run this process at ``priority`` (absolute: a niceness, ``"idle"``, None: leave it): every
    thread's niceness raised to it (never lowered), SCHED_IDLE for ``"idle"``, and, with ``autogroup``,
    its session's autogroup niceness (``"idle"``: 19). Idempotent: a second call changes nothing."""
    if priority is None:
        return
    nice = MAX_NICE if priority == IDLE else int(priority)
    for tid in _threads():
        try:
            if os.getpriority(os.PRIO_PROCESS, tid) < nice:
                os.setpriority(os.PRIO_PROCESS, tid, nice)
            if priority == IDLE and os.sched_getscheduler(tid) != os.SCHED_IDLE:
                os.sched_setscheduler(tid, os.SCHED_IDLE, os.sched_param(0))
        except (ProcessLookupError, PermissionError):  # a thread that ended meanwhile
            continue
    if autogroup:
        _set_autogroup_nice(nice)


def _autogroup_nice() -> int | None:
    try:
        return int(AUTOGROUP.read_text().split("nice")[-1])
    except (OSError, ValueError):
        return None  # autogroups off or absent (another kernel, another OS)


def _set_autogroup_nice(nice: int) -> None:
    current = _autogroup_nice()
    if current is None or current >= nice:
        return
    for _ in range(40):  # the kernel takes one autogroup change per 100 ms, machine-wide (EAGAIN meanwhile)
        try:
            AUTOGROUP.write_text(str(nice))
            return
        except OSError as exc:
            if exc.errno != errno.EAGAIN:
                return  # not allowed here (a sandbox's /proc): the threads' niceness still holds
            time.sleep(0.05)


def describe_priority() -> str:
    """This process's CPU priority in words, for a job's log: ``nice 10 (its session's group: nice 10)``."""
    words = f"nice {os.getpriority(os.PRIO_PROCESS, 0)}"
    if hasattr(os, "sched_getscheduler") and os.sched_getscheduler(0) == getattr(os, "SCHED_IDLE", None):
        words += ", SCHED_IDLE"
    group = _autogroup_nice()
    return words if group is None else f"{words} (its session's group: nice {group})"
