"""The supervisor's paragraph about a job that died: what died, how, where it stood, what is kept."""

from __future__ import annotations

import re
import signal


_FATAL = {signal.SIGSEGV: "crashed (segmentation fault)", signal.SIGBUS: "crashed (bus error)",
          signal.SIGABRT: "aborted", signal.SIGFPE: "crashed (floating-point exception)",
          signal.SIGILL: "crashed (illegal instruction)"}


def describe_death(reports: dict, returncode: int | None, signum: int | None, crash: str, limits,
                   max_rss: int | None, what: str) -> str:
    """The supervisor's one paragraph: what died, how, where it stood, what is kept."""
    model = reports.get("model")
    subject = f"{reports.get('what', what)} of model {model!r}" if model else reports.get("what", what)
    if signum is not None:
        name = signal.Signals(signum).name
        if signum == signal.SIGKILL and reports.get("reward_call"):
            how = f"was killed by {name}, which its reward function sent"
        elif signum == signal.SIGKILL:
            peak = f" (it had used {_size(max_rss)} at its peak)" if max_rss else ""
            how = f"was killed by {name}: the system's out-of-memory killer{peak} or another process (kill -9)"
        elif signum == getattr(signal, "SIGXCPU", None):
            how = f"used up its CPU-time limit of {limits.cpu_seconds:g} s (--cpu-limit) and was stopped"
        elif signum in _FATAL:
            how = f"{_FATAL[signum]} ({name})"
        else:
            how = f"was ended by signal {name} before it could stop cleanly"
    elif returncode == 0:
        how = ("ended with exit code 0 without finishing: something in it called os._exit(0) or an "
               "equivalent (the reward function is the only user code in a job)")
    else:
        how = (f"ended with exit code {returncode} without reporting why: something in it called "
               f"os._exit({returncode}) or the interpreter failed")
    where = ""
    if reports.get("iteration") is not None:
        where = f" It had finished iteration {reports['iteration']}."
    elif reports.get("folder"):
        where = " It had not finished an iteration yet."
    reward = _reward_frame(crash, reports.get("reward_path"))
    if reports.get("reward_call"):  # laplab.reward.guards saw the reward function end the job itself
        where += f" The reward function called {reports['reward_call']}."
    elif reward:
        where += f" It was running the reward function at {reward}."
    kept = ""
    if reports.get("folder"):
        kept = f" The model folder {reports['folder']} keeps every checkpoint saved before that"
        if reports.get("resume"):
            kept += f"; `{reports['resume']}` continues from the last one"
        kept += "."
    return f"the {subject} {how}.{where}{kept}"


def _reward_frame(crash: str, reward_path: str | None) -> str | None:
    """``file, line N`` of the innermost reward-function frame in a faulthandler dump."""
    frames = re.findall(r'File "([^"]+)", line (\d+)', crash)
    for path, line in frames:  # faulthandler lists the innermost frame first
        if (reward_path and path == reward_path) or path.endswith("reward_function.py"):
            return f"{path}, line {line}"
    return None


def _size(value: int | None) -> str:
    return "?" if value is None else f"{value / 2**30:.1f} GiB" if value >= 2**30 else f"{value / 2**20:.0f} MiB"


