"""Errors raised by user reward functions, with the file, line and params that caused them.

DeepRacer kills a whole training job with a bare log line when a reward function fails. laplab
instead raises :class:`RewardFunctionError`, whose one-paragraph message names the reward file,
the line in it, the source text of that line, what went wrong (with a hint for the classic
tutorial bugs) and the key params of the step that triggered it.
"""

from __future__ import annotations

import difflib
import math
import re
import sys
from collections.abc import Mapping
from types import TracebackType
from typing import Any, Callable

from laplab.errors import UserError

#: The params shown in error messages: enough to rebuild the failing state by hand.
PARAMS_SUMMARY_KEYS = (
    "x", "y", "heading", "progress", "steps", "speed", "steering_angle", "distance_from_center",
    "is_left_of_center", "track_width", "all_wheels_on_track", "is_offtrack", "is_crashed",
    "is_reversed", "closest_waypoints",
)

#: Every key of DeepRacer's params dict (reference doc section 2), for "did you mean" hints.
DEEPRACER_PARAMS_KEYS = (
    "all_wheels_on_track", "x", "y", "heading", "distance_from_center", "is_left_of_center",
    "progress", "steps", "speed", "steering_angle", "track_width", "track_length", "waypoints",
    "closest_waypoints", "is_offtrack", "is_crashed", "is_reversed", "projection_distance",
    "closest_objects", "objects_location", "objects_left_of_center", "objects_speed",
    "objects_heading", "objects_distance", "objects_distance_from_center", "object_in_camera",
)

_SYNTAX_HINTS = (
    (re.compile(r"^\s*else\s+if\b"), "Python writes `elif`, not `else if`"),
    (re.compile(r"&&|\|\|"), "Python writes `and` / `or`, not `&&` / `||`"),
    (re.compile(r"^\s*(if|elif|while|for|def|else)\b[^#]*[^:\s#]\s*(#.*)?$"),
     "a block statement must end with `:`"),
)


class RewardFunctionError(UserError):
    """A user reward function failed to load, raised, returned a bad value or hung.

    Attributes: ``path`` (the reward file, or ``"<string>"``), ``lineno`` (1-based line in that
    file, or None), ``source_line`` (that line's text, stripped), ``problem`` (what went wrong),
    ``cause`` (``repr`` of the underlying exception, or None), ``hint`` (a likely fix, or None),
    ``params_summary`` (the key params of the failing step, or None at load time); ``field``:
    ``"reward_function"`` (the console's name for the code, the CLI's is ``--reward``).
    """

    default_field = "reward_function"

    def __init__(self, problem: str, *, path: str = "<string>", lineno: int | None = None,
                 source_line: str | None = None, cause: str | None = None,
                 hint: str | None = None, params_summary: Mapping[str, Any] | None = None):
        self.problem = problem
        self.path = str(path)
        self.lineno = lineno
        self.source_line = source_line.strip() if source_line else source_line
        self.cause = cause
        self.hint = hint
        self.params_summary = dict(params_summary) if params_summary is not None else None
        super().__init__(self._compose_message())

    def _compose_message(self) -> str:
        where = f"Reward function error in {self.path}"
        if self.lineno is not None:
            where += f", line {self.lineno}"
        if self.source_line:
            where += f" (`{self.source_line}`)"
        parts = [f"{where}: {_sentence(self.problem)}"]
        if self.hint:
            parts.append(f"Hint: {_sentence(self.hint)}")
        if self.params_summary:
            shown = ", ".join(f"{key}={_format_value(value)}" for key, value in self.params_summary.items())
            parts.append(f"Params of the failing step: {shown}.")
        return " ".join(parts)

    def __reduce__(self):
        # Rebuilt from its fields so it survives the pipe from a timeout subprocess.
        fields = dict(path=self.path, lineno=self.lineno, source_line=self.source_line,
                      cause=self.cause, hint=self.hint, params_summary=self.params_summary)
        return (_rebuild_error, (type(self), self.problem, fields))


