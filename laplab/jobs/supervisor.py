"""Run a job (training, evaluation) in a child process under a small supervisor.

The supervisor waits for the child and, whatever way it dies (an exit code it did not report, a
signal, the out-of-memory killer, its CPU limit), writes ``error.txt`` in the job's model folder,
prints one paragraph saying what died, at which iteration and, when known, in which line of the
reward function, and returns a non-zero exit code. The child runs under the :class:`JobLimits`
of :mod:`laplab.jobs.confinement` (the console's jobs use the same class and the same
:func:`~laplab.jobs.confinement.apply_limits`): ``RLIMIT_AS`` (memory), ``RLIMIT_CPU`` and
``RLIMIT_FSIZE`` set in the child, the reward watchdog's time limit, and a cap on what the reward
function prints on the terminal.

Library use (the console runs its jobs this way)::

    outcome = run_supervised(["train", "--name", "m1", "--max-time", "10m"], JobLimits(memory_bytes=4 << 30))
    outcome.exit_code, outcome.message, outcome.iteration

``job`` is either the argv of a ``laplab`` command (run with ``python -m laplab.cli`` in a fresh
interpreter: safe from a threaded server) or a callable returning an exit code (run in a forked
child: what the ``laplab`` command line does, at no start-up cost). A job reports to its supervisor
through :func:`report` (its model folder once it holds the folder's lock, each finished iteration,
its exit code); a job that exits without reporting its exit code did not end on its own.
"""

from __future__ import annotations

import json
import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from laplab.jobs.confinement import JobLimits, apply_limits, default_memory_limit, physical_memory_bytes  # noqa: F401
from laplab.jobs.diagnosis import describe_death

ENV_LIMITS = "LAPLAB_JOB_LIMITS"  # JSON of JobLimits + the status fd and crash-log path, for an exec'ed child
ENV_DISABLE = "LAPLAB_SUPERVISOR"  # "0": the command line runs jobs in its own process (no supervisor)


def parse_memory_limit(text: str) -> int | None:
    """``4G``, ``512M``, ``50%`` (of the machine's memory) or ``none`` -> bytes (None: unlimited)."""
    value = str(text).strip().lower()
    if value in ("none", "unlimited", "0"):
        return None
    match = re.fullmatch(r"([0-9]*\.?[0-9]+)\s*(%|[kmgt]i?b?|b)?", value)
    if match is None:
        raise ValueError(f"memory limit {text!r}: expected a size such as 4G, 512M, 50% (of this machine's "
                         "memory) or none")
    number, unit = float(match.group(1)), (match.group(2) or "b")
    if unit == "%":
        total = physical_memory_bytes()
        if total is None or not 0 < number <= 100:
            raise ValueError(f"memory limit {text!r}: a percentage must be in (0, 100] on a machine whose memory "
                             "size is known")
        return int(total * number / 100)
    size = int(number * 1024 ** "bkmgt".index(unit[0]))
    if size < 256 << 20:
        raise ValueError(f"memory limit {text!r} is below 256 MiB: no training job fits in it")
    return size


@dataclass(frozen=True)
class JobOutcome:
    """How a supervised job ended.

    exit_code: what the command should exit with (the job's own code when it ended on its own,
    else non-zero). clean: the job ended on its own (its messages were printed, its files written).
    message: the supervisor's paragraph when it did not (also in error.txt when folder is known).
    returncode / signal: the child's exit status or the signal that killed it. iteration: the last
    iteration the job reported. max_rss_bytes: the child's peak resident memory.
    """

    exit_code: int
    clean: bool
    message: str | None
    returncode: int | None
    signal: int | None
    folder: Path | None
    iteration: int | None
    max_rss_bytes: int | None
    reports: dict = field(default_factory=dict)


# -- the child's side ---------------------------------------------------------------------------

_child: dict = {"status_fd": None, "limits": None}


def in_job() -> bool:
    """Whether this process is a supervised job."""
    return _child["limits"] is not None


def job_limits() -> JobLimits:
    """The limits of this job (the defaults when not supervised)."""
    return _child["limits"] or JobLimits()


def report(**fields) -> None:
    """Tell the supervisor something (``folder=``, ``model=``, ``what=``, ``iteration=``, ``exit=``);
    a no-op when not supervised. One JSON line per call on the status pipe."""
    if "folder" in fields:
        from laplab.jobs.sandbox import set_output_folder
        _child["folder"] = fields["folder"]
        if in_job():
            set_output_folder(fields["folder"])
    fd = _child["status_fd"]
    if fd is None:
        return
    try:
        os.write(fd, (json.dumps(fields, default=str) + "\n").encode())
    except OSError:
        pass


