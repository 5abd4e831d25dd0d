"""Guards on the calls by which a reward function could end or cripple the process that runs it.

Installed by a supervised job (:mod:`laplab.jobs.sandbox`) and by the reward check's child process
(:mod:`laplab.reward.check_process`); they cost nothing per reward call and act only when the call
is made from the user's reward code (modules named ``laplab_user_reward_<n>``, see
:mod:`laplab.reward.watchdog`):

- ``os._exit(code)`` raises :class:`ExitCalled` (a SystemExit), which the reward loader reports as
  the usual RewardFunctionError with the line and params.
- ``os.close`` / ``os.dup2`` onto standard input, output or error, and ``close()`` of ``sys.stdout`` /
  ``sys.stderr``, raise :class:`StreamCloseCalled`: the job would lose its output (and its error
  messages) and die later without saying where.
- ``os.kill`` / ``os.killpg`` aimed at this process or its group, ``signal.raise_signal`` and
  ``os.abort`` (and ``posix._exit``, the way around ``os._exit``'s guard) go through (the process
  dies as asked), but first the hook set with
  :func:`on_self_signal` is told the file and line they were called from, so that whoever reports
  the death can name them.

:func:`die_with_parent` (Linux) makes a job, or the check's child, die with the process that
started it, so that killing that one with SIGKILL leaves no orphan running a reward function.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable

try:
    import posix
except ImportError:  # not a POSIX system: os._exit is nt._exit, guarded above
    posix = None

from laplab.reward.watchdog import is_user_frame

STANDARD_FDS = {0: "standard input", 1: "standard output", 2: "standard error"}
_hooks: dict[str, Callable[[str], None] | None] = {"self_signal": None}


class ExitCalled(SystemExit):
    """``os._exit(code)`` called by a reward function: the job cannot be ended from there."""

    def __str__(self) -> str:
        return f"os._exit({self.code}) was called; a reward function cannot end the job"


class StreamCloseCalled(SystemExit):
    """A reward function closed (or replaced) the process's standard input, output or error."""

    def __str__(self) -> str:
        return f"{self.code}; a reward function cannot close the job's terminal output"


def user_location(start: int = 2) -> str | None:
    """``"FILE, line N"`` of the innermost reward-function frame on the stack, or None."""
    frame = sys._getframe(start)
    while frame is not None:
        if is_user_frame(frame):
            return f"{frame.f_code.co_filename}, line {frame.f_lineno}"
        frame = frame.f_back
    return None


def on_self_signal(hook: Callable[[str], None] | None) -> None:
    """``hook("os.kill(PID, SIGKILL) at FILE, line N")`` runs just before a reward function signals
    (or aborts) its own process."""
    _hooks["self_signal"] = hook


def install_guards() -> None:
    """Wrap the calls listed in the module docstring (once per process; idempotent)."""
    if getattr(os._exit, "laplab_guard", False):
        return
    real_exit, real_close, real_dup2 = os._exit, os.close, os.dup2
    real_kill, real_killpg, real_raise, real_abort = os.kill, os.killpg, signal.raise_signal, os.abort

    def guarded_exit(code: int) -> None:
        if user_location() is not None:
            raise ExitCalled(code)
        real_exit(code)

    def guarded_close(fd: int) -> None:
        if fd in STANDARD_FDS and user_location() is not None:
            raise StreamCloseCalled(f"os.close({fd}) would close the {STANDARD_FDS[fd]}")
        real_close(fd)

    def guarded_dup2(fd: int, fd2: int, inheritable: bool = True) -> int:
        if fd2 in STANDARD_FDS and user_location() is not None:
            raise StreamCloseCalled(f"os.dup2({fd}, {fd2}) would replace the {STANDARD_FDS[fd2]}")
        return real_dup2(fd, fd2, inheritable)

    def announce(call: str) -> None:
        where, hook = user_location(3), _hooks["self_signal"]
        if where is not None and hook is not None:
            try:
                hook(f"{call} at {where}")
            except Exception:  # noqa: BLE001 - the report is best effort; the call goes on
                pass

    def guarded_kill(pid: int, sig: int) -> None:
        if pid in (0, os.getpid(), -os.getpgrp()) and _ends_process(sig):
            announce(f"os.kill({pid}, {_signal_name(sig)})")
        real_kill(pid, sig)

    def guarded_killpg(pgid: int, sig: int) -> None:
        if pgid in (0, os.getpgrp()) and _ends_process(sig):
            announce(f"os.killpg({pgid}, {_signal_name(sig)})")
        real_killpg(pgid, sig)

    def guarded_raise(sig: int) -> None:
        if _ends_process(sig):
            announce(f"signal.raise_signal({_signal_name(sig)})")
        real_raise(sig)

    def guarded_abort() -> None:
        announce("os.abort()")
        real_abort()

    def announced_exit(code: int) -> None:  # posix._exit, the way around os._exit's guard
        announce(f"posix._exit({code})")
        real_exit(code)

    for module, name, wrapper in ((os, "_exit", guarded_exit), (os, "close", guarded_close),
                                  (os, "dup2", guarded_dup2), (os, "kill", guarded_kill),
                                  (os, "killpg", guarded_killpg), (signal, "raise_signal", guarded_raise),
                                  (os, "abort", guarded_abort), (posix, "_exit", announced_exit)):
        if module is None:
            continue
        wrapper.laplab_guard = True
        setattr(module, name, wrapper)


def die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when the process that started it ends (no-op elsewhere)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        parent = os.getppid()
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG
        if os.getppid() != parent:  # the supervisor died before prctl took effect
            os._exit(1)
    except (OSError, AttributeError):
        pass


_NOT_ENDING = ("SIGCHLD", "SIGURG", "SIGWINCH", "SIGCONT", "SIGSTOP", "SIGTSTP", "SIGTTIN", "SIGTTOU")
_IGNORED_BY_DEFAULT = {getattr(signal, name) for name in _NOT_ENDING if hasattr(signal, name)}


def _ends_process(sig: int) -> bool:
    """Whether ``sig`` ends this process: SIGKILL, or a signal left to its default action that
    terminates (a signal with a Python handler, such as the stop flag's SIGTERM, does not; nor do
    those whose default is to be ignored or to stop the process)."""
    if sig == getattr(signal, "SIGKILL", None):
        return True
    if not sig or sig in _IGNORED_BY_DEFAULT:
        return False
    try:
        return signal.getsignal(sig) == signal.SIG_DFL
    except (ValueError, OSError):
        return False


def _signal_name(sig: int) -> str:
    try:
        return signal.Signals(sig).name
    except ValueError:
        return str(sig)
