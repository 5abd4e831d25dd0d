"""The console's API takes laplab.train.request's TrainRequest (and EvaluateRequest, ExportRequest):
the same defaults as the CLI and laplab.api, the same messages, and the field the request's error
carries (no message is looked into)."""

from __future__ import annotations

import time

import pytest

from laplab.env.metadata import ModelMetadata
from laplab.errors import UserError
from laplab.evaluate.trials import EvaluateRequest
from laplab.train.request import DEFAULT_MAX_TIME_S, ExportRequest, TrainRequest


def _request_error(**values) -> UserError:
    with pytest.raises(UserError) as error:
        TrainRequest.from_mapping(values).validate()
    return error.value


@pytest.mark.parametrize("values", [{"max_time_s": -5}, {"max_episodes": 0}, {"physics": "seven"},
                                    {"workers": 0}, {"max_time_s": 0},
                                    {"race_type": {"kind": "object_avoidance", "objects": 99}},
                                    {"hyperparameters": {"batch_size": -3}},
                                    {"domain_randomization": True}])  # laplab's default sensor: STATE
def test_a_bad_value_is_the_request_message_next_to_the_request_field(console, values):
    answer = console.admin.post("/api/models", json={"name": "m-bad", **values})
    assert answer.status_code == 400, answer.text
    detail = answer.json()["detail"]
    expected = _request_error(**values)
    assert detail["field"] == expected.field == next(iter(values)), detail
    assert detail["message"] == str(expected)
    assert "m-bad" not in [m["name"] for m in console.admin.get("/api/models").json()]


def test_the_api_schema_documents_the_request_defaults(console):
    schema = console.admin.get("/openapi.json").json()["components"]["schemas"]
    create = schema["CreateModel"]["properties"]
    assert create["max_time_s"]["default"] == DEFAULT_MAX_TIME_S == TrainRequest().max_time_s
    assert create["seed"]["default"] == TrainRequest().seed
    assert {"track", "physics", "race_type", "workers", "max_episodes"} <= set(create)
    assert schema["CloneModel"]["properties"]["max_time_s"]["default"] == DEFAULT_MAX_TIME_S
    assert schema["Export"]["properties"]["checkpoint"]["default"] == ExportRequest().checkpoint


def test_a_model_created_without_max_time_trains_for_the_default(console):
    tiny = {"num_episodes_between_training": 2, "batch_size": 32, "num_epochs": 3}
    created = console.admin.post("/api/models", json={"name": "default-time", "hyperparameters": tiny})
    assert created.status_code == 201, created.text
    job = [j for j in console.app.state.store.jobs(kind=("train",)) if j.model.endswith("default-time")][-1]
    assert job.params["max_time_s"] == DEFAULT_MAX_TIME_S  # what the worker builds its TrainRequest from
    seen = set()  # the config shown while queued (the request's) and once started (its laplab.json)
    deadline = time.monotonic() + 300
    while "training" not in seen and time.monotonic() < deadline:
        detail = console.admin.get("/api/models/default-time").json()
        if detail["config"] is not None:
            assert detail["config"]["max_time_s"] == DEFAULT_MAX_TIME_S, detail["config"]
            seen.add(detail["status"])
        assert detail["status"] in ("queued", "training"), detail
        time.sleep(0.2)
    assert "training" in seen
    console.admin.post("/api/models/default-time/stop")
    console.wait_for(console.admin, "default-time", ("ready", "failed", "interrupted"), timeout_s=300)


def test_evaluation_and_export_errors_carry_their_request_field(console, make_model):
    make_model("request-fields")
    answer = console.admin.post("/api/models/request-fields/evaluations", json={"trials": 9})
    assert answer.status_code == 400, answer.text
    with pytest.raises(UserError) as expected:
        EvaluateRequest(trials=9)
    assert answer.json()["detail"] == {"message": str(expected.value), "field": "trials"}
    answer = console.admin.post("/api/models/request-fields/evaluations", json={"off_track_penalty": -1})
    assert answer.status_code == 400 and answer.json()["detail"]["field"] == "off_track_penalty", answer.text
    answer = console.admin.post("/api/models/request-fields/exports", json={"checkpoint": ""})
    assert answer.status_code == 400 and answer.json()["detail"]["field"] == "checkpoint", answer.text


def test_a_randomised_evaluation_of_a_model_without_a_camera_is_refused_at_once(console, make_model):
    make_model("randomize-state")  # laplab's default sensor: STATE
    answer = console.admin.post("/api/models/randomize-state/evaluations", json={"domain_randomization": True})
    assert answer.status_code == 400, answer.text
    detail = answer.json()["detail"]
    assert detail["field"] == "domain_randomization" and "no camera (sensors: STATE)" in detail["message"]
    assert console.admin.get("/api/models/randomize-state/evaluations").json() == []  # no job was queued


def test_a_camera_model_created_with_domain_randomization_trains_under_it(console):
    camera = {**ModelMetadata().to_dict(), "sensor": ["FRONT_FACING_CAMERA"]}
    tiny = {"num_episodes_between_training": 2, "batch_size": 32, "num_epochs": 3}
    created = console.admin.post("/api/models", json={"name": "randomized-camera", "model_metadata": camera,
                                                      "hyperparameters": tiny, "domain_randomization": True,
                                                      "max_time_s": 30})
    assert created.status_code == 201, created.text
    job = [j for j in console.app.state.store.jobs(kind=("train",)) if j.model.endswith("randomized-camera")][-1]
    assert job.params["domain_randomization"] is True  # what the worker builds its TrainRequest from
    deadline = time.monotonic() + 300  # started: the worker wrote its laplab.json
    while console.admin.get("/api/models/randomized-camera").json()["status"] == "queued" and time.monotonic() < deadline:
        time.sleep(0.2)
    console.admin.post("/api/models/randomized-camera/stop")
    console.wait_for(console.admin, "randomized-camera", ("ready", "failed", "interrupted"), timeout_s=300)
    saved = console.admin.get("/api/models/randomized-camera").json()["config"]
    assert saved["domain_randomization"] is True and saved["model_metadata"]["sensor"] == ["FRONT_FACING_CAMERA"]


def test_the_create_form_shows_the_request_default(console):
    page = console.admin.get("/create")
    assert page.status_code == 200, page.text[:300]
    assert f'id="max-time" type="number" min="0.1" max="1440" step="0.1" value="{DEFAULT_MAX_TIME_S / 60:g}"' in page.text
