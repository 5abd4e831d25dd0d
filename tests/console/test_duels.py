"""Head-to-model races from a model's page: a racer races two of their own models in a confined job
(the same race as ``laplab race``) and sees both cars; another user's model is refused with the rule,
alike whether it exists or not; an opponent on another physics version is refused next to the field."""

from __future__ import annotations

import json
import time
from dataclasses import replace

import pytest

from tests.console.conftest import TINY_HYPERPARAMETERS, signed_in_page


def tiny_model(console, key: str, owner: int, vehicle: str | None = None) -> None:
    """A real model folder ``key`` (initial checkpoint) owned by user ``owner``."""
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    config = replace(TrainConfig(), hyperparameters={**TrainConfig().hyper().to_dict(), **TINY_HYPERPARAMETERS},
                     max_time_s=5.0, vehicle=vehicle)
    create_training(key, config)
    console.app.state.store.claim_model(key, owner)
    console.app.state.service.models_changed()


def wait_duel(client, name: str, job_id: int, timeout_s: float = 300.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while (race := client.get(f"/api/models/{name}/duels/{job_id}").json())["status"] in ("queued", "running"):
        assert time.monotonic() < deadline, race
        time.sleep(0.2)
    return race


@pytest.fixture(scope="module")
def racers(console):
    store = console.app.state.store
    ann, ann_token = store.add_user("duel-ann")
    bob, bob_token = store.add_user("duel-bob")
    tiny_model(console, f"u{ann.id}-alpha", ann.id)
    tiny_model(console, f"u{ann.id}-bravo", ann.id)
    tiny_model(console, f"u{ann.id}-old-car", ann.id, vehicle="deepracer-v4")
    tiny_model(console, f"u{bob.id}-secret", bob.id)
    return console.client(ann_token), console.client(bob_token), ann, bob, ann_token


def test_a_racer_races_two_own_models_and_sees_both_cars(console, racers):
    ann, bob, *_ = racers
    choices = ann.get("/api/models/alpha/opponents").json()
    names = {o["name"]: o for o in choices["opponents"]}
    assert set(names) == {"bravo", "old-car"} and choices["track"] == "classic_2018"
    assert names["bravo"]["ready"] and "deepracer-v4" in names["old-car"]["refused"]

    started = ann.post("/api/models/alpha/duels", json={"opponent": "bravo", "track": "oval", "laps": 1,
                                                         "max_time_s": 4})
    assert started.status_code == 202, started.text
    race = wait_duel(ann, "alpha", started.json()["id"])
    assert race["status"] == "done", race
    assert race["models"] == ["alpha", "bravo"] and race["track"] == "oval"
    assert sorted(r["name"] for r in race["racers"]) == ["alpha", "bravo"]
    assert sorted(r["position"] for r in race["racers"]) == [1, 2]
    assert sorted(r["car"] for r in race["racers"]) == [0, 1]
    for racer in race["racers"]:
        assert {"laps", "finish_time", "lap_times", "crash_count", "off_track_count", "penalty_time"} <= set(racer)
    assert 3.9 <= race["duration"] <= 4.2  # nobody lapped the oval in 4 s: the race ran to its max time
    picture = ann.get(race["picture"])
    assert picture.status_code == 200 and picture.content[:8] == b"\x89PNG\r\n\x1a\n"
    assert [r["id"] for r in ann.get("/api/models/alpha/duels").json()] == [race["id"]]
    # the other racer learns nothing of it: the model does not exist for them, nor does its race
    assert bob.get(f"/api/models/alpha/duels/{race['id']}").status_code == 404
    assert bob.get(f"/api/models/alpha/duels/{race['id']}/picture").status_code == 404


def test_stop_ends_a_running_race_promptly_and_keeps_it_so_far(console, racers):
    """Stop on the model page ends the race within a step (not at its 10 simulated minutes): the race
    is done, marked stopped, with its racers and picture as far as it went."""
    from laplab.jobs.runner import job_folder
    ann = racers[0]
    started = ann.post("/api/models/alpha/duels", json={"opponent": "bravo", "track": "oval", "max_time_s": 600})
    assert started.status_code == 202, started.text
    job_id = started.json()["id"]
    deadline = time.monotonic() + 120
    while "started" not in ((job_folder(job_id) / "events.jsonl").read_text()
                            if (job_folder(job_id) / "events.jsonl").exists() else ""):
        assert time.monotonic() < deadline, ann.get(f"/api/models/alpha/duels/{job_id}").json()
        time.sleep(0.2)
    time.sleep(1.0)  # the cars are on the track (or the policies still load: the race stops at its first step)
    stopped_at = time.monotonic()
    assert ann.post("/api/models/alpha/stop").status_code == 200
    race = wait_duel(ann, "alpha", job_id, timeout_s=60)
    assert time.monotonic() - stopped_at < 30
    assert race["status"] == "done" and race["stopped"] is True, race
    assert race["duration"] < 600 and sorted(r["position"] for r in race["racers"]) == [1, 2]
    assert ann.get(race["picture"]).status_code == 200
    assert json.loads((job_folder(job_id) / "race" / "race.json").read_text())["stopped"] is True


def test_another_users_model_is_refused_with_the_rule_whether_it_exists_or_not(console, racers):
    ann, _, ann_user, bob_user, _ = racers
    assert not any("secret" in o["name"] for o in ann.get("/api/models/alpha/opponents").json()["opponents"])
    refusals = [ann.post("/api/models/alpha/duels", json={"opponent": name, "laps": 1, "max_time_s": 4})
                for name in (f"u{bob_user.id}-secret", f"u{bob_user.id}-nothing", "secret")]
    for refused in refusals:
        assert refused.status_code == 403, refused.text
        detail = refused.json()["detail"]
        assert detail["field"] == "opponent" and "private" in detail["message"]
    texts = [r.json()["detail"]["message"].replace(name, "X") for r, name in
             zip(refusals, (f"u{bob_user.id}-secret", f"u{bob_user.id}-nothing", "secret"))]
    assert len(set(texts)) == 1  # an existing model and a missing one read alike
    assert not console.app.state.service.store.jobs(kind=("duel",), model=f"u{bob_user.id}-secret")
    # an admin may pick any model (by its key)
    admin_choices = console.admin.get(f"/api/models/u{ann_user.id}-alpha/opponents").json()
    assert f"u{bob_user.id}-secret" in {o["name"] for o in admin_choices["opponents"]}
    # so may a race facilitator, from one of their own models
    facilitator, token = console.app.state.store.add_user("duel-host", role="facilitator")
    tiny_model(console, f"u{facilitator.id}-host-car", facilitator.id)
    host = console.client(token)
    host_choices = {o["name"] for o in host.get("/api/models/host-car/opponents").json()["opponents"]}
    assert {f"u{bob_user.id}-secret", f"u{ann_user.id}-alpha"} <= host_choices
    missing = host.post("/api/models/host-car/duels", json={"opponent": "u999-nothing"})
    assert missing.status_code == 404 and missing.json()["detail"]["field"] == "opponent"


def test_an_opponent_on_another_physics_version_is_refused_next_to_the_field(racers):
    ann = racers[0]
    refused = ann.post("/api/models/alpha/duels", json={"opponent": "old-car", "laps": 1, "max_time_s": 4})
    assert refused.status_code == 400
    detail = refused.json()["detail"]
    assert detail["field"] == "opponent" and "opponent 'old-car' drives deepracer-v4" in detail["message"]
    itself = ann.post("/api/models/alpha/duels", json={"opponent": "alpha"})
    assert itself.status_code == 400 and itself.json()["detail"]["field"] == "opponent"


def test_the_race_job_mounts_both_models_read_only_and_nothing_else(console, racers):
    from laplab.jobs.confinement import SANDBOX_HOME
    from laplab.jobs.runner import job_mounts
    _, _, ann_user, bob_user, _ = racers
    job = console.app.state.store.jobs(kind=("duel",))[0]  # the race of the first test
    mounts = job_mounts(job)
    inside_ro = set(mounts.readonly.values())
    assert {f"{SANDBOX_HOME}/models/u{ann_user.id}-alpha", f"{SANDBOX_HOME}/models/u{ann_user.id}-bravo"} <= inside_ro
    assert not any("/models/" in inside for inside in mounts.writable.values())
    assert not any(f"u{bob_user.id}-" in path for path in (*mounts.readonly, *mounts.writable))


def test_the_model_page_shows_the_race_and_the_refusal_next_to_the_field(console, racers, tmp_path):
    """One look in Chromium at the race of the first test (no new job)."""
    with signed_in_page(console.url, racers[4], viewport={"width": 1360, "height": 900}) as page:
        page.goto(f"{console.url}/models/alpha")
        page.wait_for_selector("#duels [data-duel][data-status=done] img.duel-picture")
        page.wait_for_function("document.querySelector('#duels img.duel-picture').naturalWidth > 100")
        assert "bravo" in page.inner_text("#duels table")
        page.select_option("#duel-opponent", "old-car")
        assert "drives deepracer-v4" in page.inner_text("#duel-error")
        assert page.is_disabled("#duel-start")
        page.select_option("#duel-opponent", "bravo")
        assert page.inner_text("#duel-error") == "" and not page.is_disabled("#duel-start")
        page.screenshot(path=str(tmp_path / "race-another-model.png"), full_page=True)
