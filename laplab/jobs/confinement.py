"""How a job process is confined: resource limits, a clean environment, and (on Linux with
bubblewrap) a filesystem view without the console's database, secret key or other users' models.

Inside the sandbox ``$LAPLAB_HOME`` is ``/tmp/laplab``, on a fresh tmpfs holding only what the job needs:

    /tmp/laplab/job            the job's folder (spec, log, events, poses, result)       read-write
    /tmp/laplab/models/NAME    the model the job writes                                   read-write
    /tmp/laplab/models/SOURCE  the model a clone starts from                              read-only
    /tmp/laplab/models/RIVAL   a head-to-model race's opponent (its model: read-only too) read-only
    /tmp/laplab/tracks         imported tracks                                            read-only
    /tmp/laplab/cache          this owner's race-line cache (never shared between users)  read-write

The rest of the machine is read-only, ``/tmp`` is private, ``/root`` and ``/home`` are hidden except
for the Python installation, there is no network, a new PID namespace (no ``/proc`` of the server)
and no capabilities. One exception: a training job of a console started with ``--ray-address`` keeps
the machine's network (``Mounts.network``, bubblewrap's ``--share-net``) to reach the Ray cluster;
its filesystem view is the same. See docs/console.md for the threat model.
"""

from __future__ import annotations

import math
import os
import resource
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

from laplab.jobs.priority import DEFAULT_EVALUATION_PRIORITY, apply_priority, parse_priority
from laplab.reward.guards import die_with_parent

GIB = 1024 ** 3
# hidden behind empty tmpfs mounts inside the sandbox (code found under them is bound back read-only)
HIDDEN_DIRS = ("/tmp", "/var/tmp", "/dev/shm", "/root", "/home", "/run", "/var/run")
SANDBOX_HOME = "/tmp/laplab"  # on the private /tmp (bwrap can only make folders on a tmpfs)


def physical_memory_bytes() -> int | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def default_memory_limit() -> int | None:
    """75% of the machine's memory: a runaway job fails with MemoryError before the machine swaps."""
    total = physical_memory_bytes()
    return None if total is None else int(total * 0.75)


