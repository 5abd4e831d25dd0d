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


def test_an_object_avoidance_reward_validates_with_the_race_objects(console):
    from tests.sim.test_race_types import DEEPRACER_OA_EXAMPLE
    plain = console.admin.post("/api/reward/validate", json={"source": DEEPRACER_OA_EXAMPLE})
    assert plain.json()["ok"] is False and "IndexError" in plain.json()["errors"][0]["message"]
    race = {"kind": "object_avoidance", "objects": 3}
    ok = console.admin.post("/api/reward/validate", json={"source": DEEPRACER_OA_EXAMPLE, "race_type": race})
    assert ok.json()["ok"] is True, ok.json()
    created = console.admin.post("/api/models", json={"name": "oa-example", "reward_function": DEEPRACER_OA_EXAMPLE,
                                                       "race_type": race, "max_time_s": 3})
    assert created.status_code == 201, created.text
