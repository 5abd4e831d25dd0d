"""Load a user's DeepRacer ``reward_function`` and call it safely.

``load_reward_function`` compiles a reward file (or source string) into a :class:`RewardFunction`:
a callable ``params dict -> float`` that checks every returned value and turns every failure into
a :class:`~laplab.reward.errors.RewardFunctionError` naming the line of the user's file. The 2018
signature (twelve positional arguments, optionally after ``self``) is detected and called with
its units converted from the modern params dict.

Shared ``waypoints``: the params builder passes one list of ``(x, y)`` tuples shared by every
step. Each call hands the user function a shallow copy of that list, so appending to, sorting or
reversing it never leaks into later steps, and the tuples themselves are immutable.

:func:`laplab.reward.timeout.call_with_timeout` guards the validation step against functions that
never return; during a job :class:`laplab.reward.watchdog.RewardWatchdog` limits every step's calls
without a timer per call (a :class:`RewardTimeout` it raises becomes a RewardFunctionError here).
"""

from __future__ import annotations

import dis
import inspect
import itertools
import math
import os
import re
import sys
import tokenize
import types
from collections.abc import Callable, Mapping
from typing import Any

from laplab.reward.errors import (
    RewardFunctionError, describe_exception, hint_for_exception, hint_for_syntax, last_user_frame,
    replay_return_line, summarize_params,
)
from laplab.reward.watchdog import RewardTimeout
from laplab.vehicle.params import DEEPRACER

#: Argument names of the 2018 signature, after the optional leading ``self``.
LEGACY_PARAMETERS = (
    "on_track", "x", "y", "distance_from_center", "car_orientation", "progress", "steps",
    "throttle", "steering", "track_width", "waypoints", "closest_waypoint",
)
#: DeepRacer's accepted reward range (inclusive).
REWARD_LIMIT = 1e5

_module_counter = itertools.count()
_RAISE_OPCODE = dis.opmap["RAISE_VARARGS"]