@dataclass(frozen=True)
class JobLimits:
    """What one job may use, on the command line (``laplab train``'s supervisor) and in the console alike.

    memory_bytes: address-space limit of the job process (RLIMIT_AS; None: unlimited).
    cpu_seconds: CPU-time limit of the job process, all threads (RLIMIT_CPU; None: unlimited).
    file_bytes: the largest file the job may write (RLIMIT_FSIZE; None: unlimited).
    reward_timeout_s: CPU seconds one step's reward calls may take (the reward watchdog).
    reward_wait_timeout_s: waking seconds one step's reward calls may take however little CPU
        they use (a call blocked in sleep or input).
    reward_output_lines: lines a reward function may print on the terminal (the job's log in the
        console); the rest goes to ``logs/reward-output.log`` in the model folder only.
    wall_margin_s: (console) wall-clock seconds a job may run past its own time budget before the
        server ends it (a job blocked in a sleep or on a lock uses no CPU).
    max_time_s: (console) the longest training a request may ask for (DeepRacer on AWS: 1440 min).
    cpu_priority: this job's CPU priority (:mod:`laplab.jobs.priority`): an absolute niceness 0..19,
        ``"idle"`` (SCHED_IDLE), or None (the parent's, as trainings run).
    evaluation_priority: (console) how far evaluation jobs (evaluate, race submissions, duels) run
        below trainings: a niceness 0..19 relative to theirs, or ``"idle"`` (``--evaluation-priority``).

    :meth:`console` gives the console's defaults (6 GiB, 4 h of CPU, 4 GiB files).
    """

    memory_bytes: int | None = field(default_factory=default_memory_limit)
    cpu_seconds: float | None = None
    file_bytes: int | None = None
    reward_timeout_s: float = 5.0
    reward_wait_timeout_s: float = 60.0
    reward_output_lines: int = 50
    wall_margin_s: float = 600.0
    max_time_s: float = 24 * 3600.0
    cpu_priority: int | str | None = None
    evaluation_priority: int | str = DEFAULT_EVALUATION_PRIORITY

    def __post_init__(self) -> None:
        if self.cpu_priority is not None:
            parse_priority(self.cpu_priority, "JobLimits.cpu_priority")
        parse_priority(self.evaluation_priority, "JobLimits.evaluation_priority")
        for name in ("memory_bytes", "cpu_seconds", "file_bytes"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ValueError(f"JobLimits.{name} must be positive or None, got {value!r}")
        for name in ("reward_timeout_s", "reward_wait_timeout_s", "wall_margin_s", "max_time_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"JobLimits.{name} must be a positive number of seconds, got {value!r}")
        if self.reward_output_lines < 0:
            raise ValueError(f"JobLimits.reward_output_lines must be >= 0, got {self.reward_output_lines!r}")

    @classmethod
    def console(cls, **overrides) -> "JobLimits":
        """The console's limits for one job: 6 GiB of address space, 4 h of CPU, 4 GiB files."""
        return cls(**{"memory_bytes": 6 * GIB, "cpu_seconds": 4 * 3600, "file_bytes": 4 * GIB, **overrides})


@dataclass(frozen=True)
class Mounts:
    """Real paths a job may see: read-write and read-only, each real path -> path inside; and
    ``network``: whether the job keeps the machine's network (only to reach a Ray cluster)."""

    writable: dict[str, str]
    readonly: dict[str, str]
    network: bool = False


@lru_cache(maxsize=1)
def bubblewrap_works() -> bool:
    """True when ``bwrap`` exists and can build the namespace this module uses (tested once)."""
    if sys.platform != "linux" or shutil.which("bwrap") is None:
        return False
    command = _bwrap_prefix(Mounts({}, {})) + ["/bin/true"]
    try:
        return subprocess.run(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, timeout=20).returncode == 0
    except (OSError, subprocess.SubprocessError):
        return False


def _python_dirs() -> list[str]:
    """Folders the interpreter and laplab load code from that the sandbox hides (a checkout under /tmp
    or a home folder): rebound read-only over the private tmpfs."""
    dirs = {sys.prefix, sys.base_prefix, str(Path(sys.executable).resolve().parent.parent)}
    dirs |= {p for p in sys.path if p and os.path.isdir(p)}
    import laplab
    dirs.add(str(Path(laplab.__file__).resolve().parent.parent))
    return sorted(d for d in dirs if d.startswith(HIDDEN_DIRS))


def _bwrap_prefix(mounts: Mounts) -> list[str]:
    cmd = ["bwrap", "--ro-bind", "/", "/", "--dev", "/dev", "--proc", "/proc", "--tmpfs", "/tmp",
           "--tmpfs", "/var/tmp", "--tmpfs", "/dev/shm", "--unshare-all", "--die-with-parent", "--cap-drop", "ALL"]
    if mounts.network:  # every namespace but the network's stays private (a Ray cluster's job only)
        cmd.append("--share-net")
    for hidden in ("/root", "/home", "/run", "/var/run"):
        if os.path.isdir(hidden) and not os.path.islink(hidden):
            cmd += ["--tmpfs", hidden]
    for folder in _python_dirs():
        cmd += ["--ro-bind", folder, folder]
    from laplab.jobs.db import laplab_home
    home = laplab_home()
    if home.exists():
        cmd += ["--tmpfs", str(home.resolve())]  # the real home (DB, secret, models) vanishes
    cmd += ["--tmpfs", SANDBOX_HOME, "--dir", f"{SANDBOX_HOME}/models"]
    for real, inside in mounts.readonly.items():
        cmd += ["--ro-bind", real, inside]
    for real, inside in mounts.writable.items():
        cmd += ["--bind", real, inside]
    return cmd


def clean_environment(extra: dict[str, str] | None = None, sandboxed: bool = True) -> dict[str, str]:
    """The only variables a job sees: no tokens, no keys, no server settings."""
    env = {"PATH": "/usr/local/bin:/usr/bin:/bin", "LANG": "C.UTF-8", "PYTHONUNBUFFERED": "1",
           "PYTHONDONTWRITEBYTECODE": "1", "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    pythonpath = os.environ.get("PYTHONPATH")
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    env["HOME"] = f"{SANDBOX_HOME}/job" if sandboxed else os.environ.get("HOME", "/tmp")
    env.update(extra or {})
    return env


def _lower(kind: int, value: float | None, hard_extra: int = 0) -> None:
    """Set ``kind``'s soft limit to ``value`` (never above the hard limit) and its hard limit to
    ``value + hard_extra``: a job cannot raise it again."""
    if value is None:
        return
    soft, hard = resource.getrlimit(kind)
    value = int(value) if hard == resource.RLIM_INFINITY else min(int(value), hard)
    value = max(value, 1)
    top = value + hard_extra if hard == resource.RLIM_INFINITY else min(value + hard_extra, hard)
    resource.setrlimit(kind, (value, top))


def apply_limits(limits: JobLimits) -> None:
    """In the job's process: the resource limits of ``limits`` (address space, CPU time with a 10 s
    grace from SIGXCPU to SIGKILL, file size, no core dumps), its CPU priority and death with its parent."""
    die_with_parent()
    apply_priority(limits.cpu_priority)
    _lower(resource.RLIMIT_AS, limits.memory_bytes)
    _lower(resource.RLIMIT_CPU, limits.cpu_seconds, 10)
    _lower(resource.RLIMIT_FSIZE, limits.file_bytes)
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


def limits_preexec(limits: JobLimits):
    """:func:`apply_limits` for ``subprocess.Popen(preexec_fn=...)``."""
    return lambda: apply_limits(limits)


def confined_command(command: list[str], mounts: Mounts, use_bubblewrap: bool | None = None) -> list[str]:
    """``command`` wrapped in bubblewrap with ``mounts`` (or unchanged when bubblewrap is off)."""
    if use_bubblewrap is None:
        use_bubblewrap = bubblewrap_works()
    if not use_bubblewrap:
        return command
    return _bwrap_prefix(mounts) + ["--chdir", f"{SANDBOX_HOME}/job", "--"] + command


def start_confined(command: list[str], mounts: Mounts, limits: JobLimits, log_path: Path,
                   env: dict[str, str], use_bubblewrap: bool | None = None) -> subprocess.Popen:
    """Start ``command`` confined, stdout and stderr appended to ``log_path``, in its own session."""
    if use_bubblewrap is None:
        use_bubblewrap = bubblewrap_works()
    with open(log_path, "ab") as log:
        return subprocess.Popen(confined_command(command, mounts, use_bubblewrap), stdin=subprocess.DEVNULL,
                                stdout=log, stderr=subprocess.STDOUT, env=env, close_fds=True,
                                start_new_session=True, preexec_fn=limits_preexec(limits),
                                cwd=None if use_bubblewrap else str(log_path.parent))
