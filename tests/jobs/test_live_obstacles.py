"""The console's live view of a race-type training: the boxes (once, in obstacles.json, then as an
``obstacles`` event) and the bots (every poses frame, each with the car whose episode it drives in),
and car 0's camera frame with the race's obstacles in it."""

from __future__ import annotations

import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from laplab.jobs.worker import JobFiles, LiveFeed
from laplab.sim.obstacles import BOT_CAR, BOX, EMPTY, Obstacles, footprint_rows, no_obstacles
from laplab.train.events import PosesFrame

TINY = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}


def two_cars_with(kind: int, moving_apart: bool) -> Obstacles:
    """Two cars, two slots each: the same two obstacles for both cars (or, ``moving_apart``, car 1's
    shifted 1 m), a third slot empty."""
    empty = no_obstacles(2, 3)
    x = np.array([[1.0, 2.0, 0.0], [1.0, 2.0, 0.0]]) + (np.array([[0.0], [1.0]]) if moving_apart else 0.0)
    kinds = np.array([[kind, kind, EMPTY], [kind, kind, EMPTY]])
    return empty._replace(x=x, y=np.full((2, 3), 0.5), yaw=np.full((2, 3), 0.25), half_length=np.full((2, 3), 0.2),
                          half_width=np.full((2, 3), 0.15), height=np.full((2, 3), 0.25), kind=kinds)


def test_standing_boxes_are_sent_once_for_all_cars_and_driving_bots_per_car():
    standing, driving = footprint_rows(two_cars_with(BOX, False), moving=False)
    assert standing == [[1.0, 0.5, 0.25, 0.2, 0.15, BOX], [2.0, 0.5, 0.25, 0.2, 0.15, BOX]] and driving == []
    standing, driving = footprint_rows(two_cars_with(BOT_CAR, True), moving=True)
    assert standing == []
    assert driving == [[0, 1.0, 0.5, 0.25, 0.2, 0.15, BOT_CAR], [0, 2.0, 0.5, 0.25, 0.2, 0.15, BOT_CAR],
                       [1, 2.0, 0.5, 0.25, 0.2, 0.15, BOT_CAR], [1, 3.0, 0.5, 0.25, 0.2, 0.15, BOT_CAR]]
    parked, _ = footprint_rows(two_cars_with(BOT_CAR, True), moving=False)  # object avoidance's parked cars
    assert len(parked) == 3  # 1, 2 (both cars) and 3 m
    assert footprint_rows(no_obstacles(4, 0), moving=True) == ([], [])


def train_with_live_feed(home, monkeypatch, folder, race_type: dict):
    """One tiny training iteration of a race type with the console's LiveFeed listening; returns the trainer."""
    from laplab.env.metadata import ModelMetadata
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    monkeypatch.setenv("LAPLAB_HOME", str(home))
    config = replace(TrainConfig(), hyperparameters={**TrainConfig().hyper().to_dict(), **TINY},
                     model_metadata=ModelMetadata().to_dict(), max_episodes=2, max_time_s=60, race_type=race_type)
    trainer = create_training(folder.name, config)
    folder.mkdir()
    files = JobFiles(folder)
    trainer.subscribe(LiveFeed(files, trainer))
    trainer.run()
    return trainer, files


def test_a_training_with_boxes_writes_them_once_and_its_bots_with_every_frame(tmp_path, monkeypatch):
    home = tmp_path / "home"
    trainer, files = train_with_live_feed(home, monkeypatch, tmp_path / "boxes", {
        "kind": "object_avoidance", "object_positions": [[0.3, 1], [0.6, -1]]})
    boxes = json.loads(files.obstacles.read_text())
    assert boxes["seq"] == 1  # fixed places: written once, the same for every car and episode
    field = trainer.sim.field.obstacles
    expected = sorted([round(float(field.x[0, k]), 3), round(float(field.y[0, k]), 3)] for k in range(2))
    assert sorted(b[:2] for b in boxes["boxes"]) == expected and {b[5] for b in boxes["boxes"]} == {BOX}
    assert json.loads(files.poses.read_text())["objects"] == []  # boxes stand: nothing per frame

    trainer, files = train_with_live_feed(home, monkeypatch, tmp_path / "bots", {
        "kind": "head_to_bot", "bots": 2, "bot_speed": 1.0})
    poses = json.loads(files.poses.read_text())
    objects = poses["objects"]
    assert len(objects) == 2 * len(poses["cars"]) and {o[6] for o in objects} == {BOT_CAR}
    assert {o[0] for o in objects} == set(range(len(poses["cars"])))  # each car's own bots
    assert json.loads(files.obstacles.read_text())["boxes"] == []


