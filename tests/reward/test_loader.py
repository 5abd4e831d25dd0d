"""Loading user reward functions: every error class names the file and line, legacy calls, timeouts."""

from __future__ import annotations

import math
import pickle
import signal
import sys
import textwrap
import threading
import time

import numpy as np
import pytest

from laplab.reward.errors import RewardFunctionError
from laplab.reward.loader import LEGACY_PARAMETERS, RewardFunction, load_reward_function
from laplab.reward.timeout import call_with_timeout

WAYPOINTS = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (3.0, 0.0), (0.0, 0.0)]


def make_params(**changes) -> dict:
    """A plausible params dict: car at (1.3, 0.1) between waypoints 1 and 2, 2 m/s, steering 15 deg."""
    params = {
        "all_wheels_on_track": True, "x": 1.3, "y": 0.1, "heading": 90.0, "distance_from_center": 0.1,
        "is_left_of_center": True, "progress": 12.5, "steps": 7.0, "speed": 2.0, "steering_angle": 15.0,
        "track_width": 0.76, "track_length": 6.0, "waypoints": list(WAYPOINTS), "closest_waypoints": [1, 2],
        "is_offtrack": False, "is_crashed": False, "is_reversed": False, "projection_distance": 1.3,
    }
    params.update(changes)
    return params


def write(tmp_path, source: str, name: str = "reward_function.py") -> str:
    path = tmp_path / name
    path.write_text(textwrap.dedent(source).lstrip("\n"))
    return str(path)


def failure(reward_fn: RewardFunction, params: dict) -> RewardFunctionError:
    with pytest.raises(RewardFunctionError) as caught:
        reward_fn(params)
    return caught.value


def assert_names_location(error: RewardFunctionError, path: str, lineno: int) -> None:
    assert error.path == path and error.lineno == lineno
    assert path in str(error) and f"line {lineno}" in str(error)
    assert error.source_line and error.source_line in str(error)


# -- load time ----------------------------------------------------------------------------------


def test_else_if_is_a_syntax_error_with_file_line_and_hint(tmp_path):
    path = write(tmp_path, """
        def reward_function(params):
            if params['x'] > 0:
                return 1.0
            else if params['y'] > 0:
                return 0.5
            return 0.1
        """)
    with pytest.raises(RewardFunctionError) as caught:
        load_reward_function(path)
    error = caught.value
    assert_names_location(error, path, 4)
    assert error.source_line == "else if params['y'] > 0:"
    assert "SyntaxError" in str(error) and "elif" in error.hint
    assert error.params_summary is None


def test_source_string_errors_are_located_in_string():
    with pytest.raises(RewardFunctionError) as caught:
        load_reward_function("def reward_function(params):\n    return params['x'] &&& 1\n")
    assert caught.value.path == "<string>" and caught.value.lineno == 2
    assert "<string>, line 2" in str(caught.value)


def test_missing_file_missing_function_and_bad_top_level(tmp_path):
    with pytest.raises(RewardFunctionError, match="no such reward file"):
        load_reward_function(tmp_path / "absent.py")
    path = write(tmp_path, "def reward(params):\n    return 1.0\n")
    with pytest.raises(RewardFunctionError, match=r"no function named `reward_function`; it defines reward"):
        load_reward_function(path)
    assert load_reward_function(path, name="reward")(make_params()) == 1.0
    path = write(tmp_path, "import math\nimport shapely_not_installed_here\n\ndef reward_function(params):\n"
                           "    return 1.0\n", "top.py")
    with pytest.raises(RewardFunctionError) as caught:
        load_reward_function(path)
    assert_names_location(caught.value, path, 2)
    assert "ModuleNotFoundError" in str(caught.value)


def test_unsupported_signature_fails_at_load_naming_the_def_line(tmp_path):
    path = write(tmp_path, "import math\n\ndef reward_function(params, weights):\n    return 1.0\n")
    with pytest.raises(RewardFunctionError) as caught:
        load_reward_function(path)
    assert_names_location(caught.value, path, 3)
    assert "unsupported signature" in str(caught.value)


