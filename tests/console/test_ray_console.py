"""A console whose training jobs run their rollout workers on a Ray cluster (``laplab serve
--ray-address``), with one real cluster for the module: ``ray start --head --block`` on 127.0.0.1
(its own temp folder and ports, 2 CPUs), joined through Ray Client as a sandboxed job joins it.

- the Ray path reports the collection's progress while the workers drive, and the model folder's
  ``logs/workers.json`` follows the workers (in the test's process, as `laplab train --workers 2`);
- a console job on a server with the cluster trains with 2 workers; the model's API shows them;
- bubblewrap without ``--share-net`` cannot reach the cluster (so only such jobs get the network);
- bad addresses and worker counts are one paragraph, never a traceback;
- a race submission's evaluation drives its lap on the cluster and ranks as a local one.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import textwrap
import time
from dataclasses import replace
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

from laplab.cluster.console import RayCluster, check_console_cluster, job_worker_count  # noqa: E402
from laplab.cluster.status import read_workers, workers_file  # noqa: E402
from laplab.jobs.confinement import Mounts, bubblewrap_works, clean_environment, confined_command  # noqa: E402
from laplab.train.errors import JobError  # noqa: E402

from tests.console.conftest import free_port, numba_seed  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
SMALL_HP = {"num_episodes_between_training": 4, "batch_size": 32, "num_epochs": 3}


def _listening(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1.0):
            return True
    except OSError:
        return False


@pytest.fixture(scope="module")
def ray_head(tmp_path_factory):
    """A one-node Ray cluster on 127.0.0.1 (GCS and Ray Client ports free ones), its workers importing
    this checkout with the console tests' numba cache; stopped (its process group) at the end."""
    temp = tempfile.mkdtemp(prefix="lrc", dir="/tmp")  # short: Ray's socket paths live under it
    cache = Path(temp) / "numba"
    shutil.copytree(numba_seed(tmp_path_factory.getbasetemp()), cache)
    gcs, client = free_port(), free_port()
    env = {**os.environ, "PYTHONPATH": str(REPO), "NUMBA_CACHE_DIR": str(cache), "RAY_USAGE_STATS_ENABLED": "0"}
    command = [sys.executable, "-m", "ray.scripts.scripts", "start", "--head", "--block", "--port", str(gcs),
               "--ray-client-server-port", str(client), "--num-cpus", "2",
               "--include-dashboard", "false", "--disable-usage-stats", "--temp-dir", temp]
    log = open(Path(temp) / "ray-start.log", "w")
    head = subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                            stdin=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not (_listening(gcs) and _listening(client)):
            assert head.poll() is None, (Path(temp) / "ray-start.log").read_text()
            assert time.monotonic() < deadline, "ray start --head did not listen within 120 s"
            time.sleep(0.5)
        yield {"gcs": f"127.0.0.1:{gcs}", "client": f"ray://127.0.0.1:{client}", "gcs_port": gcs}
    finally:
        head.send_signal(signal.SIGTERM)
        try:
            head.wait(30)
        except subprocess.TimeoutExpired:
            pass
        try:
            os.killpg(head.pid, signal.SIGKILL)  # whatever of its session is left
        except ProcessLookupError:
            pass
        head.wait()
        log.close()
        shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture(scope="module")
