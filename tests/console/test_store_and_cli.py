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
    # --no-sandbox: this test is about the token, not the sandbox (test_safe_default.py: the refusal)
    assert main(["users", "add", "dana", "--no-sandbox"]) == 0
    token = capsys.readouterr().out.strip().splitlines()[-1]
    assert JobStore().user_for_token(token).name == "dana"
    assert main(["users", "add", "dana", "--no-sandbox"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["users", "list"]) == 0
    assert "admin" in capsys.readouterr().out


def test_serve_refuses_no_accounts_on_a_public_address(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    assert main(["serve", "--host", "0.0.0.0", "--no-accounts"]) == 2
    assert "only with accounts" in capsys.readouterr().err
    assert main(["serve", "--workers", "0"]) == 2


def test_live_feed_publishes_poses_and_the_camera_frame_of_car_0(tmp_path):
    import json
    from types import SimpleNamespace

    import numpy as np
    from PIL import Image

    from laplab.env.metadata import ModelMetadata
    from laplab.jobs.worker import JobFiles, LiveFeed
    from laplab.track.registry import load_track
    from laplab.train.events import PosesFrame
    track = load_track("classic_2018")
    start = track.centerline[0]
    heading = np.arctan2(*(track.centerline[1] - start)[::-1])
    poses = np.array([[start[0], start[1], heading], [start[0] + 1.0, start[1], 0.0]])
    camera_model = SimpleNamespace(metadata=ModelMetadata(sensors=("FRONT_FACING_CAMERA",)), track=track)
    feed = LiveFeed(JobFiles(tmp_path), camera_model)
    feed.on_poses(PosesFrame(iteration=1, poses=poses, sim_time=0.0))
    cars = json.loads((tmp_path / "poses.json").read_text())["cars"]
    assert cars == [[round(float(v), 3) for v in pose] for pose in poses]
    frame = np.asarray(Image.open(tmp_path / "camera.png"))
    assert frame.shape == (120, 160) and frame.std() > 5  # the road seen from the start line, not a blank
    state_model = SimpleNamespace(metadata=ModelMetadata(), track=track)
    LiveFeed(JobFiles(tmp_path / "state"), state_model)  # no camera: nothing to render
