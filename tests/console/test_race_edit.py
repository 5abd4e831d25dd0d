"""Editing a race's rules after submissions came in: the board re-ranks them at once from the laps
their evaluations recorded (no evaluation runs again), the edit's answer says which submissions now
rank how, and a race moved to another track ranks none of the old ones, saying why. The evaluations
here are hand-made (done evaluate jobs with their laps), so no job runs."""

from __future__ import annotations

import json
import time

import pytest

from laplab.races.results import race_params
from laplab.store.atomic import atomic_write_json
from laplab.store.layout import model_folder
from tests.console.conftest import signed_in_page


def lap(time_s=None, off=0):
    done = time_s is not None
    return {"index": 0, "status": "lap_complete" if done else "off_track", "lap_time": time_s,
            "duration": time_s or 5.0, "start_time": 0.0, "completion": 100.0 if done else 40.0,
            "off_track_count": off, "reset_count": off if done else 0, "penalty_time": 2.0 * off if done else 0.0}


def recorded_submission(console, race_id: int, racer: str, model: str, laps: list[dict]) -> int:
    """A submission whose evaluation is done, driven under the race's rules at submission time."""
    store, races = console.app.state.store, console.app.state.races
    user, race = store.user_by_name(racer), races.race(race_id)
    key = f"u{user.id}-{model}"
    folder = model_folder(key)
    folder.create().write_laplab_config({"track": "oval"})
    stamp = folder.new_evaluation()
    atomic_write_json(folder.evaluation_dir(stamp) / "summary.json", {"model": key, "trials": laps, "summary": {}})
    store.claim_model(key, user.id)

    def done_job():
        cursor = store.execute("INSERT INTO jobs(kind, model, owner, status, params, created, result) "
                               "VALUES ('evaluate', ?, ?, 'done', ?, ?, ?)",
                               (key, user.id, json.dumps(race_params(race.settings)), time.time(),
                                json.dumps({"stamp": stamp})))
        return store.job(int(cursor.lastrowid))
    return races.add_submission(race, user, key, done_job).id


@pytest.fixture(scope="module")
def race(tmp_path_factory, serve_console):
    with serve_console(tmp_path_factory.mktemp("race-edit-home"), workers=1, seed_numba=False) as console:
        store = console.app.state.store
        clients = {name: console.client(store.add_user(name, role=role)[1])
                   for name, role in (("fay", "facilitator"), ("ann", "racer"), ("bob", "racer"))}
        for name in ("ann", "bob"):
            console.app.state.accounts.update_profile(store.user_by_name(name), f"{name.title()} Racer", None, None)
        settings = {"name": "Rules change", "track": "oval", "laps": 3, "ranking": "best_lap",
                    "off_track_penalty": 2.0, "max_submissions": 5}
        created = clients["fay"].post("/api/races", json=settings)
        assert created.status_code == 201, created.text
        rid = created.json()["id"]
        ids = {"ann": recorded_submission(console, rid, "ann", "fast", [lap(10.0, off=2), lap(9.5), lap(None)]),
               "bob": recorded_submission(console, rid, "bob", "steady", [lap(9.0), lap(9.2), lap(9.1)])}
        console.app.state.service.models_changed()
        yield console, clients, rid, settings, ids


def board(client, rid):
    return [(e["alias"], e["score"]) for e in client.get(f"/api/races/{rid}/leaderboard").json()["entries"]]


