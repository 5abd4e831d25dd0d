"""Downloads for the car through the console: export jobs build the car's tar.gz (TensorFlow
``agent/model.pb`` + ``model_metadata.json``) and the DeepRacer console's layout in a worker
process; their state and file are served to the model's owner only."""

from __future__ import annotations

import io
import tarfile
import time

import pytest


def wait_export(client, name: str, job_id: int, timeout_s: float = 400.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while (export := client.get(f"/api/models/{name}/exports/{job_id}").json())["status"] in ("queued", "running"):
        assert time.monotonic() < deadline, export
        time.sleep(0.2)
    return export


def test_export_requests_are_checked_and_private(console, make_model, monkeypatch):
    make_model("export-checks")
    admin = console.admin
    assert admin.post("/api/models/export-checks/exports", json={"format": "phone"}).status_code == 422
    assert admin.post("/api/models/export-checks/exports", json={"format": "car", "extra": 1}).status_code == 422
    assert admin.get("/api/models/export-checks/exports/999").status_code == 404
    refused = admin.get("/api/models/export-checks/download?format=car")
    assert refused.status_code == 409 and "/exports" in refused.json()["detail"]["message"]
    other = console.add_user("export-outsider")
    for method, path in (("POST", "/api/models/export-checks/exports"), ("GET", "/api/models/export-checks/exports"),
                         ("GET", "/api/models/export-checks/download?format=car")):
        assert other.request(method, path, json={"format": "car"} if method == "POST" else None).status_code == 404

    import importlib.util

    from laplab.console import api_exports
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(api_exports.importlib.util, "find_spec",
                        lambda name, *a: None if name == "tensorflow" else real_find_spec(name, *a))
    # a STATE model says it is not a camera model before TensorFlow is asked for
    state = admin.post("/api/models/export-checks/exports", json={"format": "car"})
    assert state.status_code == 400 and "'STATE' is not supported" in state.json()["detail"]["message"]
    make_model("export-camera", sensor=["FRONT_FACING_CAMERA"])
    missing = admin.post("/api/models/export-camera/exports", json={"format": "car"})
    assert missing.status_code == 400
    detail = missing.json()["detail"]
    assert detail["field"] == "format" and "pip install 'laplab[deepracer]'" in detail["message"]
    # the model page gets the same reasons, and disables those buttons with them
    blocked = admin.get("/api/models/export-checks").json()["downloads_blocked"]
    assert blocked["tar"] is None and "'STATE' is not supported" in blocked["car"]
    assert "pip install 'laplab[deepracer]'" in admin.get("/api/models/export-camera").json()["downloads_blocked"]["console"]


def test_the_car_and_console_formats_are_built_by_jobs_and_downloaded(console, make_model):
    pytest.importorskip("tensorflow")
    make_model("car-ready", sensor=["FRONT_FACING_CAMERA"])
    make_model("simulator-only")  # STATE: laplab's own sensor, which the car does not have
    admin = console.admin
    car = admin.post("/api/models/car-ready/exports", json={"format": "car"})
    layout = admin.post("/api/models/car-ready/exports", json={"format": "console"})
    assert car.status_code == 202 and layout.status_code == 202, (car.text, layout.text)
    assert car.json()["status"] == "queued" and car.json()["url"] is None
    refused = admin.post("/api/models/simulator-only/exports", json={"format": "car"})  # before any job
    assert refused.status_code == 400 and refused.json()["detail"]["field"] == "format"
    assert "sensor 'STATE' is not supported by the DeepRacer car" in refused.json()["detail"]["message"]

    done = wait_export(admin, "car-ready", car.json()["id"])
    assert done["status"] == "done", done
    archive = admin.get(done["url"])
    assert archive.status_code == 200 and archive.content[:2] == b"\x1f\x8b"
    with tarfile.open(fileobj=io.BytesIO(archive.content)) as tar:
        assert sorted(tar.getnames()) == ["agent/model.pb", "model_metadata.json"]
        assert b"action_space" in tar.extractfile("model_metadata.json").read()
    assert done["size"] == len(archive.content)
    latest = admin.get("/api/models/car-ready/download?format=car")
    assert latest.status_code == 200 and latest.content == archive.content

    done = wait_export(admin, "car-ready", layout.json()["id"])
    assert done["status"] == "done", done
    with tarfile.open(fileobj=io.BytesIO(admin.get(done["url"]).content)) as tar:
        names = set(tar.getnames())
    assert {"car-ready-console/model/model_metadata.json", "car-ready-console/reward_function.py",
            "car-ready-console/training_params.yaml"} <= names
    assert any(n.startswith("car-ready-console/model/model_") and n.endswith(".pb") for n in names)
    listed = admin.get("/api/models/car-ready").json()["exports"]
    assert [x["format"] for x in listed] == ["car", "console"] and all(x["status"] == "done" for x in listed)

    assert admin.get("/api/models/simulator-only").json()["exports"] == []  # nothing was queued