class RewardFunction:
    """A loaded user reward function: ``reward_fn(params) -> float``.

    Attributes: ``path`` (the file, or ``"<string>"``), ``source`` (its text), ``name`` (the
    function's name), ``is_legacy`` (2018 positional signature), ``max_speed`` (m/s) and
    ``max_steering_deg`` (deg) used to convert legacy ``throttle`` and ``steering`` to [-1, 1].
    """

    def __init__(self, function: Callable, *, path: str, source: str, name: str, code_filename: str,
                 is_legacy: bool, legacy_has_self: bool, max_speed: float, max_steering_deg: float):
        self.function = function
        self.path = path
        self.source = source
        self.name = name
        self.is_legacy = is_legacy
        self.max_speed = max_speed
        self.max_steering_deg = max_steering_deg
        self._code_filename = code_filename
        self._legacy_has_self = legacy_has_self
        self._source_lines = source.splitlines()

    def __call__(self, params: Mapping[str, Any]) -> float:
        """Reward of one step, validated: finite float in [-1e5, 1e5]."""
        return self._invoke(self._arguments(params), params)

    def call_fresh(self, params: dict) -> float:
        """:meth:`__call__` for a params dict built for this call alone, with its own ``waypoints``
        list of tuples (as :class:`laplab.reward.params.ParamsBuilder` makes them): skips the
        defensive copy, which costs more than a typical reward function."""
        return self(params) if self.is_legacy else self._invoke((params,), params)

    def _invoke(self, args: tuple, params: Mapping[str, Any]) -> float:
        try:
            value = self.function(*args)
        except (Exception, SystemExit) as exc:
            raise self._raised_error(exc, params) from exc
        except RewardTimeout as timeout:  # laplab.reward.watchdog stopped a batch of calls that ran too long
            raise self._timeout_error(timeout, params) from None
        except KeyboardInterrupt as exc:
            if not self._raised_by_user(exc):  # Ctrl-C while the function ran: the user's interrupt
                raise
            raise self._raised_error(exc, params, hint="a reward function cannot stop the job; return a "
                                                        "number on every path") from exc
        reward, why_invalid = _checked_reward(value)
        if why_invalid:
            raise self._return_error(value, params, why_invalid) from None
        return reward

    def __repr__(self) -> str:
        kind = "2018 signature" if self.is_legacy else "params dict"
        return f"RewardFunction({self.path!r}, name={self.name!r}, {kind})"

    def __reduce__(self):
        # Pickled as its source, so spawn-started worker processes recompile it.
        return (_compile_reward, (self.source, self.path, self.name, self.max_speed, self.max_steering_deg))

    def _arguments(self, params: Mapping[str, Any]) -> tuple:
        """Positional arguments of the user function for one step (2018 units when legacy)."""
        call_params = _with_private_waypoints(params)
        if not self.is_legacy:
            return (call_params,)
        args = legacy_arguments(call_params, self.max_speed, self.max_steering_deg)
        return (None, *args) if self._legacy_has_self else args

    # -- diagnostics -------------------------------------------------------------------------

    def line_text(self, lineno: int | None) -> str | None:
        """Text of 1-based line ``lineno`` of the user's source, or None."""
        if lineno is None or not 1 <= lineno <= len(self._source_lines):
            return None
        return self._source_lines[lineno - 1]

    def error_at(self, problem: str, lineno: int | None, params: Any, *, cause: str | None = None,
                 hint: str | None = None) -> RewardFunctionError:
        """A :class:`RewardFunctionError` located at ``lineno`` of the user's file."""
        return RewardFunctionError(problem, path=self.path, lineno=lineno, source_line=self.line_text(lineno),
                                   cause=cause, hint=hint, params_summary=summarize_params(params))

    def user_frame(self, traceback: types.TracebackType | None) -> types.TracebackType | None:
        """The innermost traceback entry inside the user's file."""
        return last_user_frame(traceback, self._code_filename)

    def _raised_error(self, exc: BaseException, params: Any, hint: str | None = None) -> RewardFunctionError:
        entry = self.user_frame(exc.__traceback__)
        names = [*entry.tb_frame.f_locals, *entry.tb_frame.f_globals] if entry is not None else []
        return self.error_at(f"the function raised {describe_exception(exc)}",
                             entry.tb_lineno if entry is not None else None, params,
                             cause=repr(exc), hint=hint or hint_for_exception(exc, names, params))

    def _raised_by_user(self, exc: BaseException) -> bool:
        return raised_by_statement(exc, self._code_filename)

    def _timeout_error(self, timeout: RewardTimeout, params: Any) -> RewardFunctionError:
        problem = (f"one step's calls of the function did not return within {timeout.seconds:g} s of "
                   f"{timeout.what}")
        if timeout.busy_line is not None:
            problem += "; it was stopped while running this line"
        return self.error_at(problem, timeout.busy_line if timeout.busy_line is not None else self._def_line(),
                             params, hint="look for a loop that never ends or a call that waits; the limit is "
                                          "--reward-timeout (seconds of CPU per step's calls)")

    def _return_error(self, value: Any, params: Any, why: str) -> RewardFunctionError:
        lineno, fell_off = self._find_return_line(params)
        shown = repr(value)
        shown = shown if len(shown) <= 60 else shown[:57] + "..."
        problem = f"the function returned {shown} ({type(value).__name__}), {why}"
        hint = None
        if lineno is None:
            lineno = self._def_line()
            problem += f" (the function `{self.name}` starts at this line)"
        elif fell_off:
            problem += f"; execution reached the end of `{self.name}` without a return statement after this line"
            hint = "every path through the function must end with `return <number>`"
        return self.error_at(problem, lineno, params, hint=hint)

    def _def_line(self) -> int | None:
        code = getattr(self.function, "__code__", None)
        return code.co_firstlineno if code is not None and code.co_filename == self._code_filename else None

    def _find_return_line(self, params: Any) -> tuple[int | None, bool]:
        """``(line that returned, whether it is not a return statement)``, by replaying the call."""
        code = getattr(self.function, "__code__", None)
        if code is None or code.co_filename != self._code_filename:
            return None, False
        lineno, value = replay_return_line(self.function, self._arguments(params))
        if lineno is None or _checked_reward(value)[1] is None:  # the replay took another path
            return None, False
        fell_off = re.search(r"\breturn\b|\blambda\b", self.line_text(lineno) or "") is None
        return lineno, fell_off


def load_reward_function(path_or_source: str | os.PathLike, *, name: str = "reward_function",
                         max_speed: float = DEEPRACER.max_speed,
                         max_steering_deg: float = DEEPRACER.max_steering_deg) -> RewardFunction:
    """Compile a reward file or source string and return its checked :class:`RewardFunction`.

    A ``str`` containing a newline is source code; any other ``str`` or path-like is a file path.
    ``max_speed`` (m/s) and ``max_steering_deg`` (deg) convert the 2018 signature's ``throttle`` and
    ``steering``. Raises :class:`RewardFunctionError` for a missing file, a syntax error, an error
    while running the module's top level, a missing function or an unsupported signature.
    """
    if not (math.isfinite(max_speed) and max_speed > 0 and math.isfinite(max_steering_deg) and max_steering_deg > 0):
        raise ValueError(f"max_speed and max_steering_deg must be positive, got {max_speed!r}, {max_steering_deg!r}")
    path, source = _read_source(path_or_source)
    return _compile_reward(source, path, name, float(max_speed), float(max_steering_deg))


