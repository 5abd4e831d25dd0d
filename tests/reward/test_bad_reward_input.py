"""Issue 31, bad input: reward functions that fail in unusual ways get a RewardFunctionError
naming the file and line, never a traceback or a message that blames the user's Ctrl-C."""

import pytest

from laplab.cli import main
from laplab.reward.errors import RewardFunctionError
from laplab.reward.loader import load_reward_function

PARAMS = {"x": 0.0, "y": 0.0, "speed": 1.0, "steps": 1}


def _write(tmp_path, text):
    path = tmp_path / "reward_function.py"
    path.write_text(text)
    return path


def test_returned_object_whose_float_raises(tmp_path):
    path = _write(tmp_path, "class R:\n    def __float__(self):\n        raise RuntimeError('nope')\n"
                            "def reward_function(params):\n    return R()\n")
    with pytest.raises(RewardFunctionError) as info:
        load_reward_function(path)(PARAMS)
    assert info.value.lineno == 5 and str(path) in str(info.value)
    assert "float() of it raised RuntimeError: nope" in str(info.value)


def test_reward_raising_keyboard_interrupt_is_a_reward_error(tmp_path):
    path = _write(tmp_path, "def reward_function(params):\n    raise KeyboardInterrupt\n")
    with pytest.raises(RewardFunctionError) as info:
        load_reward_function(path)(PARAMS)
    assert info.value.lineno == 2 and "KeyboardInterrupt" in str(info.value)


def test_keyboard_interrupt_at_the_top_level_is_a_load_error(tmp_path):
    path = _write(tmp_path, "raise KeyboardInterrupt()\ndef reward_function(params):\n    return 1.0\n")
    with pytest.raises(RewardFunctionError) as info:
        load_reward_function(path)
    assert info.value.lineno == 1


def test_a_real_interrupt_during_the_call_stays_an_interrupt(tmp_path):
    # _thread.interrupt_main() raises KeyboardInterrupt as SIGINT does (at the loop, not a `raise`)
    path = _write(tmp_path, "import _thread\ndef reward_function(params):\n    _thread.interrupt_main()\n"
                            "    for i in range(10 ** 6):\n        pass\n    return 1.0\n")
    with pytest.raises(KeyboardInterrupt):
        load_reward_function(path)(PARAMS)


def test_reward_validate_refuses_a_bad_timeout(tmp_path, capsys):
    path = _write(tmp_path, "def reward_function(params):\n    return 1.0\n")
    for value in ("0", "-1", "nan"):
        assert main(["reward", "validate", str(path), "--timeout", value]) == 2
        err = capsys.readouterr().err
        assert "--timeout" in err and "Traceback" not in err


def test_reward_validate_cli_reports_keyboard_interrupt_with_its_line(tmp_path, capsys):
    path = _write(tmp_path, "def reward_function(params):\n    raise KeyboardInterrupt\n")
    assert main(["reward", "validate", str(path)]) == 1
    out = capsys.readouterr().out
    assert f"{path}, line 2" in out and "interrupted" not in out


def test_train_names_a_keyboard_interrupt_raised_by_the_reward(tmp_path, monkeypatch, capsys):
    from laplab.store.layout import model_folder
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    path = _write(tmp_path, "def reward_function(params):\n    raise KeyboardInterrupt\n")
    assert main(["train", "--name", "kbi", "--reward", str(path), "--max-time", "5s"]) == 2
    err = capsys.readouterr().err
    assert f"{path}, line 2" in err and "interrupted" not in err
    assert not model_folder("kbi").exists()
