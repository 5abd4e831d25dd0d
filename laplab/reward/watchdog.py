"""A time limit on the reward calls of a running job, at no cost per call.

:class:`RewardWatchdog` is a background thread that samples the main thread's stack a few times a
second. A *batch of reward calls* is the frame that calls into the reward function (one simulator
step calls it once per car from the same frame). When the same batch frame has been on the stack
for more than ``timeout_s`` seconds of the main thread's CPU time, or ``wait_timeout_s`` seconds of
waking time (a call blocked in ``sleep`` or ``input`` uses no CPU), the watchdog interrupts the
main thread with a signal whose handler raises :class:`RewardTimeout` inside the user's code.
:class:`~laplab.reward.loader.RewardFunction` turns it into the usual
:class:`~laplab.reward.errors.RewardFunctionError` naming the file, the line it was busy on and the
params of the call. A bare ``except:`` that swallows it is traced line by line, as in
:mod:`laplab.reward.timeout`. Time the process spends stopped (Ctrl-Z) is not counted.

Reward code is recognised by its module name: :mod:`laplab.reward.loader` names every user
module ``laplab_user_reward_<n>``.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from dataclasses import dataclass

USER_MODULE_PREFIX = "laplab_user_reward_"
TIMEOUT_SIGNAL = signal.SIGUSR1
_REPEAT_S = 0.05  # re-signal period while the user's code swallows the timeout


class RewardTimeout(BaseException):
    """Raised in the reward function when its batch of calls ran out of time (a BaseException, so
    ``except Exception`` in user code misses it). ``seconds`` is the limit, ``busy_line`` the user's
    line when time ran out, ``what`` says which limit (CPU or waiting)."""

    def __init__(self, seconds: float, busy_line: int | None, what: str):
        super().__init__(f"the reward calls of one step ran for more than {seconds:g} s of {what}")
        self.seconds, self.busy_line, self.what = seconds, busy_line, what


def is_user_frame(frame) -> bool:
    return frame.f_globals.get("__name__", "").startswith(USER_MODULE_PREFIX)


def _frames(frame):
    while frame is not None:
        yield frame
        frame = frame.f_back


def _batch_frame(frame):
    """The frame that called into the reward function (below its outermost user and loader frames)."""
    outermost_user = None
    for f in _frames(frame):
        if is_user_frame(f):
            outermost_user = f
    if outermost_user is None:
        return None
    for f in _frames(outermost_user.f_back):
        if not f.f_code.co_filename.endswith(("loader.py", "watchdog.py")):
            return f
    return None


@dataclass(frozen=True)
class WatchdogLimits:
    """timeout_s: CPU seconds (of the job's main thread) one batch of reward calls may use;
    wait_timeout_s: waking seconds it may take however little CPU it uses (blocked calls)."""

    timeout_s: float = 5.0
    wait_timeout_s: float = 60.0

    def __post_init__(self) -> None:
        for name in ("timeout_s", "wait_timeout_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")


class RewardWatchdog:
    """``with RewardWatchdog(limits):`` around a job's loop, in the main thread of the process."""

    def __init__(self, limits: WatchdogLimits = WatchdogLimits()):
        self.limits = limits
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._expired: tuple[object, float, str] | None = None  # (batch frame, limit, what)
        self._fires = 0
        self._previous_handler = None
        self._previous_trace = None
        self.tick_s = min(0.25, limits.timeout_s / 10, limits.wait_timeout_s / 10)

    # -- main thread -----------------------------------------------------------------------------

    def __enter__(self) -> "RewardWatchdog":
        if threading.current_thread() is not threading.main_thread() or not hasattr(time, "pthread_getcpuclockid"):
            return self  # no signals off the main thread: the job runs unwatched (the supervisor still limits it)
        self._main_ident = threading.main_thread().ident
        self._clock = time.pthread_getcpuclockid(self._main_ident)
        self._previous_handler = signal.signal(TIMEOUT_SIGNAL, self._on_signal)
        self._previous_trace = sys.gettrace()
        self._thread = threading.Thread(target=self._watch, name="laplab-reward-watchdog", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join()
        self._thread = None
        signal.signal(TIMEOUT_SIGNAL, self._previous_handler)
        if self._fires:
            sys.settrace(self._previous_trace)

    def _on_signal(self, signum, frame) -> None:
        expired = self._expired
        if expired is None:
            return
        batch, limit, what = expired
        if not any(f is batch for f in _frames(frame)) or not any(is_user_frame(f) for f in _frames(frame)):
            return  # between two calls of the batch: the next signal lands inside one
        busy = next((f.f_lineno for f in _frames(frame) if is_user_frame(f)), None)
        self._fires += 1
        if self._fires > 1:  # the user's code swallowed the last one: raise on its every line too
            def stop_user_lines(f, event, arg):
                if self._expired is None or not is_user_frame(f):
                    return None
                if event == "line":
                    raise RewardTimeout(limit, busy, what)
                return stop_user_lines
            sys.settrace(stop_user_lines)
            for f in _frames(frame):
                if is_user_frame(f):
                    f.f_trace = stop_user_lines
        raise RewardTimeout(limit, busy, what)

    # -- watchdog thread -------------------------------------------------------------------------

    def _watch(self) -> None:
        batch, cpu_start, awake, last_tick = None, 0.0, 0.0, time.monotonic()
        while not self._stop.wait(_REPEAT_S if self._expired is not None else self.tick_s):
            now = time.monotonic()
            # A gap far longer than the tick means the process was stopped: that time is not counted.
            step = min(now - last_tick, 2 * self.tick_s)
            last_tick = now
            frame = sys._current_frames().get(self._main_ident)
            current = _batch_frame(frame) if frame is not None else None
            del frame
            if current is None or current is not batch:
                batch, awake, self._expired = current, 0.0, None
                self._fires = 0
                if current is not None:
                    cpu_start = time.clock_gettime(self._clock)
                continue
            awake += step
            if self._expired is None:
                cpu = time.clock_gettime(self._clock) - cpu_start
                if cpu > self.limits.timeout_s:
                    self._expired = (batch, self.limits.timeout_s, "CPU time")
                elif awake > self.limits.wait_timeout_s:
                    self._expired = (batch, self.limits.wait_timeout_s, "waiting (the call was blocked)")
            if self._expired is not None:
                signal.pthread_kill(self._main_ident, TIMEOUT_SIGNAL)