def joined(ray_head):
    """This test process as a Ray Client driver of the module's cluster."""
    from laplab.cluster.collector import connect_ray
    saved = {k: os.environ.get(k) for k in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN")}
    assert connect_ray(ray_head["client"], 2)  # with the token `ray start` made or found, as laplab's jobs join
    yield ray_head
    ray.shutdown()
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


@pytest.fixture
def laplab_home(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    return tmp_path / "home"


def test_ray_collection_reports_progress_and_the_workers_file_follows_the_workers(joined, laplab_home, tmp_path,
                                                                                    monkeypatch):
    from laplab.cluster import collector as collector_module
    from laplab.cluster.launch import RayWorkers
    from laplab.env.metadata import ModelMetadata
    from laplab.train import trainer as trainer_module
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    monkeypatch.setattr(trainer_module, "PROGRESS_INTERVAL_S", 0.0)  # every event the collector offers
    monkeypatch.setattr(collector_module, "PROGRESS_READ_S", 0.1)
    reward = tmp_path / "reward_function.py"
    reward.write_text(textwrap.dedent(f"""\
        import os
        import time


        def reward_function(params):
            if {os.getpid()} not in (os.getpid(), os.getppid()):  # in the rollout workers (not the reward
                # check's child): slow steps, a collection of seconds
                time.sleep(0.02)
            return 1.0
        """))
    hyper = {**TrainConfig().hyper().to_dict(), **SMALL_HP}
    config = replace(TrainConfig(), hyperparameters=hyper, model_metadata=ModelMetadata().to_dict(), max_time_s=300,
                     workers=2, max_episodes=4, reward_path=str(reward))
    trainer = create_training("on-ray", config, launcher=RayWorkers())
    events, snapshots = [], []

    class Listener:
        def on_progress(self, progress):
            events.append(progress)
    trainer.subscribe(Listener())
    path = workers_file(trainer.folder.root)
    with trainer:
        started = json.loads(path.read_text())["workers"]
        result = trainer.run(callbacks=(lambda report: snapshots.append(read_workers(trainer.folder.root)),))
        pids = trainer.collector.pids()
    assert result.error is None and result.iterations == 1, result
    first = [e for e in events if e.iteration == 1]
    phases = [e.phase for e in first]
    collecting = first[:phases.index("learn")]
    assert all(e.phase == "collect" and e.total == 4 for e in collecting)
    assert any(0 < e.env_steps and e.done < 4 for e in collecting), collecting  # counted while the workers drove
    assert [e.done for e in collecting] == sorted(e.done for e in collecting) and collecting[-1].done == 4
    assert [w["state"] for w in started] == ["alive", "alive"] and all(w["pid"] for w in started)
    assert [[(w["state"], w["episodes"], w["iteration"]) for w in rows] for rows in snapshots] == [[("alive", 2, 1)] * 2]
    final = read_workers(trainer.folder.root)
    assert [w["index"] for w in final] == [0, 1] and [w["pid"] for w in final] == pids
    for row in final:
        assert row["state"] == "stopped" and row["restarts"] == 0 and row["track"] == "classic_2018"
        assert row["host"] == socket.gethostname() and row["node_ip"]
        assert row["actor_id"] and row["node_id"]


def test_only_jobs_with_the_network_reach_the_cluster(ray_head, tmp_path):
    if not bubblewrap_works():
        pytest.skip("bubblewrap cannot build its sandbox here")
    probe = [sys.executable, "-c", f"import socket; socket.create_connection(('127.0.0.1', {ray_head['gcs_port']}), 5)"]
    outcomes = {}
    for network in (False, True):
        command = confined_command(probe, Mounts({str(tmp_path): "/tmp/laplab/job"}, {}, network=network), True)
        assert ("--share-net" in command) is network and "--unshare-all" in command
        outcomes[network] = subprocess.run(command, env=clean_environment(), capture_output=True, text=True,
                                           timeout=60)
    assert outcomes[False].returncode != 0 and "Error" in outcomes[False].stderr
    assert outcomes[True].returncode == 0, outcomes[True].stderr


def test_a_console_job_trains_with_two_workers_on_the_cluster(ray_head, tmp_path, serve_console):
    cluster = RayCluster.at(ray_head["client"], 2)  # with this user's Ray token, as `laplab serve` takes it
    with serve_console(tmp_path / "home", workers=1, cluster=cluster) as console:
        too_many = console.admin.post("/api/models", json={"name": "greedy", "workers": 3})
        assert too_many.status_code == 400 and too_many.json()["detail"]["field"] == "workers"
        assert "at most 2 rollout workers" in too_many.json()["detail"]["message"]
        body = {"name": "on-cluster", "hyperparameters": SMALL_HP, "max_episodes": 4, "max_time_s": 240}
        created = console.admin.post("/api/models", json=body)
        assert created.status_code == 201, created.text
        model = console.wait_for(console.admin, "on-cluster", ("ready", "failed"), timeout_s=300)
        job = model["job"]
        log = (tmp_path / "home" / "jobs" / str(job["id"]) / "log.txt").read_text()
        assert model["status"] == "ready", (model.get("error"), log)
        assert "starting 2 rollout workers on the Ray cluster at ray://127.0.0.1" in log
        spec = json.loads((tmp_path / "home" / "jobs" / str(job["id"]) / "spec.json").read_text())
        assert spec["cluster"] == {"address": ray_head["client"], "workers": 2} and spec["params"]["workers"] == 2
        assert model["rollout_workers"] == 2 and len(model["iterations"]) == 1
        assert [(w["index"], w["state"], w["episodes"], w["iteration"]) for w in model["workers"]] == [
            (0, "stopped", 2, 1), (1, "stopped", 2, 1)]
        assert all(w["pid"] and w["host"] and w["actor_id"] for w in model["workers"])
        assert model["config"]["workers"] == 2
        events = [json.loads(line) for line in (tmp_path / "home" / "jobs" / str(job["id"]) / "events.jsonl").open()]
        phases = [(e["phase"], e["total"]) for e in events if e["type"] == "phase" and e["iteration"] == 1]
        assert ("collect", 4) in phases and phases.index(("collect", 4)) < [p for p, _ in phases].index("learn")
        live = json.loads((tmp_path / "home" / "jobs" / str(job["id"]) / "poses.json").read_text())
        assert live["seq"] >= 1 and 1 <= len(live["cars"]) <= 4  # the car view: cars of the workers, as they drove
        other = console.add_user("other")
        assert other.get("/api/models/on-cluster").status_code == 404  # the workers, like the model, are the owner's
        page = console.admin.get("/models/on-cluster")
        assert page.status_code == 200 and 'id="workers-card"' in page.text


def test_bad_cluster_settings_are_one_paragraph(ray_head, capsys):
    from laplab.cli import main
    if bubblewrap_works():
        with pytest.raises(JobError, match=r"join the cluster through Ray Client: --ray-address ray://127\.0\.0\.1:10001"):
            check_console_cluster(ray_head["gcs"], 2, sandboxed=True)
    assert check_console_cluster(ray_head["gcs"], 2, sandboxed=False)[0].startswith(
        f"the Ray cluster at {ray_head['gcs']} runs on this machine")
    code = main(["serve", "--ray-address", "ray://127.0.0.1:9", "--port", str(free_port())])
    err = capsys.readouterr().err
    assert code != 0 and "cannot reach the Ray cluster at ray://127.0.0.1:9" in err and "Traceback" not in err
    assert main(["serve", "--rollout-workers", "2"]) != 0
    assert "--rollout-workers needs --ray-address" in capsys.readouterr().err
    assert main(["serve", "--ray-address", ray_head["client"], "--rollout-workers", "0"]) != 0
    assert "--rollout-workers must be an integer within 1..1024" in capsys.readouterr().err
    with pytest.raises(JobError, match="need a Ray cluster"):
        job_worker_count(2, None, 20)
    assert job_worker_count(None, None, 20) == 1
    assert job_worker_count(None, RayCluster("ray://h:1", 8), 4) == 4  # the default, at most one per episode
    with pytest.raises(JobError, match="more than the 2 episodes"):
        job_worker_count(3, RayCluster("ray://h:1", 8), 2)


def test_a_cluster_gone_at_job_time_fails_the_job_with_one_paragraph(tmp_path, serve_console):
    """The address was checked at start; a cluster that went away since fails the job, on its page."""
    with serve_console(tmp_path / "home", workers=1, cluster=RayCluster("ray://127.0.0.1:9", 2)) as console:
        created = console.admin.post("/api/models", json={"name": "orphan", "hyperparameters": SMALL_HP,
                                                          "max_episodes": 4, "max_time_s": 120})
        assert created.status_code == 201, created.text
        model = console.wait_for(console.admin, "orphan", ("ready", "failed"), timeout_s=240)
    assert model["status"] == "failed"
    assert "cannot reach the Ray cluster at ray://127.0.0.1:9" in model["error"] and "Traceback" not in model["error"]
    assert "\n" not in model["error"].strip()


def test_a_race_submission_is_evaluated_on_the_cluster(ray_head, tmp_path, serve_console):
    """With --ray-address a race submission's evaluate job drives its lap on a Ray worker, at the
    evaluation priority below the node's other workers, and the result reaches the race's board as a
    local one does."""
    from tests.console.conftest import create_tiny_model
    cluster = RayCluster.at(ray_head["client"], 1)  # with this user's Ray token, as `laplab serve` takes it
    with serve_console(tmp_path / "home", workers=1, cluster=cluster) as console:
        store = console.app.state.store
        fay = console.client(store.add_user("fay", role="facilitator")[1])
        rita_user, rita_token = store.add_user("rita", role="racer")
        rita = console.client(rita_token)
        create_tiny_model(f"u{rita_user.id}-fast")
        store.claim_model(f"u{rita_user.id}-fast", rita_user.id)
        console.app.state.service.models_changed()
        race = fay.post("/api/races", json={"name": "Cluster race", "track": "oval", "laps": 1,
                                            "ranking": "best_lap"}).json()
        submitted = rita.post(f"/api/races/{race['id']}/submissions", json={"model": "fast"})
        assert submitted.status_code == 202, submitted.text
        deadline = time.monotonic() + 400
        while (sub := rita.get(f"/api/races/{race['id']}/submissions").json()[0])["state"] not in ("done", "failed"):
            assert time.monotonic() < deadline, sub
            time.sleep(1.0)
        job = store.job(submitted.json()["job"])
        log = (tmp_path / "home" / "jobs" / str(job.id) / "log.txt").read_text()
        assert sub["state"] == "done", (sub, log)
        assert f"evaluating 1 lap on the Ray cluster at {ray_head['client']}" in log and "the laps were driven on" in log
        assert job.result["driven_on"]["pid"] not in (job.pid, os.getpid()) and job.result["driven_on"]["node_id"]  # a Ray worker drove
        # below the node's rollout workers (Ray starts its workers at nice 15: the default 10 reaches 19)
        assert job.result["driven_on"]["nice"] == 19 and "at nice 19)" in log
        assert len(sub["laps"]) == 1 and (sub["score"] is not None or sub["reason"])
        assert rita.get(f"/api/races/{race['id']}/submissions/{sub['id']}/video").status_code == 200
