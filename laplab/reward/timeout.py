"""``call_with_timeout``: a reward function call that cannot hang the validation step.

In the main thread on Unix a repeating ``SIGALRM`` timer unwinds the user's code (re-firing, and
tracing the user's lines, if a bare ``except:`` swallows it); elsewhere the call runs in a child
process that is killed when it outlives the timeout. Either way a hang becomes a
:class:`~laplab.reward.errors.RewardFunctionError` naming the line the function was busy on. A
function that ignores or blocks SIGALRM defeats the timer: the commands' check therefore makes its
calls in :mod:`laplab.reward.check_process`'s child, which its caller kills.
"""

from __future__ import annotations

import multiprocessing
import signal
import sys
import threading
from collections.abc import Mapping
from typing import Any

from laplab.reward.errors import RewardFunctionError, describe_exception, summarize_params
from laplab.reward.loader import RewardFunction


def call_with_timeout(reward_fn: RewardFunction, params: Mapping[str, Any], timeout_s: float,
                      *, method: str = "auto") -> float:
    """``reward_fn(params)``, or :class:`RewardFunctionError` if it does not return within ``timeout_s``.

    ``method``: ``"signal"`` runs the call here under a SIGALRM timer (main thread on Unix only),
    ``"process"`` runs it in a child process (fork where available) that is killed if it hangs,
    ``"auto"`` picks ``signal`` when possible, else ``process``. For the validation step only.
    """
    if not timeout_s > 0:
        raise ValueError(f"timeout_s must be positive, got {timeout_s!r}")
    if method == "auto":
        method = "signal" if _can_use_alarm() else "process"
    if method == "signal":
        if not _can_use_alarm():
            raise ValueError("method='signal' needs the main thread of a Unix process")
        return _call_with_alarm(reward_fn, params, timeout_s)
    if method == "process":
        return _call_in_process(reward_fn, params, timeout_s)
    raise ValueError(f"method must be 'auto', 'signal' or 'process', got {method!r}")


class _RewardTimeout(BaseException):
    """Raised by the SIGALRM handler; a BaseException so `except Exception` in user code misses it."""


_ALARM_REPEAT_S = 0.05  # re-fire period while the user's code keeps swallowing the timeout
_PROCESS_GRACE_S = 2.0  # extra wait for the child's own alarm before the parent kills it


def _can_use_alarm() -> bool:
    return hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()


def _call_with_alarm(reward_fn: RewardFunction, params: Mapping[str, Any], timeout_s: float) -> float:
    """Main-thread call under a repeating SIGALRM timer that unwinds the user's code when it fires."""
    user_filename = getattr(reward_fn, "_code_filename", None)
    state = {"finished": False, "fires": 0, "first_line": None}

    def stop_user_frames(frame, event, arg):
        if state["finished"] or frame.f_code.co_filename != user_filename:
            return None
        if event == "line":  # the next line the user's code runs, even inside its `except:` block
            raise _RewardTimeout
        return stop_user_frames

    def on_alarm(signum, frame):
        if state["finished"]:
            return
        state["fires"] += 1
        if state["fires"] == 1:  # where the code was busy when time ran out, before any unwinding
            state["first_line"] = next((f.f_lineno for f in _frames_of(frame)
                                        if f.f_code.co_filename == user_filename), None)
        else:  # a bare `except:` swallowed the last one: raise on every user line too
            sys.settrace(stop_user_frames)
            for user_frame in _frames_of(frame):
                if user_frame.f_code.co_filename == user_filename:
                    user_frame.f_trace = stop_user_frames
        raise _RewardTimeout

    previous_handler = signal.signal(signal.SIGALRM, on_alarm)
    previous_trace = sys.gettrace()
    try:
        signal.setitimer(signal.ITIMER_REAL, timeout_s, _ALARM_REPEAT_S)
        try:
            return reward_fn(params)
        finally:
            state["finished"] = True
            signal.setitimer(signal.ITIMER_REAL, 0)
    except _RewardTimeout:
        state["finished"] = True
        raise _timeout_error(reward_fn, params, timeout_s, state["first_line"]) from None
    finally:
        state["finished"] = True
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous_handler)
        if state["fires"] > 1:
            sys.settrace(previous_trace)


def _frames_of(frame):
    """``frame`` and its callers, innermost first."""
    while frame is not None:
        yield frame
        frame = frame.f_back


def _timeout_error(reward_fn, params, timeout_s, busy_line: int | None = None) -> RewardFunctionError:
    problem = f"the function did not return within {timeout_s:g} s"
    if not isinstance(reward_fn, RewardFunction):
        return RewardFunctionError(problem, path=getattr(reward_fn, "path", "<unknown>"),
                                   params_summary=summarize_params(params))
    if busy_line is not None:
        problem += " and was stopped while running this line"
    return reward_fn.error_at(problem, busy_line if busy_line is not None else reward_fn._def_line(), params,
                              hint="look for a `while` loop whose condition never becomes false")


def _timeout_child(connection, reward_fn, params, timeout_s) -> None:
    try:
        # The child is its process's main thread, so its own alarm can name the line it hung on.
        value = _call_with_alarm(reward_fn, params, timeout_s) if hasattr(signal, "setitimer") else reward_fn(params)
        connection.send(("ok", value))
    except RewardFunctionError as error:
        connection.send(("error", error))
    except BaseException as exc:  # noqa: BLE001 - anything else is reported, never hung on
        connection.send(("error", RewardFunctionError(f"the check process failed: {describe_exception(exc)}",
                                                      path=getattr(reward_fn, "path", "<unknown>"))))
    finally:
        connection.close()


def _call_in_process(reward_fn: RewardFunction, params: Mapping[str, Any], timeout_s: float) -> float:
    methods = multiprocessing.get_all_start_methods()
    context = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    receiver, sender = context.Pipe(duplex=False)
    process = context.Process(target=_timeout_child, args=(sender, reward_fn, params, timeout_s),
                              name="laplab-reward-check", daemon=True)
    process.start()
    sender.close()
    try:
        if receiver.poll(timeout_s + _PROCESS_GRACE_S):
            try:
                status, payload = receiver.recv()
            except EOFError:
                process.join(1.0)
                raise RewardFunctionError(f"the check process exited (code {process.exitcode}) without a result, "
                                          f"e.g. the function called os._exit() or crashed the interpreter",
                                          path=getattr(reward_fn, "path", "<unknown>"),
                                          params_summary=summarize_params(params)) from None
            if status == "ok":
                return payload
            raise payload
        raise _timeout_error(reward_fn, params, timeout_s)
    finally:
        receiver.close()
        if process.is_alive():
            process.terminate()
            process.join(1.0)
            if process.is_alive():
                process.kill()
        process.join(1.0)
