"""Fault injection: SIGKILL a training job at random moments, 10 times across resumes; the model folder
must stay loadable (resume, evaluate) and every simtrace row must be unique."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import time

from laplab.cli import main
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import model_folder
from laplab.store.simtrace import read_simtrace
from laplab.train.checkpoint_read import read_checkpoint

KILLS = 10


def test_ten_sigkills_across_resumes_leave_a_loadable_folder(laplab_cli, tiny_hp):
    rng = random.Random(11)
    folder = model_folder("fault")
    kills = 0
    while kills < KILLS:
        args = (["--resume", "fault"] if folder.exists() else ["--name", "fault", "--hyperparameters", tiny_hp])
        proc = laplab_cli("train", *args, "--max-time", "10m", "--quiet", start_new_session=True,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        if kills % 4 == 3:  # anywhere, start-up and validation included
            time.sleep(rng.uniform(0.2, 3.0))
        else:  # once the job has finished an iteration: collection, learning, writing logs, saving ...
            done = len(folder.list_training_iterations()) if folder.exists() else 0
            deadline = time.time() + 60
            while time.time() < deadline and len(folder.list_training_iterations()) <= done:
                assert proc.poll() is None, proc.stderr.read().decode()
                time.sleep(0.02)
            time.sleep(rng.uniform(0.0, 1.0))
        if proc.poll() is not None:
            raise AssertionError(f"the job ended by itself: {proc.stderr.read().decode()}")
        os.killpg(proc.pid, signal.SIGKILL)  # the supervisor and the job at once, as a crash would
        proc.wait(30)
        proc.stderr.close()
        kills += 1
    assert folder.exists(), "ten kills and the model was never created"
    last = CheckpointStore(folder).last()
    name, state = read_checkpoint(folder, "last")
    assert name == last.name and state["iteration"] == int(name.split("_")[0])
    # Resume once more to the end: the folder is loadable and the iteration count continues.
    target = state["episodes"] + 4
    assert main(["train", "--resume", "fault", "--max-episodes", str(target), "--quiet"]) == 0
    _, final = read_checkpoint(folder, "last")
    assert final["episodes"] == target and final["iteration"] == state["iteration"] + 2
    iterations = folder.list_training_iterations()
    assert iterations == list(range(final["iteration"]))
    rows = set()
    total = 0
    for iteration in iterations:
        trace = read_simtrace(folder.training_simtrace(iteration))
        keys = set(zip(trace["episode"].tolist(), trace["steps"].tolist()))
        total += len(trace["episode"])
        rows |= keys
    assert len(rows) == total, f"{total - len(rows)} simtrace rows were written twice"
    episodes = sorted({e for e, _ in rows})
    assert episodes == list(range(target))
    assert main(["evaluate", "fault", "--trials", "1", "--checkpoint", "last"]) == 0
