"""Issue 31: the reward check before a job runs its calls in a child process, so a reward function
that ignores SIGALRM and loops, kills or aborts its process, exits or closes stdout fails the check
with its file and line, and leaves the caller (its signals, its output) as it was."""

import os
import signal
import time

import pytest

from laplab.reward.loader import load_reward_function
from laplab.reward.validate import validate_reward_function

HEADER = "import os, signal, sys\n\ndef reward_function(params):\n"


def _check(tmp_path, body, circle_track, timeout_s=1.0):
    path = tmp_path / "reward_function.py"
    path.write_text(HEADER + "".join(f"    {line}\n" for line in body.splitlines()))
    report = validate_reward_function(load_reward_function(path), circle_track, [(0.0, 1.0)],
                                      timeout_s=timeout_s, isolate=True)
    assert not report.passed
    return path, report.error


def test_a_function_that_ignores_sigalrm_and_loops_is_stopped(tmp_path, circle_track):
    handler = signal.getsignal(signal.SIGALRM)
    started = time.monotonic()
    path, error = _check(tmp_path, "signal.signal(signal.SIGALRM, signal.SIG_IGN)\nwhile True:\n    pass",
                         circle_track)
    assert time.monotonic() - started < 15
    assert error.path == str(path) and error.lineno in (5, 6) and "did not return within 1 s" in str(error)
    assert error.params_summary and signal.getsignal(signal.SIGALRM) is handler


@pytest.mark.parametrize("body, line, words", [
    ("os.kill(os.getpid(), signal.SIGKILL)", 4, "SIGKILL"),
    ("os._exit(3)", 4, "os._exit(3)"),
    ("import posix\nposix._exit(0)", 5, "posix._exit(0)"),
    ("os.close(1)", 4, "standard output"),
    ("sys.stdout.flush()\nos.dup2(os.open(os.devnull, os.O_RDONLY), 2)", 5, "standard error"),
    ("import ctypes\nctypes.string_at(0)", 5, "SIGSEGV"),
])
def test_a_function_that_ends_its_process_is_named_with_its_line(tmp_path, circle_track, body, line, words):
    path, error = _check(tmp_path, body, circle_track)
    if words == "SIGSEGV":
        # a crash's line comes from faulthandler's dump, written from the signal handler: in a long
        # pytest session (after Ray, torch and TensorFlow loaded their own handlers) it can be missing
        assert error.path == str(path) and error.lineno in (line, None), str(error)
    else:
        assert error.path == str(path) and error.lineno == line, str(error)
    assert words in str(error)
    os.fstat(1), os.fstat(2)  # the caller's streams are open


def test_a_second_sigterm_interrupts_instead_of_deadlocking():
    from laplab.commands.train import _StopFlag
    with _StopFlag() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)
        assert stop.event.is_set()
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1.0)


def test_train_refuses_a_hanging_reward_before_writing_anything(tmp_path, monkeypatch, capsys):
    from laplab.cli import main
    from laplab.store.layout import model_folder
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    reward = tmp_path / "hang.py"
    reward.write_text(HEADER + "    signal.signal(signal.SIGALRM, signal.SIG_IGN)\n    while True:\n        pass\n")
    started = time.monotonic()
    assert main(["train", "--name", "hang", "--reward", str(reward), "--max-time", "5s"]) == 2
    assert time.monotonic() - started < 60
    err = capsys.readouterr().err
    assert f"{reward}, line" in err and "Traceback" not in err
    assert not model_folder("hang").exists()
