"""The supervisor: however a training job dies, `laplab train` says so, writes error.txt and exits non-zero;
a reward function that hangs, exits or floods the terminal ends (or is capped) with a clear message."""

from __future__ import annotations

import signal
import time

import pytest

from laplab.jobs.supervisor import JobLimits, parse_memory_limit, run_supervised
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import model_folder
from laplab.store.lock import is_locked

TRIGGERED = '''
import os, sys, signal, time
TRIGGER = {trigger!r}

def reward_function(params):
    if os.path.exists(TRIGGER):
{body}
    return 1.0
'''


def _checkpointed(folder) -> bool:
    """Iteration 1's files are written: a simtrace and a checkpoint after checkpoint 0."""
    if not folder.list_training_iterations() or not folder.deepracer_checkpoints.exists():
        return False
    last = CheckpointStore(folder).last()
    return last is not None and last.name != "0_Step-0.ckpt"


def start_job(laplab_cli, tmp_path, tiny_hp, name, body, *extra):
    trigger = tmp_path / f"{name}.go"
    reward = tmp_path / f"{name}.py"
    reward.write_text(TRIGGERED.format(trigger=str(trigger), body="\n".join("        " + b for b in body.splitlines())))
    proc = laplab_cli("train", "--name", name, "--reward", reward, "--hyperparameters", tiny_hp,
                      "--max-time", "10m", "--quiet", *extra)
    folder = model_folder(name)
    deadline = time.time() + 150
    # an iteration's files are written on the folder's writer thread while the next one runs: wait for
    # its checkpoint (written after its simtrace), which a process killed outright keeps
    while time.time() < deadline and not _checkpointed(folder):
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.2)
    trigger.write_text("go")
    out, err = proc.communicate(timeout=150)
    return proc.returncode, out.decode(), " ".join(err.decode().split()), folder


@pytest.mark.parametrize("body, expect", [
    ("import posix; posix._exit(0)", "ended with exit code 0 without finishing"),
    ("os.kill(os.getpid(), signal.SIGKILL)", "was killed by SIGKILL"),
    ("import ctypes; ctypes.string_at(0)", "crashed (segmentation fault)"),
])
def test_a_job_that_dies_is_reported_and_exits_non_zero(laplab_cli, tmp_path, tiny_hp, body, expect):
    code, out, err, folder = start_job(laplab_cli, tmp_path, tiny_hp, "dies", body)
    assert code != 0
    assert expect in err and "training job of model 'dies'" in err and "finished iteration" in err, err
    assert "laplab train --resume dies" in err and "Traceback" not in err
    assert expect in folder.read_error()
    assert "dies.py, line 7" in err, err  # where it crashed, exited or sent itself the signal
    assert not is_locked(folder.root)
    assert CheckpointStore(folder).last().name != "0_Step-0.ckpt"  # the checkpoints are kept


def test_os_exit_in_the_reward_function_is_a_reward_function_error(laplab_cli, tmp_path, tiny_hp):
    code, out, err, folder = start_job(laplab_cli, tmp_path, tiny_hp, "exits", "os._exit(0)")
    assert code == 1
    assert "os._exit(0) was called" in err + out and "exits.py, line 7" in folder.read_error()


def test_a_hanging_reward_function_ends_the_job_with_its_line_and_params(laplab_cli, tmp_path, tiny_hp):
    body = "while True:\n    try:\n        pass\n    except BaseException:\n        pass"
    started = time.time()
    code, out, err, folder = start_job(laplab_cli, tmp_path, tiny_hp, "hangs", body, "--reward-timeout", "1")
    assert code == 1, err
    error = folder.read_error()
    assert "did not return within 1 s of CPU time" in error and "hangs.py, line" in error
    assert "Params of the failing step: x=" in error
    assert time.time() - started < 150
    assert CheckpointStore(folder).last().name != "0_Step-0.ckpt"


