"""The reward check's calls in a child process that is killed when it stops answering.

Inside the child every call runs under :func:`laplab.reward.timeout.call_with_timeout`'s SIGALRM
timer, which names the line a slow call was busy on. A function that ignores or blocks SIGALRM, or
that kills, aborts or exits its process, cannot take the caller with it: the parent watches the
index of the call under way, and when one call outlives its time (plus a grace period) it asks the
child for its stack (``faulthandler`` on SIGUSR2, which needs no Python code to run), kills it and
raises the usual :class:`~laplab.reward.errors.RewardFunctionError` with the line and the params.
The child ignores SIGINT and SIGTERM's Python handlers (they belong to the caller, whose own stop
flag decides), and closes nothing of the caller's: its standard streams are its own copies.
"""

from __future__ import annotations

import faulthandler
import multiprocessing
import os
import re
import signal
import tempfile
import time
from collections.abc import Mapping, Sequence
from typing import Any

from laplab.reward.errors import RewardFunctionError, describe_exception, summarize_params
from laplab.reward.guards import die_with_parent, install_guards, on_self_signal
from laplab.reward.loader import RewardFunction
from laplab.reward.timeout import call_with_timeout

GRACE_S = 2.0  # beyond a call's timeout, before the parent gives up on the child's own timer
_POLL_S = 0.05
_DUMP_SIGNAL = signal.SIGUSR2


def can_isolate() -> bool:
    """Whether the calls can run in a forked child (Unix)."""
    return hasattr(os, "fork") and "fork" in multiprocessing.get_all_start_methods()


def call_all(reward_fn: RewardFunction, params_list: Sequence[Mapping[str, Any]],
             timeout_s: float) -> tuple[list[float], RewardFunctionError | None]:
    """``reward_fn(params)`` for every params dict, in a child process, until the first failure:
    ``(the rewards before it, the failure or None)``."""
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)
    progress = context.Value("q", -1, lock=False)  # index of the call under way
    with tempfile.TemporaryFile() as dump:
        process = context.Process(target=_child, name="laplab-reward-check", daemon=True,
                                  args=(sender, reward_fn, params_list, timeout_s, progress, dump.fileno()))
        process.start()
        sender.close()
        try:
            return _watch(process, receiver, progress, dump, reward_fn, params_list, timeout_s)
        finally:
            receiver.close()
            if process.is_alive():
                process.kill()
            process.join(5.0)


def _watch(process, receiver, progress, dump, reward_fn, params_list, timeout_s):
    signalled = None  # what the function did to its own process, as the guards reported it
    index, since = -1, time.monotonic()
    while True:
        if receiver.poll(_POLL_S):
            try:
                message = receiver.recv()
            except EOFError:  # the child is gone without its result
                process.join(5.0)
                return _died(process, reward_fn, params_list, progress.value, signalled, dump)
            if message[0] == "signal":
                signalled = message[1]
                continue
            _, values, error = message
            return values, error
        if progress.value != index:
            index, since = progress.value, time.monotonic()
        elif index >= 0 and time.monotonic() - since > timeout_s + GRACE_S:
            return [], _hung(process, reward_fn, params_list[index], timeout_s, dump)
        if not process.is_alive() and not receiver.poll(0):
            return _died(process, reward_fn, params_list, progress.value, signalled, dump)


def _child(sender, reward_fn, params_list, timeout_s, progress, dump_fd) -> None:
    die_with_parent()  # a caller killed with SIGKILL leaves no orphan looping in the reward function
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is for the caller: it stops the check
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    faulthandler.register(_DUMP_SIGNAL, file=dump_fd, all_threads=False)
    faulthandler.enable(file=dump_fd, all_threads=False)  # a crash leaves its stack too
    install_guards()
    on_self_signal(lambda where: sender.send(("signal", where)))
    values: list[float] = []
    try:
        for i, params in enumerate(params_list):
            progress.value = i
            values.append(call_with_timeout(reward_fn, params, timeout_s, method="signal"))
        sender.send(("done", values, None))
    except RewardFunctionError as error:
        sender.send(("done", values, error))
    except BaseException as exc:  # noqa: BLE001 - reported as the check's failure, never hung on
        error = RewardFunctionError(f"the check failed: {describe_exception(exc)}", path=reward_fn.path,
                                    params_summary=summarize_params(params_list[max(progress.value, 0)]))
        sender.send(("done", values, error))
    finally:
        sender.close()


def _stack_line(dump, reward_fn) -> int | None:
    """The innermost line of the user's file in what faulthandler wrote (innermost frame first)."""
    dump.seek(0)
    text = dump.read().decode(errors="replace")
    for path, line in re.findall(r'File "([^"]+)", line (\d+)', text):
        if path == getattr(reward_fn, "_code_filename", None):
            return int(line)
    return None


def _hung(process, reward_fn, params, timeout_s, dump) -> RewardFunctionError:
    os.kill(process.pid, _DUMP_SIGNAL)
    deadline = time.monotonic() + 1.0
    line = None
    while line is None and time.monotonic() < deadline:
        time.sleep(0.05)
        line = _stack_line(dump, reward_fn)
    process.kill()
    problem = (f"the function did not return within {timeout_s:g} s, and it kept the check's own timer "
               "(SIGALRM) from stopping it")
    if line is not None:
        problem += "; it was stopped while running this line"
    return reward_fn.error_at(problem, line, params, hint="look for a loop that never ends, and do not change "
                                                          "signal handlers in a reward function")


def _died(process, reward_fn, params_list, index, signalled, dump) -> tuple[list, RewardFunctionError]:
    code = process.exitcode
    how = (f"was killed by signal {signal.Signals(-code).name}" if code is not None and code < 0
           else f"exited with code {code}")
    params = params_list[max(index, 0)]
    if signalled:
        match = re.search(r" at (.+), line (\d+)$", signalled)
        call = signalled[:match.start()] if match else signalled
        line = int(match.group(2)) if match else None
        return [], reward_fn.error_at(f"the function called {call}: the check's process {how}", line, params,
                                      hint="a reward function must return a number, not end its process")
    line = _stack_line(dump, reward_fn)
    problem = f"the check's process {how} while the function ran (state {index + 1} of {len(params_list)})"
    if line is not None:
        problem += ", at this line"
    return [], reward_fn.error_at(problem, line, params,
                                  hint="a reward function must return a number, not end its process")