def job_failed(message: str) -> None:
    """Record ``message`` in error.txt of the folder this job reported (if any)."""
    folder = _child.get("folder")
    if folder and Path(folder).is_dir():
        from laplab.store.layout import ModelFolder
        try:
            ModelFolder(folder).write_error(message)
        except OSError:
            pass


def enter_job(limits: JobLimits, status_fd: int | None, crash_log: str | None) -> None:
    """Set up this process as a supervised job: limits, death with the supervisor, crash log, guards."""
    import faulthandler

    from laplab.jobs import sandbox
    _child["limits"], _child["status_fd"] = limits, status_fd
    apply_limits(limits)  # the same limits as a console job's (laplab.jobs.confinement)
    if crash_log:
        handle = open(crash_log, "w")  # noqa: SIM115 - kept open for faulthandler until the process ends
        _child["crash_log"] = handle
        faulthandler.enable(handle, all_threads=False)
    sandbox.guard_exit_calls(lambda where: report(reward_call=where))
    sandbox.cap_reward_output(limits.reward_output_lines)


def enter_job_from_environment() -> bool:
    """In an exec'ed child (``python -m laplab.cli`` started by :func:`run_supervised`), read the
    limits from the environment and enter the job. Returns whether it did."""
    text = os.environ.pop(ENV_LIMITS, None)
    if not text:
        return False
    data = json.loads(text)
    status_fd, crash_log = data.pop("status_fd"), data.pop("crash_log")
    enter_job(JobLimits(**data), status_fd, crash_log)
    return True


# -- the supervisor's side ----------------------------------------------------------------------


class _Child:
    """A started job: its pid, the read end of its status pipe, and what it reported."""

    def __init__(self, pid: int, status_read: int, popen: subprocess.Popen | None):
        self.pid, self.status_read, self.popen = pid, status_read, popen
        self.reports: dict = {}
        self._buffer = b""
        self.closed = False

    def read_reports(self, timeout: float) -> None:
        if self.closed:
            time.sleep(timeout)
            return
        ready, _, _ = select.select([self.status_read], [], [], timeout)
        if not ready:
            return
        try:
            chunk = os.read(self.status_read, 65536)
        except OSError:
            chunk = b""
        if not chunk:
            if not self.closed and timeout:
                time.sleep(timeout)  # the child closed its end: it is ending, poll its status
            self.closed = True
            return
        self._buffer += chunk
        *lines, self._buffer = self._buffer.split(b"\n")
        for line in lines:
            try:
                self.reports.update(json.loads(line))
            except ValueError:
                continue


    def drain(self) -> None:
        """Read what is left after the child ended (its end of the pipe is closed: EOF comes)."""
        for _ in range(10000):
            if self.closed or not select.select([self.status_read], [], [], 0)[0]:
                return
            self.read_reports(0.0)


def _start_fork(job: Callable[[], int], limits: JobLimits, crash_log: str) -> _Child:
    status_read, status_write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the job
        code = 1
        try:
            os.close(status_read)
            enter_job(limits, status_write, crash_log)
            code = int(job() or 0)
            report(exit=code)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
            report(exit=code)
        except BaseException:  # noqa: BLE001 - a traceback here is a bug; the supervisor reports the exit
            import traceback
            traceback.print_exc()
        finally:
            try:
                sys.stdout.flush()
                sys.stderr.flush()
            finally:
                os._exit(code)
    os.close(status_write)
    return _Child(pid, status_read, None)


def _start_exec(argv: Sequence[str], limits: JobLimits, crash_log: str, env: dict | None) -> _Child:
    status_read, status_write = os.pipe()
    if env is None:  # this process's environment, with the settings in force (laplab.settings)
        from laplab.settings import current_settings
        env = current_settings().child_environment()
    environment = dict(env)
    environment[ENV_LIMITS] = json.dumps({**asdict(limits), "status_fd": status_write, "crash_log": crash_log})
    popen = subprocess.Popen([sys.executable, "-m", "laplab.cli", *argv], env=environment, pass_fds=(status_write,))
    os.close(status_write)
    return _Child(popen.pid, status_read, popen)