def test_attributes_and_pickling(tmp_path):
    source = "def reward_function(params):\n    return params['speed'] / 4.0\n"
    path = write(tmp_path, source)
    reward_fn = load_reward_function(path)
    assert (reward_fn.path, reward_fn.source, reward_fn.is_legacy) == (path, source, False)
    clone = pickle.loads(pickle.dumps(reward_fn))
    assert clone.path == path and clone(make_params()) == 0.5
    error = RewardFunctionError("boom", path=path, lineno=2, source_line="return 1", cause="ValueError()",
                                hint="fix it", params_summary={"x": 1.0})
    again = pickle.loads(pickle.dumps(error))
    assert str(again) == str(error) and again.lineno == 2 and again.params_summary == {"x": 1.0}


# -- exceptions raised by the function ----------------------------------------------------------


def test_math_abs_names_its_line(tmp_path):
    path = write(tmp_path, """
        import math

        def reward_function(params):
            steering = params['steering_angle']
            if math.abs(steering) > 15:
                return 0.5
            return 1.0
        """)
    error = failure(load_reward_function(path), make_params())
    assert_names_location(error, path, 5)
    assert "AttributeError" in str(error) and "abs(" in error.hint
    assert "AttributeError" in error.cause
    assert error.params_summary["steering_angle"] == 15.0 and error.params_summary["x"] == 1.3


def test_misnamed_parameter_name_error_suggests_the_key(tmp_path):
    path = write(tmp_path, """
        def reward_function(params):
            track_width = params['track_width']
            distance_from_center = params['distance_from_center']
            if distance_from_centre < 0.1 * track_width:
                return 1.0
            return 0.1
        """)
    error = failure(load_reward_function(path), make_params())
    assert_names_location(error, path, 4)
    assert "NameError" in str(error) and "distance_from_center" in error.hint


def test_unknown_params_key_and_error_inside_a_helper(tmp_path):
    path = write(tmp_path, """
        import math

        def bonus(params):
            return math.sqrt(params['progress'] - 50.0)

        def reward_function(params):
            if params['is_left_of_centre']:
                return 1.0
            return bonus(params)
        """)
    reward_fn = load_reward_function(path)
    error = failure(reward_fn, make_params())
    assert_names_location(error, path, 7)
    assert "is_left_of_center" in error.hint
    # the failing line is the innermost one in the user's file, here inside the helper
    error = failure(reward_fn, make_params(is_left_of_centre=False))
    assert_names_location(error, path, 4)
    assert "ValueError" in str(error)


def test_raises_only_on_some_states(tmp_path):
    path = write(tmp_path, """
        def reward_function(params):
            steps = params['steps']
            return params['progress'] / steps
        """)
    reward_fn = load_reward_function(path)
    assert reward_fn(make_params()) == pytest.approx(12.5 / 7.0)
    error = failure(reward_fn, make_params(steps=0.0, x=4.25))
    assert_names_location(error, path, 3)
    assert "ZeroDivisionError" in str(error)
    assert error.params_summary["steps"] == 0.0 and "x=4.25" in str(error)


def test_system_exit_is_an_error_not_an_exit(tmp_path):
    path = write(tmp_path, "import sys\n\ndef reward_function(params):\n    sys.exit(1)\n")
    assert_names_location(failure(load_reward_function(path), make_params()), path, 4)


# -- bad return values --------------------------------------------------------------------------


@pytest.mark.parametrize("returned, why", [
    ("float('nan')", "not finite"), ("math.inf", "not finite"), ("1e9", "range"), ("-1e9", "range"),
    ("'a string'", "not a number"), ("None", "not a number"), ("[1.0]", "not a number"),
])
def test_bad_return_value_names_the_return_line(tmp_path, returned, why):
    path = write(tmp_path, f"""
        import math

        def reward_function(params):
            reward = 1.0
            if params['speed'] > 1.0:
                return {returned}
            return reward
        """)
    reward_fn = load_reward_function(path)
    assert reward_fn(make_params(speed=0.5)) == 1.0
    error = failure(reward_fn, make_params())
    assert_names_location(error, path, 6)
    assert why in str(error) and "returned" in str(error)