def test_an_edit_re_ranks_the_recorded_laps_and_says_how(race):
    console, clients, rid, settings, ids = race
    fay, ann = clients["fay"], clients["ann"]
    jobs_before = len(console.app.state.store.jobs())
    assert board(ann, rid) == [("Bob Racer", 9.0), ("Ann Racer", 9.5)]

    total = fay.put(f"/api/races/{rid}", json={**settings, "ranking": "total_time"})
    assert total.status_code == 200, total.text
    rescored = total.json()["rescored"]
    assert (rescored["submissions"], rescored["ranked"], rescored["unranked"]) == (2, 1, 1)
    changed = {c["id"]: c for c in rescored["changed"]}
    assert changed[ids["ann"]]["score_before"] == 9.5 and changed[ids["ann"]]["score"] is None
    assert changed[ids["ann"]]["rank_before"] == 2 and changed[ids["ann"]]["rank"] is None
    assert "2 of the race's 3 laps completed" in changed[ids["ann"]]["reason"]
    assert changed[ids["bob"]]["score"] == pytest.approx(27.3) and changed[ids["bob"]]["rank"] == 1
    assert board(ann, rid) == [("Bob Racer", pytest.approx(27.3))]
    own = ann.get(f"/api/races/{rid}/submissions").json()
    assert own[0]["score"] is None and "2 of the race's 3 laps" in own[0]["reason"]  # a racer sees why

    # no off-track penalty and one lap: Ann's first lap, re-timed without its 2 penalties, wins
    short = fay.put(f"/api/races/{rid}", json={**settings, "laps": 1, "off_track_penalty": 0.0}).json()
    assert [(c["id"], c["rank"]) for c in sorted(short["rescored"]["changed"], key=lambda c: c["rank"])] == [
        (ids["ann"], 1), (ids["bob"], 2)]
    assert board(ann, rid) == [("Ann Racer", pytest.approx(6.0)), ("Bob Racer", 9.0)]
    mine = ann.get(f"/api/races/{rid}/submissions/{ids['ann']}").json()
    assert [lap["time"] for lap in mine["laps"]] == [pytest.approx(6.0)]
    assert "first 1 lap of the 3 laps" in mine["rules_note"] and "off-track 2 s → 0 s" in mine["rules_note"]

    # another track: the old submissions drove another course, so none ranks, each saying why
    moved = fay.put(f"/api/races/{rid}", json={**settings, "track": "classic_2018"}).json()
    assert moved["rescored"]["ranked"] == 0 and len(moved["rescored"]["changed"]) == 2
    assert board(ann, rid) == []
    reason = ann.get(f"/api/races/{rid}/submissions").json()[0]["reason"]
    assert "driven on oval; the race is now on classic_2018" in reason and "submit the model again" in reason
    # back on the old rules, the old ranking, and not one evaluation ran for any of it
    back = fay.put(f"/api/races/{rid}", json=settings).json()
    assert back["rescored"]["ranked"] == 2 and board(ann, rid) == [("Bob Racer", 9.0), ("Ann Racer", 9.5)]
    assert len(console.app.state.store.jobs()) == jobs_before


def test_the_race_page_says_how_an_edit_re_ranked(race):
    """In Chromium: the facilitator changes the ranking on the edit page; the race's page then says who
    now ranks how, and the racer's submission row says why it does not rank."""
    console, clients, rid, settings, ids = race
    token = console.app.state.store.add_token(console.app.state.store.user_by_name("fay").id, "browser")
    with signed_in_page(console.url, token) as page:
        page.goto(f"{console.url}/races/{rid}/edit")
        page.wait_for_function("document.querySelector('#name').value === 'Rules change'")
        page.select_option("#ranking", "total_time")
        page.click("#save-race")
        page.wait_for_url(f"{console.url}/races/{rid}")
        summary = page.inner_text("#rescored")
        assert "1 of 2 submissions rank" in summary and "Ann Racer: #2 → unranked" in summary
        assert "Bob Racer: #1 → #1" in summary
        page.wait_for_selector(f"tr[data-submission='{ids['ann']}'] td.reason")
        assert "2 of the race's 3 laps" in page.inner_text(f"tr[data-submission='{ids['ann']}'] td.reason")
    assert clients["fay"].put(f"/api/races/{rid}", json=settings).json()["rescored"]["ranked"] == 2


def test_submissions_that_drove_an_old_course_do_not_count_toward_the_limit(race):
    from tests.console.conftest import create_tiny_model
    console, clients, rid, settings, ids = race
    store, ann = console.app.state.store, clients["ann"]
    ann_id = store.user_by_name("ann").id
    create_tiny_model(f"u{ann_id}-real")  # a model with a checkpoint: a submission queues its evaluation
    store.claim_model(f"u{ann_id}-real", ann_id)
    console.app.state.service.models_changed()
    strict = {**settings, "max_submissions": 1}
    assert clients["fay"].put(f"/api/races/{rid}", json=strict).status_code == 200
    over = ann.post(f"/api/races/{rid}/submissions", json={"model": "real"})  # her old one still ranks: it counts
    assert over.status_code == 409 and over.json()["detail"]["field"] == "max_submissions"
    assert clients["fay"].put(f"/api/races/{rid}", json={**strict, "track": "classic_2018"}).status_code == 200
    again = ann.post(f"/api/races/{rid}/submissions", json={"model": "real"})  # the old one drove the oval
    assert again.status_code == 202, again.text
    clients["fay"].delete(f"/api/races/{rid}")  # stops the evaluation it queued