class _Signals:
    """In the main thread: SIGTERM/SIGHUP to the supervisor stop the job (SIGTERM to the child); SIGINT
    is forwarded unless the terminal already sent it to the whole foreground process group."""

    def __init__(self, child: _Child):
        self.child, self.previous = child, {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                self.previous[sig] = signal.signal(sig, self._forward)
        return self

    def _forward(self, signum, frame):
        if signum == signal.SIGINT and _terminal_sent_it():
            return
        try:
            os.kill(self.child.pid, signal.SIGINT if signum == signal.SIGINT else signal.SIGTERM)
        except ProcessLookupError:
            pass

    def __exit__(self, *exc):
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)


def _terminal_sent_it() -> bool:
    try:
        return os.isatty(0) and os.tcgetpgrp(0) == os.getpgrp()
    except OSError:
        return False


def run_supervised(job: Sequence[str] | Callable[[], int], limits: JobLimits | None = None, *,
                   what: str = "job", should_stop: Callable[[], bool] | None = None,
                   stop_grace_s: float = 120.0, env: dict | None = None, echo: bool = True) -> JobOutcome:
    """Run ``job`` in a child process under ``limits`` and return how it ended (see the module docstring).

    what: how the message names the job ("the training job", "the evaluation"). should_stop: polled
    five times a second (from any thread); when it returns True the child gets SIGTERM (a job stops
    cleanly and keeps its model), then SIGKILL after ``stop_grace_s``. env: the environment of an
    argv job (default: this process's). echo: print the supervisor's paragraph on stderr.
    """
    limits = limits if limits is not None else JobLimits()
    crash_fd, crash_log = tempfile.mkstemp(prefix="laplab-job-", suffix=".crash.txt")
    os.close(crash_fd)
    child = _start_fork(job, limits, crash_log) if callable(job) else _start_exec(job, limits, crash_log, env)
    stop_sent = None
    try:
        with _Signals(child):
            while True:
                child.read_reports(0.2)
                pid, status, usage = os.wait4(child.pid, os.WNOHANG)
                if pid:
                    break
                if should_stop is not None and stop_sent is None and should_stop():
                    stop_sent = time.monotonic()
                    _kill(child.pid, signal.SIGTERM)
                elif stop_sent is not None and time.monotonic() - stop_sent > stop_grace_s:
                    _kill(child.pid, signal.SIGKILL)
        child.drain()  # what the child wrote just before it ended
        crash = Path(crash_log).read_text(errors="replace") if os.path.exists(crash_log) else ""
    finally:
        os.close(child.status_read)
        Path(crash_log).unlink(missing_ok=True)
    if child.popen is not None:
        child.popen.returncode = os.waitstatus_to_exitcode(status)  # reaped here; keep Popen quiet
    return _outcome(child.reports, status, usage, crash, limits, what, echo)


def _kill(pid: int, sig: int) -> None:
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        pass


def _outcome(reports: dict, status: int, usage, crash: str, limits: JobLimits, what: str, echo: bool) -> JobOutcome:
    signum = os.WTERMSIG(status) if os.WIFSIGNALED(status) else None
    returncode = os.WEXITSTATUS(status) if os.WIFEXITED(status) else None
    folder = Path(reports["folder"]) if reports.get("folder") else None
    iteration = reports.get("iteration")
    max_rss = usage.ru_maxrss * (1 if sys.platform == "darwin" else 1024)
    common = dict(returncode=returncode, signal=signum, folder=folder, iteration=iteration,
                  max_rss_bytes=max_rss, reports=reports)
    if returncode is not None and reports.get("exit") == returncode:
        return JobOutcome(exit_code=returncode, clean=True, message=None, **common)
    message = describe_death(reports, returncode, signum, crash, limits, max_rss, what)
    if folder is not None:
        _write_error(folder, message)
    if echo:
        print(f"laplab: {message}", file=sys.stderr, flush=True)
    exit_code = 128 + signum if signum is not None else (returncode or 1)
    return JobOutcome(exit_code=exit_code, clean=False, message=message, **common)


def _write_error(folder: Path, message: str) -> None:
    """error.txt in the job's folder, unless another job has taken the folder meanwhile."""
    from laplab.store.layout import ModelFolder
    from laplab.store.lock import ModelBusyError, ModelLock
    if not folder.is_dir():
        return
    try:
        with ModelLock(folder):
            ModelFolder(folder).write_error(message)
    except (ModelBusyError, OSError):
        pass


def supervision_enabled() -> bool:
    return os.environ.get(ENV_DISABLE, "1") != "0" and hasattr(os, "fork") and not in_job()