def _compile_reward(source: str, path: str, name: str, max_speed: float, max_steering_deg: float) -> RewardFunction:
    code_filename = path  # "<string>" for source text; frames of user code carry this filename
    lines = source.splitlines()

    def line_at(lineno):
        return lines[lineno - 1] if lineno and 1 <= lineno <= len(lines) else None

    try:
        code = compile(source, code_filename, "exec", dont_inherit=True)
    except SyntaxError as exc:
        text = exc.text if exc.text is not None else line_at(exc.lineno)
        raise RewardFunctionError(f"the file does not compile: SyntaxError: {exc.msg}", path=path,
                                  lineno=exc.lineno, source_line=text, cause=repr(exc),
                                  hint=hint_for_syntax(text)) from None
    except ValueError as exc:  # null bytes in the source
        raise RewardFunctionError(f"the file does not compile: {exc}", path=path, cause=repr(exc)) from None

    module_name = f"laplab_user_reward_{next(_module_counter)}"
    module = types.ModuleType(module_name)
    module.__file__ = path
    sys.modules[module_name] = module  # dataclasses and pickle look classes up here
    try:
        exec(code, module.__dict__)
    except (Exception, SystemExit, KeyboardInterrupt) as exc:
        sys.modules.pop(module_name, None)
        if isinstance(exc, KeyboardInterrupt) and not raised_by_statement(exc, code_filename):
            raise  # Ctrl-C while the file loaded; a `raise KeyboardInterrupt` in it is a load error

        entry = last_user_frame(exc.__traceback__, code_filename)
        lineno = entry.tb_lineno if entry is not None else None
        raise RewardFunctionError(f"running the file's top level raised {describe_exception(exc)}", path=path,
                                  lineno=lineno, source_line=line_at(lineno), cause=repr(exc),
                                  hint=hint_for_exception(exc, list(module.__dict__), None)) from exc

    function = module.__dict__.get(name)
    if function is None or not callable(function):
        defined = sorted(key for key, value in module.__dict__.items()
                         if callable(value) and not key.startswith("_") and not isinstance(value, types.ModuleType))
        found = f"it defines {', '.join(defined)}" if defined else "it defines no functions"
        what = (f"no function named `{name}`" if function is None
                else f"`{name}` bound to a {type(function).__name__}, not a function")
        raise RewardFunctionError(f"the file has {what}; {found}", path=path,
                                  hint=f"DeepRacer calls `def {name}(params):` and nothing else")
    is_legacy, legacy_has_self = _classify_signature(function, name, path, line_at)
    return RewardFunction(function, path=path, source=source, name=name, code_filename=code_filename,
                          is_legacy=is_legacy, legacy_has_self=legacy_has_self, max_speed=max_speed,
                          max_steering_deg=max_steering_deg)


def raised_by_statement(exc: BaseException, code_filename: str) -> bool:
    """Whether ``exc`` (e.g. a KeyboardInterrupt) came from a ``raise`` statement in ``code_filename``,
    not from SIGINT: a signal handler raises at a call or a loop's jump, never at a ``raise``."""
    last = exc.__traceback__
    while last is not None and last.tb_next is not None:
        last = last.tb_next
    if last is None or last.tb_frame.f_code.co_filename != code_filename:
        return False
    code = last.tb_frame.f_code.co_code
    return 0 <= last.tb_lasti < len(code) and code[last.tb_lasti] == _RAISE_OPCODE


def legacy_arguments(params: Mapping[str, Any], max_speed: float, max_steering_deg: float) -> tuple:
    """The 12 positional arguments of the 2018 signature, converted from a modern params dict.

    ``on_track`` = all_wheels_on_track, ``car_orientation`` = heading in rad, ``progress`` in [0, 1],
    ``throttle`` = speed / max_speed, ``steering`` = steering_angle / max_steering_deg in [-1, 1],
    ``closest_waypoint`` = whichever of ``closest_waypoints`` lies nearer to (x, y).
    """
    try:
        x, y = params["x"], params["y"]
        waypoints = params["waypoints"]
        previous_index, next_index = params["closest_waypoints"]
        px, py = waypoints[previous_index][:2]
        nx, ny = waypoints[next_index][:2]
        nearer = previous_index if math.hypot(x - px, y - py) <= math.hypot(x - nx, y - ny) else next_index
        return (params["all_wheels_on_track"], x, y, params["distance_from_center"],
                math.radians(params["heading"]), params["progress"] / 100.0, params["steps"],
                params["speed"] / max_speed, params["steering_angle"] / max_steering_deg,
                params["track_width"], waypoints, nearer)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ValueError(f"cannot build the 2018 reward arguments from params: {describe_exception(exc)}; "
                         f"params needs x, y, heading, progress, steps, speed, steering_angle, track_width, "
                         f"distance_from_center, all_wheels_on_track, waypoints and closest_waypoints") from exc