def _rebuild_error(cls, problem, fields):
    return cls(problem, **fields)


def _sentence(text: str) -> str:
    text = text.rstrip()
    return text if text.endswith((".", "?", "!")) else text + "."


def _format_value(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else repr(value)
    if isinstance(value, (list, tuple)) and len(value) <= 4:
        return "[" + ", ".join(_format_value(item) for item in value) + "]"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def summarize_params(params: Any) -> dict[str, Any] | None:
    """The :data:`PARAMS_SUMMARY_KEYS` present in ``params`` (None when it is not a mapping)."""
    if not isinstance(params, Mapping):
        return None
    return {key: params[key] for key in PARAMS_SUMMARY_KEYS if key in params}


def last_user_frame(traceback: TracebackType | None, code_filename: str) -> TracebackType | None:
    """The innermost traceback entry executing code compiled from ``code_filename``, or None."""
    found = None
    while traceback is not None:
        if traceback.tb_frame.f_code.co_filename == code_filename:
            found = traceback
        traceback = traceback.tb_next
    return found


def describe_exception(exc: BaseException) -> str:
    """``TypeName: message`` of an exception, as a traceback's last line shows it."""
    message = str(exc)
    return f"{type(exc).__name__}: {message}" if message else type(exc).__name__


def hint_for_exception(exc: BaseException, frame_names: list[str], params: Any) -> str | None:
    """A likely fix for the classic reward-function bugs, or None.

    ``frame_names`` are the local and global names visible in the failing frame, used for
    "did you mean" suggestions next to the params keys.
    """
    params_keys = list(params) if isinstance(params, Mapping) else list(DEEPRACER_PARAMS_KEYS)
    if isinstance(exc, AttributeError) and "module 'math' has no attribute 'abs'" in str(exc):
        return "math has no abs(); use the built-in abs(value) or math.fabs(value)"
    if isinstance(exc, NameError) and getattr(exc, "name", None):
        name = exc.name
        if name in ("true", "false", "none", "null"):
            return f"Python writes {name.capitalize() if name != 'null' else 'None'}"
        if name in params_keys:
            return f"`{name}` is a key of params, not a variable: read it with params['{name}']"
        close = difflib.get_close_matches(name, frame_names + params_keys, n=1, cutoff=0.75)
        if close:
            return f"did you mean `{close[0]}`?"
        return None
    if isinstance(exc, KeyError) and exc.args and isinstance(exc.args[0], str):
        close = difflib.get_close_matches(exc.args[0], params_keys, n=1, cutoff=0.6)
        if close:
            return f"params has no key {exc.args[0]!r}; did you mean {close[0]!r}?"
        return f"params has no key {exc.args[0]!r}; its keys are {', '.join(sorted(params_keys))}"
    return None


def hint_for_syntax(source_line: str | None) -> str | None:
    """A likely fix for a syntax error on ``source_line`` (tutorial-era habits), or None."""
    if not source_line:
        return None
    for pattern, hint in _SYNTAX_HINTS:
        if pattern.search(source_line):
            return hint
    return None


def replay_return_line(function: Callable, args: tuple) -> tuple[int | None, Any]:
    """``(line at which function(*args) returns, the value it returned)``, by calling it again under a tracer.

    Only for the error path (a bad return value): tracing is slow, and a stateful function may
    take another path the second time, so callers check the value. ``(None, None)`` when the
    replay raises or the function has no code object.
    """
    code = getattr(function, "__code__", None)
    if code is None:
        return None, None
    return_lines: list[int] = []

    def trace_returns(frame, event, arg):
        if event == "return":
            return_lines.append(frame.f_lineno)
        return trace_returns

    def trace_calls(frame, event, arg):
        return trace_returns if frame.f_code is code else None

    previous = sys.gettrace()
    sys.settrace(trace_calls)
    try:
        value = function(*args)
    except Exception:
        return None, None
    finally:
        sys.settrace(previous)
    return (return_lines[-1] if return_lines else None), value  # the outermost call returns last
