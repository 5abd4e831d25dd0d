"""Kill the server (SIGKILL) during two trainings and restart it: both show ``interrupted``, resume
and finish with loadable models, a queued job still runs, and SQLite is intact."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

httpx = pytest.importorskip("httpx")
pytest.importorskip("uvicorn")
TOKEN = "restart-admin-token"
TINY = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}


def start_server(home: Path, port: int, log: Path) -> subprocess.Popen:
    env = {**os.environ, "LAPLAB_HOME": str(home), "LAPLAB_ADMIN_TOKEN": TOKEN}
    process = subprocess.Popen([sys.executable, "-m", "laplab.cli", "serve", "--port", str(port), "--workers", "2"],
                               env=env, stdout=open(log, "ab"), stderr=subprocess.STDOUT)
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
    deadline = time.monotonic() + 90
    while True:
        try:
            if client.get("/api/health").status_code == 200:
                break
        except httpx.TransportError:
            pass
        assert process.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.3)
    process.client = client
    return process


def wait(client, name, predicate, timeout_s=300):
    deadline = time.monotonic() + timeout_s
    while True:
        model = client.get(f"/api/models/{name}").json()
        if predicate(model):
            return model
        assert time.monotonic() < deadline, model
        time.sleep(0.2)


def job_pids(database: Path) -> list[int]:
    """The process ids of the jobs the database says are running."""
    db = sqlite3.connect(database)
    try:
        return [pid for (pid,) in db.execute("SELECT pid FROM jobs WHERE status = 'running' AND pid IS NOT NULL")]
    finally:
        db.close()


def wait_until_dead(pids: list[int], timeout_s: float = 30.0) -> None:
    """Poll (0.1 s) until none of ``pids`` runs (gone, or a zombie nobody reaped)."""
    def running(pid: int) -> bool:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            return False
        return state not in ("Z", "X")

    deadline = time.monotonic() + timeout_s
    while any(running(pid) for pid in pids):
        assert time.monotonic() < deadline, f"jobs still running {timeout_s} s after the server died: {pids}"
        time.sleep(0.1)


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_sigkill_restart_interrupts_then_resumes(tmp_path, monkeypatch, numba_cache):
    import shutil

    from laplab.jobs.warmup import trusted_cache
    shutil.copytree(numba_cache, trusted_cache(tmp_path))  # the server's warm-up, done once per session
    port, log = free_port(), tmp_path / "server.log"
    server = start_server(tmp_path, port, log)
    try:
        for name in ("crash-a", "crash-b", "crash-queued"):
            body = {"name": name, "track": "oval", "max_time_s": 600 if name != "crash-queued" else 3,
                    "hyperparameters": TINY}
            assert server.client.post("/api/models", json=body).status_code == 201
        for name in ("crash-a", "crash-b"):
            wait(server.client, name, lambda m: m["status"] == "training" and m["iteration_count"] >= 1)
        assert server.client.get("/api/models/crash-queued").json()["status"] == "queued"
    finally:
        server.send_signal(signal.SIGKILL)
        server.wait(30)
    pids = job_pids(tmp_path / "laplab.db")
    assert len(pids) == 2, pids  # crash-a and crash-b
    wait_until_dead(pids)  # the jobs die with the server (parent-death signal)

    server = start_server(tmp_path, port, log)
    try:
        client = server.client
        for name in ("crash-a", "crash-b"):
            model = client.get(f"/api/models/{name}").json()
            assert model["status"] == "interrupted", model
        queued = wait(client, "crash-queued", lambda m: m["status"] in ("ready", "failed"))
        assert queued["status"] == "ready", queued
        for name in ("crash-a", "crash-b"):
            assert client.post(f"/api/models/{name}/resume", json={"max_time_s": 4}).status_code == 202
        assert client.post("/api/models/crash-queued/resume").status_code == 202  # its saved 3 s budget
        for name in ("crash-a", "crash-b", "crash-queued"):
            model = wait(client, name, lambda m: m["status"] in ("ready", "failed"))
            assert model["status"] == "ready", model
            assert model["iteration_count"] >= 1
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(60)
    db = sqlite3.connect(tmp_path / "laplab.db")
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert {r[0] for r in db.execute("SELECT status FROM jobs")} <= {"done", "interrupted"}
    resumed = db.execute("SELECT params FROM jobs WHERE kind = 'resume' AND model = 'crash-queued'").fetchone()
    assert json.loads(resumed[0])["max_time_s"] == 3  # named in the job, so the watchdog has a wall limit
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    from laplab.train.policy import load_model_policy
    for name in ("crash-a", "crash-b", "crash-queued"):
        policy = load_model_policy(name, "last")
        assert policy.folder.name == name