# -- internals ---------------------------------------------------------------------------------


def _read_source(path_or_source: str | os.PathLike) -> tuple[str, str]:
    if isinstance(path_or_source, str) and "\n" in path_or_source:
        return "<string>", path_or_source
    if not isinstance(path_or_source, (str, os.PathLike)):
        raise TypeError(f"load_reward_function needs a file path or source text, got {type(path_or_source).__name__}")
    path = os.path.abspath(os.fspath(path_or_source))
    if not os.path.isfile(path):
        looks_like_code = "def " in str(path_or_source) or "return" in str(path_or_source)
        raise RewardFunctionError(
            "no such reward file" + (" (source text must contain a newline)" if looks_like_code else ""), path=path)
    try:
        with tokenize.open(path) as handle:  # honours a PEP 263 coding line, strips a BOM
            return path, handle.read()
    except (SyntaxError, UnicodeDecodeError) as exc:
        raise RewardFunctionError(f"the file cannot be decoded as Python source text: {exc}", path=path) from None


def _classify_signature(function: Callable, name: str, path: str, line_at) -> tuple[bool, bool]:
    """``(is_legacy, legacy_has_self)`` from the function's parameters; raises for anything else."""
    try:
        signature = inspect.signature(function)
    except (TypeError, ValueError):
        return False, False  # a builtin or C callable: call it with params
    parameters = list(signature.parameters.values())
    positional = [p for p in parameters if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    required = [p for p in parameters if p.default is p.empty and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    accepts_varargs = any(p.kind is p.VAR_POSITIONAL for p in parameters)
    names = tuple(p.name for p in positional)
    if len(required) == len(positional) == len(LEGACY_PARAMETERS):  # 2018, recognised by count
        return True, False
    if len(required) == len(positional) == len(LEGACY_PARAMETERS) + 1 and (
            names[0] == "self" or names[1:] == LEGACY_PARAMETERS):
        return True, True
    required_positional = [p for p in required if p in positional]
    if len(required_positional) == len(required) and (
            len(required) == 1 or (len(required) == 0 and (positional or accepts_varargs))):
        return False, False
    code = getattr(function, "__code__", None)
    lineno = code.co_firstlineno if code is not None else None
    raise RewardFunctionError(
        f"`{name}{signature}` has an unsupported signature: DeepRacer calls `{name}(params)` with one dict, "
        f"and laplab also runs the 2018 form `{name}(self, {', '.join(LEGACY_PARAMETERS)})` (with or "
        f"without `self`)", path=path, lineno=lineno, source_line=line_at(lineno),
        hint="rewrite it as `def reward_function(params):` and read values with params['x'] etc.")


def _with_private_waypoints(params: Mapping[str, Any]) -> Mapping[str, Any]:
    """``params`` with its own shallow copy of ``waypoints`` (a list of tuples), so mutations stay local."""
    waypoints = params.get("waypoints") if isinstance(params, Mapping) else None
    if hasattr(waypoints, "tolist"):  # a numpy array: hand out immutable rows, as DeepRacer's list would be
        return {**params, "waypoints": [tuple(point) for point in waypoints.tolist()]}
    if not isinstance(waypoints, list):
        return params
    if waypoints and type(waypoints[0]) is not tuple:
        return {**params, "waypoints": [tuple(point) for point in waypoints]}
    return {**params, "waypoints": waypoints.copy()}


def _checked_reward(value: Any) -> tuple[float, str | None]:
    """``(float(value), None)`` for a valid reward, else ``(nan, why it is invalid)``."""
    try:
        reward = float(value)
    except (TypeError, ValueError, OverflowError):
        return math.nan, "which is not a number"
    except (Exception, SystemExit) as exc:  # the returned object's own __float__ failed
        return math.nan, f"and float() of it raised {describe_exception(exc)}"
    if not math.isfinite(reward):
        return reward, "which is not finite"
    if not -REWARD_LIMIT <= reward <= REWARD_LIMIT:
        return reward, "outside DeepRacer's range [-1e5, 1e5]"
    return reward, None
