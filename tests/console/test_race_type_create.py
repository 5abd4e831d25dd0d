"""The Create form's race type: recorded in the model folder, shown on its page; bad options named."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize("race, words", [
    ({"kind": "head_to_bot", "bot_speed": 7}, "bot-speed"),
    ({"kind": "object_avoidance", "objects": 12}, "do not fit"),
    ({"kind": "rally"}, "unknown race type"),
    ({"kind": "object_avoidance", "sheep": 1}, "unknown key"),
])
def test_create_model_refuses_bad_race_options(console, race, words):
    answer = console.admin.post("/api/models", json={"name": "m-race", "race_type": race})
    assert answer.status_code == 400, answer.text
    detail = answer.json()["detail"]
    assert words in detail["message"] and detail["field"] == "race_type"
    assert "m-race" not in [m["name"] for m in console.admin.get("/api/models").json()]


def test_create_object_avoidance_model_records_and_shows_its_race(console):
    tiny = {"num_episodes_between_training": 4, "batch_size": 32, "num_epochs": 3}
    created = console.admin.post("/api/models", json={"name": "oa-model", "max_time_s": 3, "hyperparameters": tiny,
                                                       "race_type": {"kind": "object_avoidance", "objects": 2}})
    assert created.status_code == 201, created.text
    model = console.wait_for(console.admin, "oa-model", ("ready", "failed"), timeout_s=300)
    assert model["status"] == "ready", model.get("error")
    detail = console.admin.get("/api/models/oa-model").json()
    assert detail["config"]["race_type"]["kind"] == "object_avoidance" and detail["config"]["race_type"]["objects"] == 2
    assert detail["race_type"] == "object avoidance: 2 boxes, evenly spaced"