def test_a_reward_function_that_waits_forever_is_stopped(tmp_path, tiny_config):
    # The CPU limit cannot see a call blocked in sleep: the waiting limit does (shortened here).
    from laplab.commands.train import run_trainer
    from laplab.jobs import supervisor
    from laplab.train.jobs import create_training
    reward = tmp_path / "sleeps.py"
    reward.write_text(TRIGGERED.format(trigger=str(tmp_path / "sleeps.go"), body="        time.sleep(3600)"))
    trainer = create_training("sleeps", tiny_config(reward_path=str(reward), max_episodes=40))
    (tmp_path / "sleeps.go").write_text("go")
    from rich.console import Console
    limits = JobLimits(reward_timeout_s=1.0, reward_wait_timeout_s=2.0)

    def job():
        supervisor._child["limits"] = limits
        return run_trainer(trainer, Console(), quiet=True)
    try:
        assert job() == 1
    finally:
        supervisor._child["limits"] = None
    assert "2 s of waiting" in trainer.folder.read_error()


def test_reward_output_is_capped_on_the_terminal_and_kept_in_the_log(laplab_cli, tmp_path, tiny_hp):
    body = "for i in range(10000):\n    print('line', i)\nos.remove(TRIGGER)"
    proc_code, out, err, folder = start_job(laplab_cli, tmp_path, tiny_hp, "chatty",
                                            body + "\nraise ValueError('enough')")
    shown = out.count("line ")
    assert shown <= 100, shown
    log = (folder.root / "logs" / "reward-output.log").read_text()
    assert log.count("line ") >= 10000 and "line 9999" in log
    assert "were not shown here" in err and "reward-output.log" in err


def test_memory_limit_parsing():
    assert parse_memory_limit("4G") == 4 << 30
    assert parse_memory_limit("512M") == 512 << 20
    assert parse_memory_limit("none") is None
    assert parse_memory_limit("50%") > 0
    for bad in ("lots", "10K", "150%"):
        with pytest.raises(ValueError):
            parse_memory_limit(bad)


def test_memory_limit_fails_the_job_not_the_machine():
    def job():  # a runaway allocation under a 1 GiB limit
        blocks = []
        while True:
            blocks.append(bytearray(64 << 20))
    # A forked child starts with this process's resident pages (a long pytest session may hold GBs),
    # so its growth is what the limit bounds.
    resident_at_fork = _resident_bytes()
    outcome = run_supervised(job, JobLimits(memory_bytes=1 << 30), echo=False)
    assert outcome.exit_code != 0 and not outcome.clean
    assert outcome.max_rss_bytes - resident_at_fork < 1.5 * (1 << 30)


def _resident_bytes() -> int:
    """This process's resident memory now (Linux /proc)."""
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmRSS in /proc/self/status")


def test_run_supervised_argv_reports_a_clean_exit_and_stops_on_request(laplab_home, tiny_hp):
    outcome = run_supervised(["tracks", "list"], JobLimits(), echo=False)
    assert outcome.clean and outcome.exit_code == 0
    outcome = run_supervised(["train", "--name", "lib", "--hyperparameters", str(tiny_hp), "--quiet"],
                             JobLimits(), should_stop=lambda: model_folder("lib").list_training_iterations() != [],
                             echo=False)
    assert outcome.clean and outcome.exit_code == 0, outcome
    assert outcome.folder == model_folder("lib").root and outcome.iteration >= 1


def test_sigint_to_the_supervisor_stops_the_job_cleanly(laplab_cli, tiny_hp):
    proc = laplab_cli("train", "--name", "intr", "--hyperparameters", tiny_hp, "--max-time", "10m", "--quiet")
    folder = model_folder("intr")
    deadline = time.time() + 150
    # an iteration's files are written on the folder's writer thread while the next one runs: wait for
    # its checkpoint (written after its simtrace), which a process killed outright keeps
    while time.time() < deadline and not _checkpointed(folder):
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=150)
    assert proc.returncode == 0, err
    assert b"stopped on request" in out and folder.read_error() is None