def test_missing_return_names_the_last_line_run(tmp_path):
    path = write(tmp_path, """
        def reward_function(params):
            if params['all_wheels_on_track']:
                reward = 1.0
            else:
                return 1e-3
        """)
    reward_fn = load_reward_function(path)
    assert reward_fn(make_params(all_wheels_on_track=False)) == 1e-3
    error = failure(reward_fn, make_params())
    assert_names_location(error, path, 3)
    assert "returned None" in str(error) and "without a return statement" in str(error)


def test_stateful_function_falls_back_to_the_def_line(tmp_path):
    path = write(tmp_path, """
        CALLS = []

        def reward_function(params):
            CALLS.append(1)
            return None if len(CALLS) == 1 else 1.0
        """)
    error = failure(load_reward_function(path), make_params())
    assert_names_location(error, path, 3)
    assert "starts at this line" in str(error)


def test_accepted_return_values_are_floats():
    for returned, expected in (("1", 1.0), ("True", 1.0), ("1e5", 1e5), ("-1e5", -1e5), ("'0.5'", 0.5),
                               ("np.float32(0.25)", 0.25)):
        reward_fn = load_reward_function(f"import numpy as np\ndef reward_function(params):\n    return {returned}\n")
        value = reward_fn(make_params())
        assert type(value) is float and value == expected


# -- waypoints ----------------------------------------------------------------------------------


def test_user_cannot_corrupt_the_shared_waypoints():
    reward_fn = load_reward_function(textwrap.dedent("""
        def reward_function(params):
            waypoints = params['waypoints']
            count = len(waypoints)
            waypoints.append((9.0, 9.0))
            waypoints.reverse()
            waypoints[0] = (7.0, 7.0)
            return float(count)
        """))
    shared = list(WAYPOINTS)
    for _ in range(3):
        assert reward_fn(make_params(waypoints=shared)) == len(WAYPOINTS)
    assert shared == WAYPOINTS
    rows = np.array(WAYPOINTS)  # an array, or lists as rows, are handed out as tuples
    assert reward_fn(make_params(waypoints=rows)) == len(WAYPOINTS)
    assert reward_fn(make_params(waypoints=[list(p) for p in WAYPOINTS])) == len(WAYPOINTS)
    np.testing.assert_array_equal(rows, np.array(WAYPOINTS))


# -- 2018 signature -----------------------------------------------------------------------------

LEGACY_RECORDER = """
RECEIVED = []

def reward_function({self_arg}on_track, x, y, distance_from_center, car_orientation, progress, steps,
                    throttle, steering, track_width, waypoints, closest_waypoint):
    RECEIVED.append(({self_name}on_track, x, y, distance_from_center, car_orientation, progress, steps,
                     throttle, steering, track_width, waypoints, closest_waypoint))
    return progress
"""


@pytest.mark.parametrize("with_self", [True, False])
def test_legacy_signature_is_called_positionally_with_converted_units(with_self):
    source = LEGACY_RECORDER.format(self_arg="self, " if with_self else "", self_name="self, " if with_self else "")
    reward_fn = load_reward_function(source, max_speed=4.0)
    assert reward_fn.is_legacy
    params = make_params(heading=90.0, progress=12.5, speed=2.0, steering_angle=-15.0, x=1.3, y=0.1)
    assert reward_fn(params) == pytest.approx(0.125)
    received = reward_fn.function.__globals__["RECEIVED"][-1]
    if with_self:
        assert received[0] is None
        received = received[1:]
    (on_track, x, y, dfc, orientation, progress, steps, throttle, steering, width, waypoints,
     closest) = received
    assert on_track is True and (x, y, dfc, steps, width) == (1.3, 0.1, 0.1, 7.0, 0.76)
    assert orientation == pytest.approx(math.pi / 2)
    assert progress == pytest.approx(0.125) and throttle == pytest.approx(0.5) and steering == pytest.approx(-0.5)
    assert waypoints == WAYPOINTS
    assert closest == 1  # (1.3, 0.1) is nearer waypoint 1 (1, 0) than waypoint 2 (2, 0)
    reward_fn(make_params(x=1.8))
    assert reward_fn.function.__globals__["RECEIVED"][-1][-1] == 2


