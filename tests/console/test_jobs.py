"""Training, stopping, evaluating, downloading, importing and cloning through the API, with the
live event stream; jobs are real confined worker processes training tiny STATE models."""

from __future__ import annotations

import io
import json
import tarfile
import threading
import time


TINY_HYPERPARAMETERS = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}


class EventCollector:
    """Reads a model's server-sent events in a thread (bounded by ``timeout_s``)."""

    def __init__(self, client, name: str, timeout_s: float = 300.0):
        self.events: list[tuple[str, dict, float]] = []
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(client, name, timeout_s), daemon=True)
        self.thread.start()

    def _run(self, client, name, timeout_s):
        deadline = time.monotonic() + timeout_s
        with client.stream("GET", f"/api/models/{name}/events", timeout=timeout_s) as stream:
            kind = None
            for line in stream.iter_lines():
                if self._stop.is_set() or time.monotonic() > deadline:
                    return
                if line.startswith("event: "):
                    kind = line[7:]
                elif line.startswith("data: ") and kind:
                    self.events.append((kind, json.loads(line[6:]), time.time()))

    def of(self, kind: str) -> list[dict]:
        return [data for k, data, _ in self.events if k == kind]

    def wait(self, predicate, timeout_s: float = 300.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not predicate(self):
            assert time.monotonic() < deadline, f"events so far: {[k for k, _, _ in self.events][-20:]}"
            time.sleep(0.2)

    def close(self):
        self._stop.set()


def test_train_watch_stop_evaluate_leaderboard_download_import_clone(console):
    admin = console.admin
    body = {"name": "live-model", "track": "oval", "max_time_s": 600, "hyperparameters": TINY_HYPERPARAMETERS,
            "description": "a test"}
    created = admin.post("/api/models", json=body)
    assert created.status_code == 201, created.text
    assert created.json()["status"] in ("queued", "training")
    assert admin.post("/api/models", json=body).status_code == 409

    events = EventCollector(console.client("admin-test-token-0123456789"), "live-model")
    try:
        events.wait(lambda e: e.of("iteration") and len({json.dumps(p["cars"]) for p in e.of("poses")}) >= 3)
        iteration = events.of("iteration")[0]
        assert iteration["iteration"] == 1 and 0 < iteration["progress"] < 100 and "mean_reward" in iteration
        assert admin.get("/api/models/live-model").json()["status"] == "training"
        assert admin.delete("/api/models/live-model").status_code == 409
        assert admin.post("/api/models/live-model/evaluations", json={"trials": 1}).status_code == 409
        assert admin.post("/api/models/live-model/stop").status_code == 200
        model = console.wait_for(admin, "live-model", ("ready",), timeout_s=180)
        events.wait(lambda e: any(s["status"] == "ready" for s in e.of("status")), timeout_s=30)
    finally:
        events.close()
    assert model["job"]["result"]["stop_reason"] == "stopped" and len(model["iterations"]) >= 1
    assert model["description"] == "a test" and model["track"] == "oval"

    started = admin.post("/api/models/live-model/evaluations", json={"trials": 2})  # standard rules: it ranks
    assert started.status_code == 202
    job_id = started.json()["id"]
    # the ONNX download is built on the spot (a child process of the server) while the evaluation job runs
    onnx = admin.get("/api/models/live-model/download?format=onnx")
    assert onnx.status_code == 200
    with tarfile.open(fileobj=io.BytesIO(onnx.content)) as archive:
        assert {"model.onnx", "model_metadata.json"} <= set(archive.getnames())
    deadline = time.monotonic() + 240
    while (evaluation := admin.get(f"/api/models/live-model/evaluations/{job_id}").json())["status"] in ("queued", "running"):
        assert time.monotonic() < deadline
        time.sleep(0.2)
    assert evaluation["status"] == "done", evaluation
    assert len(evaluation["trials"]) == 2
    for trial in evaluation["trials"]:
        assert {"lap_time", "progress", "status", "off_track_count"} <= set(trial)
    assert evaluation["summary"]["optimal_lap_time"] > 0

    # the clone trains (a job) while the report, the leaderboard, the download and the import are checked
    bad_clone = admin.post("/api/models/live-model/clone",
                           json={"name": "clone-bad", "model_metadata": {"action_space": [{"steering_angle": 0, "speed": 1},
                                                                                          {"steering_angle": 10, "speed": 1}]}})
    assert bad_clone.status_code == 400 and "action space" in bad_clone.json()["detail"]["message"]
    clone = admin.post("/api/models/live-model/clone", json={"name": "live-clone", "max_time_s": 4})
    assert clone.status_code == 201, clone.text

    report = admin.get("/models/live-model/report", follow_redirects=True)
    assert report.status_code == 200 and str(report.url).endswith("/models/live-model/report/"), report.text[:300]
    import re
    figures = re.findall(r'<img src="([^"]+)"', report.text)
    assert "live-model" in report.text and len(figures) >= 3, figures
    for figure in figures:  # each figure is served beside the page, as a real PNG
        picture = admin.get(f"/models/live-model/report/{figure}")
        assert picture.status_code == 200 and picture.content[:4] in (b"\x89PNG", b"GIF8"), figure
    assert admin.get("/models/live-model/report/..%2Flaplab.json").status_code == 404

    boards = admin.get("/api/leaderboard?track=oval").json()
    assert boards[0]["entries"][0]["model"] == "live-model" and boards[0]["entries"][0]["user"] == "admin"

    tar = admin.get("/api/models/live-model/download?format=tar")
    assert tar.status_code == 200 and tar.content[:2] == b"\x1f\x8b"

    user = console.add_user("importer")
    imported = user.post("/api/models/import", files={"file": ("live.tar.gz", tar.content)}, data={"name": "imported-copy"})
    assert imported.status_code == 201, imported.text
    assert [m["name"] for m in user.get("/api/models").json()] == ["imported-copy"]
    # another user sees the admin's row on the leaderboard, but not the model's name
    theirs = user.get("/api/leaderboard?track=oval").json()[0]["entries"][0]
    assert theirs["user"] == "admin" and theirs["model"] is None
    assert user.post("/api/models/import", files={"file": ("live.tar.gz", tar.content)},
                     data={"name": "imported-copy"}).status_code == 400

    cloned = console.wait_for(admin, "live-clone", ("ready", "failed"), timeout_s=240)
    assert cloned["status"] == "ready", cloned
    assert cloned["track"] == "oval"
    assert admin.get("/api/models/live-clone").json()["config"]["cloned_from"].startswith("live-model (checkpoint ")
    assert admin.delete("/api/models/live-clone").status_code == 200
