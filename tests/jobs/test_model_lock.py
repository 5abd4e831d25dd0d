"""One job per model folder: a second trainer fails at once naming the holder; a SIGKILL leaves no stale lock."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from laplab.store.layout import model_folder
from laplab.store.lock import ModelBusyError, ModelLock, is_locked, read_holder


def test_lock_is_exclusive_and_names_its_holder(tmp_path):
    first = ModelLock(tmp_path).acquire(command="laplab train --name x")
    with pytest.raises(ModelBusyError) as error:
        ModelLock(tmp_path).acquire()
    message = str(error.value)
    assert f"process {os.getpid()}" in message and "laplab train --name x" in message and "since" in message
    first.release()
    ModelLock(tmp_path).acquire().release()


def test_a_killed_holder_leaves_no_stale_lock(tmp_path):
    code = ("import sys, time; from laplab.store.lock import ModelLock; "
            f"lock = ModelLock({str(tmp_path)!r}).acquire(); print('held', flush=True); time.sleep(60)")
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    assert child.stdout.readline().strip() == b"held"
    assert is_locked(tmp_path) and read_holder(tmp_path).pid == child.pid
    child.send_signal(signal.SIGKILL)
    child.wait(10)
    assert not is_locked(tmp_path)
    ModelLock(tmp_path).acquire().release()


def test_second_resume_of_a_training_model_fails_at_once(laplab_cli, tiny_hp, tmp_path):
    first = laplab_cli("train", "--name", "twice", "--hyperparameters", tiny_hp, "--max-time", "10m", "--quiet")
    folder = model_folder("twice")
    deadline = time.time() + 120
    while time.time() < deadline and not folder.list_training_iterations():
        time.sleep(0.2)
    try:
        for args in (("--resume", "twice"), ("--name", "twice")):
            started = time.time()
            second = laplab_cli("train", *args, "--max-time", "10m", "--quiet")
            out, err = second.communicate(timeout=120)
            assert second.returncode != 0
            text = " ".join(err.decode().split())
            assert "twice" in text and "Traceback" not in text
            if args[0] == "--resume":
                assert "being trained by another job" in text and "(laplab train --name twice" in text, text
            else:
                assert "already exists" in text, text
            assert time.time() - started < 60
        # Readers take no lock and read a consistent checkpoint while the job trains and prunes (all
        # three at once).
        readers = [laplab_cli("evaluate", "twice", "--trials", "1", "--checkpoint", which) for which in ("last", "best")]
        exporter = laplab_cli("export", "twice", "--checkpoint", "last", "--out", tmp_path / "twice.tar.gz")
        for reader in readers:
            out, err = reader.communicate(timeout=150)
            assert reader.returncode == 0, err.decode()
        out, err = exporter.communicate(timeout=150)
        assert exporter.returncode == 0, err.decode()
        importer = laplab_cli("import", tmp_path / "twice.tar.gz", "--name", "copy")
        assert importer.wait(150) == 0, importer.stderr.read().decode()
        assert first.poll() is None  # the first job is untouched
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=120)
    assert first.returncode == 0
    assert not is_locked(folder.root)