def test_legacy_signature_recognised_by_count_and_max_speed_parameter():
    names = ", ".join(f"a{i}" for i in range(len(LEGACY_PARAMETERS)))
    reward_fn = load_reward_function(f"def reward_function({names}):\n    return a7\n", max_speed=2.0)
    assert reward_fn.is_legacy and reward_fn(make_params(speed=1.5)) == pytest.approx(0.75)


def test_legacy_error_names_the_line(tmp_path):
    path = write(tmp_path, """
        import math

        def reward_function(self, on_track, x, y, distance_from_center, car_orientation, progress, steps,
                            throttle, steering, track_width, waypoints, closest_waypoint):
            return math.abs(steering)
        """)
    reward_fn = load_reward_function(path)
    assert reward_fn.is_legacy
    assert_names_location(failure(reward_fn, make_params()), path, 5)


# -- timeouts -----------------------------------------------------------------------------------

NEVER_RETURNS = """
def reward_function(params):
    x = 0
    while x >= 0:
        x += 1
    return 1.0
"""

SWALLOWS_EVERYTHING = """
import time

def reward_function(params):
    while True:
        try:
            time.sleep(10)
        except:
            pass
"""


@pytest.mark.parametrize("method", ["signal", "process"])
@pytest.mark.parametrize("source, busy_line", [(NEVER_RETURNS, 4), (SWALLOWS_EVERYTHING, 7)],
                         ids=["endless-loop", "bare-except-swallows-timeout"])
def test_timeout_fires_and_names_the_busy_line(method, source, busy_line):
    reward_fn = load_reward_function(source)
    trace_before = sys.gettrace()
    handler_before = signal.getsignal(signal.SIGALRM)
    started = time.perf_counter()
    with pytest.raises(RewardFunctionError, match=r"did not return within 0.3 s") as caught:
        call_with_timeout(reward_fn, make_params(), 0.3, method=method)
    assert time.perf_counter() - started < 3.0
    assert caught.value.lineno == busy_line and caught.value.params_summary["x"] == 1.3
    assert sys.gettrace() is trace_before and signal.getsignal(signal.SIGALRM) is handler_before
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)


def test_timeout_from_a_worker_thread_uses_a_process():
    reward_fn = load_reward_function(NEVER_RETURNS)
    outcome = {}

    def run():
        started = time.perf_counter()
        try:
            call_with_timeout(reward_fn, make_params(), 0.3)
        except RewardFunctionError as error:
            outcome["error"], outcome["seconds"] = error, time.perf_counter() - started

    worker = threading.Thread(target=run)
    worker.start()
    worker.join(10.0)
    assert "error" in outcome and outcome["seconds"] < 3.0 and outcome["error"].lineno == 4


@pytest.mark.parametrize("method", ["signal", "process"])
def test_timeout_passes_values_and_errors_through(method):
    good = load_reward_function("def reward_function(params):\n    return params['speed'] / 4.0\n")
    assert call_with_timeout(good, make_params(), 1.0, method=method) == 0.5
    bad = load_reward_function("def reward_function(params):\n    return params['sped']\n")
    with pytest.raises(RewardFunctionError, match="line 2") as caught:
        call_with_timeout(bad, make_params(), 1.0, method=method)
    assert "speed" in caught.value.hint


def test_process_exit_without_result_is_reported():
    reward_fn = load_reward_function("import os\ndef reward_function(params):\n    os._exit(3)\n")
    with pytest.raises(RewardFunctionError, match=r"exited \(code 3\)"):
        call_with_timeout(reward_fn, make_params(), 1.0, method="process")