def test_a_time_trial_sends_no_obstacles(tmp_path):
    feed = LiveFeed(JobFiles(tmp_path), SimpleNamespace(metadata=SimpleNamespace(camera=None)))
    feed.on_poses(PosesFrame(1, np.zeros((2, 3)), 0.0))
    assert "objects" not in json.loads((tmp_path / "poses.json").read_text())
    assert not (tmp_path / "obstacles.json").exists()


def test_car_0s_camera_frame_shows_a_box_in_front_of_it(tmp_path):
    from PIL import Image

    from laplab.env.metadata import ModelMetadata
    from laplab.track.registry import load_track
    track = load_track("classic_2018")
    start, ahead = track.centerline[0], track.centerline[1]
    heading = float(np.arctan2(*(ahead - start)[::-1]))
    poses = np.array([[start[0], start[1], heading]])
    box = no_obstacles(1, 1)._replace(x=np.array([[start[0] + 0.8 * np.cos(heading)]]),
                                      y=np.array([[start[1] + 0.8 * np.sin(heading)]]), yaw=np.array([[heading]]),
                                      half_length=np.array([[0.2]]), half_width=np.array([[0.15]]),
                                      height=np.array([[0.25]]), kind=np.array([[BOX]]))
    model = SimpleNamespace(metadata=ModelMetadata(sensors=("FRONT_FACING_CAMERA",)), track=track)
    frames = []
    for name, obstacles in (("plain", None), ("box", box)):
        (tmp_path / name).mkdir()
        LiveFeed(JobFiles(tmp_path / name), model).on_poses(PosesFrame(1, poses, 0.0, obstacles=obstacles))
        frames.append(np.asarray(Image.open(tmp_path / name / "camera.png"), dtype=np.int16))
    changed = np.abs(frames[0] - frames[1]) > 10
    assert changed.mean() > 0.02  # the box covers part of the road ahead


def test_the_console_hub_sends_the_boxes_to_every_stream(tmp_path, monkeypatch):
    pytest.importorskip("fastapi")
    from laplab.console.service import ConsoleService
    from laplab.jobs.db import JobStore
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    store = JobStore(tmp_path / "console.db")
    try:
        admin, _ = store.add_user("admin", is_admin=True)
        job = store.add_job("train", "racer", admin.id, {})
        service = ConsoleService(store, SimpleNamespace(poll=lambda: []), workers=1)
        folder = tmp_path / "jobs" / str(job.id)
        folder.mkdir(parents=True)
        files = JobFiles(folder)
        files.write_obstacles({"seq": 1, "boxes": [[1.0, 2.0, 0.0, 0.2, 0.15, BOX]]})
        files.write_poses({"seq": 1, "cars": [[0.0, 0.0, 0.0]], "objects": []})
        service._tail(store.job(job.id))
        stream = service.hub.stream("racer")
        assert stream.obstacles_seq == 1 and stream.poses_seq == 1
        assert stream.obstacles_text.startswith("event: obstacles\n")
        assert json.loads(stream.obstacles_text.split("data: ", 1)[1])["boxes"] == [[1.0, 2.0, 0.0, 0.2, 0.15, BOX]]
        service._tail(store.job(job.id))  # unchanged files: nothing sent again
        assert stream.obstacles_seq == 1
    finally:
        store.close()


def test_rollout_workers_hand_their_obstacles_to_the_live_view(monkeypatch):
    """On Ray: each worker posts its cars' obstacles with its poses; the learner joins them in worker
    order (the first track's workers only)."""
    pytest.importorskip("ray")
    from laplab.cluster.collector import RayCollector
    from laplab.cluster.status import ProgressBoard
    board = ProgressBoard()
    first, second = two_cars_with(BOT_CAR, True), two_cars_with(BOT_CAR, False)
    board.post_poses(1, 4, np.ones((2, 3)), 2.0, second)
    board.post_poses(0, 4, np.zeros((2, 3)), 1.0, first)
    board.post_poses(2, 3, np.zeros((2, 3)), 1.0, first)  # an older iteration's: left out
    collector = RayCollector.__new__(RayCollector)
    collector.setups = [SimpleNamespace(track="oval")] * 3
    monkeypatch.setattr(collector, "_ask_board", lambda method, version: getattr(board, method)(version))
    poses, sim_time, obstacles = collector._read_poses(4)
    assert poses.shape == (4, 3) and sim_time == 2.0 and obstacles.kind.shape == (4, 3)
    assert np.array_equal(obstacles.x, np.concatenate([first.x, second.x]))
    board.post_poses(0, 5, np.zeros((2, 3)), 1.0)  # a time trial's worker posts none
    assert collector._read_poses(5)[2] is None
