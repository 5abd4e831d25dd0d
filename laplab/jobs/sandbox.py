"""What a supervised job sets up in its own process before it runs user code.

- :func:`die_with_parent`: the job is killed when its supervisor dies (Linux), so killing
  ``laplab train`` with SIGKILL never leaves an orphan training the model.
- :func:`guard_exit_calls`: ``os._exit`` called from a reward function raises :class:`ExitCalled`
  (a SystemExit) instead, which the reward loader reports as the usual RewardFunctionError with
  the line and params; called anywhere else it exits as usual.
- :func:`cap_reward_output`: what a reward function prints goes to the model folder's
  ``logs/reward-output.log`` in full, and only its first lines to the terminal;
  :func:`reward_output_summary` says how much was held back.

Reward code is recognised as in :mod:`laplab.reward.watchdog` (user modules are named
``laplab_user_reward_<n>``): nothing here costs anything per reward call.
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

from laplab.reward.watchdog import is_user_frame

REWARD_LOG = Path("logs") / "reward-output.log"
_PENDING_LIMIT = 4 << 20  # bytes of reward output kept in memory until the job knows its folder


def die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when the process that started it ends (no-op elsewhere)."""
    from laplab.jobs.confinement import die_with_parent as confined_die_with_parent
    confined_die_with_parent()


class ExitCalled(SystemExit):
    """``os._exit(code)`` called by a reward function: the job cannot be ended from there."""

    def __str__(self) -> str:
        return f"os._exit({self.code}) was called; a reward function cannot end the job"


def _user_code_on_stack() -> bool:
    frame = sys._getframe(2)
    while frame is not None:
        if is_user_frame(frame):
            return True
        frame = frame.f_back
    return False


def guard_exit_calls() -> None:
    real_exit = os._exit
    if getattr(real_exit, "laplab_guard", False):
        return

    def guarded_exit(code: int) -> None:
        if _user_code_on_stack():
            raise ExitCalled(code)
        real_exit(code)

    guarded_exit.laplab_guard = True
    os._exit = guarded_exit


class _RewardOutput:
    """Shared state of the capped stdout/stderr: lines shown, lines held back, the log file."""

    def __init__(self, max_lines: int):
        self.max_lines = max_lines
        self.shown = 0
        self.lines = 0
        self.dropped = 0
        self.log: Path | None = None
        self._handle = None
        self._pending: list[str] = []
        self._pending_bytes = 0
        self._pending_lost = 0
        self.notice_shown = False

    def set_folder(self, folder: Path) -> None:
        self.log = Path(folder) / REWARD_LOG
        try:
            self.log.parent.mkdir(parents=True, exist_ok=True)
            self._handle = open(self.log, "a", encoding="utf-8", errors="replace")  # noqa: SIM115
        except OSError:
            self._handle = None
            return
        for text in self._pending:
            self._handle.write(text)
        if self._pending_lost:
            self._handle.write(f"[laplab: {self._pending_lost} bytes printed before the model folder existed "
                               f"were not kept]\n")
        self._pending.clear()
        self._handle.flush()

    def keep(self, text: str) -> None:
        if self._handle is not None:
            self._handle.write(text)
            if "\n" in text:
                self._handle.flush()
        elif self._pending_bytes + len(text) <= _PENDING_LIMIT:
            self._pending.append(text)
            self._pending_bytes += len(text)
        else:
            self._pending_lost += len(text)


class _CappedStream:
    """A text stream that passes laplab's own output through and caps the reward function's."""

    def __init__(self, stream, output: _RewardOutput):
        self._stream, self._output = stream, output

    def write(self, text: str) -> int:
        if not text or not _user_code_on_stack():
            return self._stream.write(text)
        out = self._output
        out.keep(text)
        newlines = text.count("\n")
        out.lines += newlines
        if out.shown < out.max_lines:
            out.shown += newlines
            return self._stream.write(text)
        out.dropped += max(newlines, 0)
        if not out.notice_shown:
            out.notice_shown = True
            where = out.log if out.log is not None else "the model folder's " + str(REWARD_LOG)
            self._stream.write(f"[laplab: the reward function printed more than {out.max_lines} lines; the rest "
                               f"goes to {where} only]\n")
        return len(text)

    def __getattr__(self, name):
        return getattr(self._stream, name)


_output: _RewardOutput | None = None


def cap_reward_output(max_lines: int) -> None:
    """Route reward-function prints on stdout/stderr through the cap (see the module docstring)."""
    global _output
    if _output is not None:
        return
    _output = _RewardOutput(max_lines)
    sys.stdout = _CappedStream(sys.stdout, _output)
    sys.stderr = _CappedStream(sys.stderr, _output)


def set_output_folder(folder: str | os.PathLike) -> None:
    """The job's model folder is known: reward output is kept in its log from now on."""
    if _output is not None and _output.log is None:
        _output.set_folder(Path(folder))


def reward_output_summary() -> str | None:
    """One line on the reward function's output when some of it was held back from the terminal."""
    if _output is None or not _output.dropped:
        return None
    return (f"the reward function printed {_output.lines:,} lines; {_output.dropped:,} were not shown here "
            f"(all of them are in {_output.log or REWARD_LOG})")
