"""Rollout workers on a real local Ray (one per module, 2 CPUs, tiny budgets): a 2-track job whose
PPO batches are all of the current policy version, worker deaths (a reward function that calls
os._exit, an actor killed mid-collection) restarted within the iteration, resume with another
worker count, and a raising reward function's usual error paragraph."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from dataclasses import replace

import numpy as np
import pytest

ray = pytest.importorskip("ray")

from laplab.cluster.collector import connect_ray  # noqa: E402
from laplab.cluster.launch import RayWorkers  # noqa: E402
from laplab.cluster.status import read_workers  # noqa: E402
from laplab.env.metadata import ModelMetadata  # noqa: E402
from laplab.store.layout import model_folder  # noqa: E402
from laplab.train.config import TrainConfig  # noqa: E402
from laplab.train.jobs import create_training, resume_training  # noqa: E402

SMALL_HP = {"num_episodes_between_training": 4, "batch_size": 32, "num_epochs": 3}
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope="module")
def local_ray():
    assert connect_ray(None, 2)  # laplab's own local Ray, as `laplab train --workers 2` starts it
    yield
    ray.shutdown()


@pytest.fixture(autouse=True)
def laplab_home(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    return tmp_path / "home"


def small_config(**changes) -> TrainConfig:
    hyper = {**TrainConfig().hyper().to_dict(), **SMALL_HP}
    return replace(TrainConfig(), hyperparameters=hyper, model_metadata=ModelMetadata().to_dict(),
                   max_time_s=300, **changes)


def reward_file(tmp_path, body: str) -> str:
    path = tmp_path / "reward_function.py"
    lines = ["import os", f"DRIVER = {os.getpid()}  # the learner's process: evaluation runs there",
             "IN_WORKER = lambda: DRIVER not in (os.getpid(), os.getppid())  # nor the reward check's child",
             "", "", "def reward_function(params):", textwrap.indent(textwrap.dedent(body), "    ").rstrip(),
             "    return 1.0", ""]
    path.write_text("\n".join(lines))
    return str(path)


def test_two_track_job_trains_on_policy_and_writes_each_workers_simtrace(local_ray):
    config = small_config(tracks=("classic_2018", "classic_2018@reversed"), workers=2, max_episodes=8)
    trainer = create_training("two-tracks", config, launcher=RayWorkers())  # both workers start with the folder
    versions_seen = []
    learn = trainer.learner.learn

    def checked_learn(batch, *args, **kwargs):  # every transition of every PPO batch: the current version
        per_step = np.broadcast_to(batch.policy_version, batch.valid.shape)[batch.valid]
        versions_seen.append((trainer.iteration, set(per_step.tolist())))
        return learn(batch, *args, **kwargs)
    trainer.learner.learn = checked_learn
    reports, frames = [], []

    class LiveView:  # the console's car view: the workers' cars while they collect
        def on_poses(self, frame):
            frames.append(frame)
    trainer.subscribe(LiveView())
    assert len(trainer.collector.actors) == 2 and trainer.evaluator is not None  # every track is evaluated
    with trainer:
        result = trainer.run(callbacks=(reports.append,))
    assert result.error is None and result.iterations == 2 and result.episodes == 8
    assert versions_seen == [(0, {0}), (1, {1})]
    # both workers drive classic_2018 (one reversed): their 2 + 2 cars, in world coordinates of that track
    assert frames and {f.iteration for f in frames} <= {1, 2} and {len(f.poses) for f in frames} <= {2, 4}
    assert any(len(f.poses) == 4 for f in frames)
    track = trainer.track
    xy = np.concatenate([f.poses[:, :2] for f in frames])
    assert np.isfinite(xy).all()
    border = np.concatenate([track.inner, track.outer])
    assert (xy.min(0) > border.min(0) - 1.0).all() and (xy.max(0) < border.max(0) + 1.0).all()  # off-track cars stop
    assert set(reports[-1].eval_progress_by_track) == {"classic_2018", "classic_2018@reversed"}
    folder = model_folder("two-tracks")
    assert not folder.training_simtrace_dir.exists()  # deepracer-utils' multi-worker layout
    assert folder.simtrace_workers() == [0, 1] and folder.list_training_iterations() == [0, 1]
    assert json.loads(folder.laplab_config.read_text())["tracks"] == ["classic_2018", "classic_2018@reversed"]
    logs = pytest.importorskip("deepracer.logs")
    log = logs.DeepRacerLog(model_folder=str(folder.root))
    assert log.fh.type == logs.LogFolderType.DRFC_MODEL_MULTIPLE_WORKERS
    log.load_training_trace()
    assert sorted(log.dataframe()["worker"].unique().tolist()) == [0, 1]


def test_dead_workers_are_restarted_and_the_job_resumes_with_one_worker(local_ray, tmp_path):
    marker = tmp_path / "crashed-once"
    path = reward_file(tmp_path, f"""\
        if IN_WORKER():
            try:  # O_EXCL: of two workers asking at once, exactly one creates the marker
                os.close(os.open({str(marker)!r}, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            except FileExistsError:
                pass
            else:
                os._exit(3)  # the reward function takes its worker's process down, once
        """)
    notices, killed, polls = [], [], []
    trainer = create_training("faults", small_config(reward_path=path, workers=2, max_episodes=8),
                              launcher=RayWorkers(notify=notices.append))

    def kill_during_second_collection():  # polled before each iteration, then while collecting
        if trainer.iteration == 1:
            polls.append(1)
            if len(polls) == 2:  # the first poll of the collection: worker 0's task is in flight
                ray.kill(trainer.collector.actors[0], no_restart=True)
                killed.append(True)
        return False
    with trainer:
        result = trainer.run(should_stop=kill_during_second_collection)
        restarts = list(trainer.collector.restarts)
    assert result.error is None and result.iterations == 2 and result.episodes == 8, result
    assert marker.exists() and killed
    assert len(notices) == 2 and all("restarted it, collecting its 2 episodes again" in n for n in notices)
    assert sum(restarts) == 2
    rows = read_workers(model_folder("faults").root, last_iteration=2)  # what the console's model page shows
    assert [r["restarts"] for r in rows] == restarts and [r["state"] for r in rows] == ["stopped", "stopped"]
    assert all(r["cause"] for r in rows if r["restarts"]) and [r["episodes"] for r in rows] == [4, 4]
    log = (model_folder("faults").root / "logs" / "workers.log").read_text().splitlines()
    assert len(log) == 2 and all(line.endswith(notice) for line, notice in zip(log, notices))
    # a dead learner leaves its last checkpoint: resume it with one worker, which collects in-process
    with resume_training("faults", max_episodes=12, workers=1, launcher=RayWorkers()) as again:
        assert again.iteration == 2 and again.collector is None and again.evaluator is None
        assert again.run().iterations == 3
    folder = model_folder("faults")
    assert json.loads(folder.laplab_config.read_text())["workers"] == 1
    assert folder.simtrace_workers() == [0, 1] and folder.list_training_iterations() == [0, 1, 2]
    assert folder.worker_training_simtrace(0, 2).is_file()  # once multi-worker, always
    assert read_workers(folder.root, last_iteration=3) == []  # the last session collected in-process


def test_a_raising_reward_function_is_the_usual_error_not_a_restart(local_ray, tmp_path):
    path = reward_file(tmp_path, """\
        if IN_WORKER() and params["steps"] > 3:
            raise KeyError("no such param")
        """)
    notices = []
    with create_training("raises", small_config(reward_path=path, workers=2, max_episodes=8),
                         launcher=RayWorkers(notify=notices.append)) as trainer:
        result = trainer.run()
    assert result.stop_reason == "reward_error" and notices == []
    assert "reward_function.py" in result.error and "KeyError" in result.error and "line 8" in result.error
    assert "Traceback" not in result.error
    assert model_folder("raises").error_file.read_text().strip() == result.error.strip()


def test_workers_1_never_imports_ray_and_an_unreachable_cluster_is_one_paragraph(tmp_path):
    env = {**os.environ, "LAPLAB_HOME": str(tmp_path / "home"), "PYTHONPATH": REPO}
    hyper = tmp_path / "hp.json"
    hyper.write_text(json.dumps({**TrainConfig().hyper().to_dict(), **SMALL_HP}))
    script = ("import sys; from laplab.cli import main; "
              f"code = main(['train', '--name', 'solo', '--hyperparameters', {str(hyper)!r}, '--max-episodes', '4', "
              "'--quiet', '--memory-limit', 'none']); "
              "print('RAY' if 'ray' in sys.modules else 'NO-RAY', code)")
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=240)
    assert done.stdout.strip().splitlines()[-1] == "NO-RAY 0", done.stdout + done.stderr
    cli = "import sys; from laplab.cli import main; sys.exit(main(sys.argv[1:]))"
    closed = subprocess.run([sys.executable, "-c", cli, "train", "--name", "far", "--workers", "2",
                             "--ray-address", "127.0.0.1:9", "--memory-limit", "none"],
                            env=env, capture_output=True, text=True, timeout=120)
    assert closed.returncode != 0 and "cannot reach the Ray cluster at 127.0.0.1:9" in closed.stderr + closed.stdout
    assert "Traceback" not in closed.stderr and not (tmp_path / "home" / "models" / "far").exists()
