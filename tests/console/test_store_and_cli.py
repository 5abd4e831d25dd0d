"""The job store (SQLite in WAL mode, hashed tokens, restart semantics) and the `serve` / `users`
commands' checks, without a server."""

from __future__ import annotations

import pytest

from laplab.cli import main
from laplab.jobs.db import JobStore, StoreError


def test_store_is_wal_and_interrupts_running_jobs_at_start(tmp_path):
    store = JobStore(tmp_path / "laplab.db")
    assert store._rows("PRAGMA journal_mode")[0][0] == "wal"
    user, token = store.add_user("teacher", is_admin=True)
    assert store.user_for_token(token) == user and store.user_for_token(token + "x") is None
    assert store.user_for_token("") is None
    with pytest.raises(StoreError, match="already exists"):
        store.add_user("teacher")
    with pytest.raises(StoreError, match="invalid user name"):
        store.add_user("no spaces")
    running = store.add_job("train", "m1", user.id, {})
    queued = store.add_job("train", "m2", user.id, {})
    store.update_job(running.id, status="running")
    store.close()
    reopened = JobStore(tmp_path / "laplab.db")
    assert [j.id for j in reopened.interrupt_running()] == [running.id]
    assert reopened.job(running.id).status == "interrupted" and reopened.job(queued.id).status == "queued"
    assert reopened.integrity_ok()
    session = reopened.new_session(user.id)
    assert reopened.user_for_session(session) == user
    reopened.end_session(session)
    assert reopened.user_for_session(session) is None


def test_users_add_prints_a_token_that_logs_in(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    monkeypatch.delenv("LAPLAB_ADMIN_TOKEN", raising=False)
    assert main(["users", "add", "dana"]) == 0
    token = capsys.readouterr().out.strip().splitlines()[-1]
    assert JobStore().user_for_token(token).name == "dana"
    assert main(["users", "add", "dana"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["users", "list"]) == 0
    assert "admin" in capsys.readouterr().out


def test_serve_refuses_no_accounts_on_a_public_address(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    assert main(["serve", "--host", "0.0.0.0", "--no-accounts"]) == 2
    assert "only with accounts" in capsys.readouterr().err
    assert main(["serve", "--workers", "0"]) == 2


def test_camera_frame_picks_the_newest_frame_of_the_first_car(tmp_path):
    import numpy as np
    from PIL import Image

    from laplab.jobs.worker import JobFiles, camera_frame
    stack = np.zeros((4, 3, 120, 160), dtype=np.uint8)
    stack[0, -1, 10:20, 30:40] = 200
    frame = camera_frame(stack)
    assert frame.shape == (120, 160) and frame[15, 35] == 200
    assert camera_frame({"FRONT_FACING_CAMERA": stack, "LIDAR": np.zeros((4, 64), np.float32)})[15, 35] == 200
    assert camera_frame(np.zeros((4, 30), np.float32)) is None  # STATE or lidar only
    JobFiles(tmp_path).write_camera(frame)
    assert np.asarray(Image.open(tmp_path / "camera.png"))[15, 35] == 200
