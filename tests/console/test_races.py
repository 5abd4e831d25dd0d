"""Races end to end over the JSON API of a real console: invitations and roles, a private race joined
by code, submissions queuing real evaluations under the race's rules, the ranked board and its CSV,
and every refusal the issue lists (window, code, limit, sensors, someone else's model, a used or
expired invite, quota, a facilitator editing a race not theirs, a racer reading another's files)."""

from __future__ import annotations

import time

import pytest


def sign_up(console, invite_code: str, name: str, **profile) -> dict:
    answer = console.client(None).post("/api/signup", json={"invite": invite_code, "name": name,
                                                            "password": f"{name}-password", **profile})
    assert answer.status_code == 201, answer.text
    return answer.json()


def token_client(console, name: str):
    token = console.admin.post(f"/api/users/{name}/tokens").json()["token"]
    return console.client(token)


def racer_model(console, user_name: str, model: str, make_model, sensor=None) -> None:
    """A tiny model of ``user_name`` (as the console names it: ``u{id}-{model}``)."""
    store = console.app.state.store
    user = store.user_by_name(user_name)
    make_model(f"u{user.id}-{model}", sensor=sensor)
    store.claim_model(f"u{user.id}-{model}", user.id)
    console.app.state.service.models_changed()


def wait_done(client, race_id: int, count: int, timeout_s: float = 400.0) -> list[dict]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        subs = client.get(f"/api/races/{race_id}/submissions").json()
        if len(subs) >= count and all(s["state"] in ("done", "failed") for s in subs):
            return subs
        time.sleep(0.2)
    raise AssertionError(f"submissions not evaluated in {timeout_s} s: {subs}")


@pytest.fixture(scope="module")
def people(console):
    """An admin-made facilitator and two racers, signed up through invitation links."""
    admin = console.admin
    codes = {}
    for name, role in (("fay", "facilitator"), ("rita", "racer"), ("ravi", "racer"), ("gus", "facilitator")):
        invite = admin.post("/api/invites", json={"role": role}).json()
        assert invite["link"].endswith(f"/join/{invite['code']}")
        codes[name] = invite["code"]
        sign_up(console, invite["code"], name, alias=name.title() + " Racer", country="de")
    return {name: token_client(console, name) for name in codes} | {"codes": codes}


def test_invites_roles_passwords_profiles(console, people):
    fay, rita = people["fay"], people["rita"]
    assert fay.get("/api/me").json()["role"] == "facilitator" and rita.get("/api/me").json()["role"] == "racer"
    # an invitation signs up one person; a used or expired one is refused naming the rule
    used = console.client(None).post("/api/signup", json={"invite": people["codes"]["rita"], "name": "eve",
                                                          "password": "eve-password"})
    assert used.status_code == 410 and "already been used" in used.json()["detail"]["message"]
    assert console.app.state.store.user_by_name("eve") is None
    stale = fay.post("/api/invites", json={"role": "racer"}).json()
    console.app.state.store.execute("UPDATE invites SET expires=? WHERE id=?", (time.time() - 1, stale["id"]))
    expired = console.client(None).post("/api/signup", json={"invite": stale["code"], "name": "eve", "password": "x" * 9})
    assert expired.status_code == 410 and "expired" in expired.json()["detail"]["message"]
    # facilitators invite racers only; racers invite no one
    assert fay.post("/api/invites", json={"role": "admin"}).status_code == 403
    assert rita.post("/api/invites", json={"role": "racer"}).status_code == 403
    assert rita.get("/api/users").status_code == 403
    # password sign-in (the token stays for scripts), password change, profile
    web = console.client(None)
    wrong = web.post("/login/password", data={"name": "rita", "password": "nope-nope"})
    assert wrong.status_code == 401
    ok = web.post("/login/password", data={"name": "rita", "password": "rita-password"})
    assert ok.status_code == 303 and "laplab_session" in ok.cookies
    bad_old = rita.post("/api/me/password", json={"old_password": "wrong-old", "new_password": "new-password-1"})
    assert bad_old.status_code == 400 and bad_old.json()["detail"]["field"] == "old_password"
    assert rita.post("/api/me/password", json={"old_password": "rita-password",
                                               "new_password": "new-password-1"}).status_code == 200
    profile = rita.get("/api/me/profile").json()
    assert profile["alias"] == "Rita Racer" and profile["initials"] == "RR" and profile["country"] == "DE"
    bad = rita.put("/api/me/profile", json={"country": "Germany"})
    assert bad.status_code == 400 and bad.json()["detail"]["field"] == "country"
    assert rita.put("/api/me/profile", json={"colour": "#00ff00"}).json()["colour"] == "#00ff00"
    # the admin changes roles; the last admin stays one
    assert console.admin.post("/api/users/gus/role", json={"role": "racer"}).json()["role"] == "racer"
    assert console.admin.post("/api/users/gus/role", json={"role": "facilitator"}).json()["role"] == "facilitator"


def test_private_race_submissions_board_and_refusals(console, people, make_model):
    fay, gus, rita, ravi = people["fay"], people["gus"], people["rita"], people["ravi"]
    settings = {"name": "Class race", "track": "oval", "laps": 2, "ranking": "best_lap", "private": True,
                "max_submissions": 2, "sensors": ["STATE", "FRONT_FACING_CAMERA"]}
    assert rita.post("/api/races", json=settings).status_code == 403
    bad = fay.post("/api/races", json={**settings, "laps": 9})
    assert bad.status_code == 400 and bad.json()["detail"]["field"] == "laps"
    race = fay.post("/api/races", json=settings).json()
    rid, code = race["id"], race["code"]
    # a private race does not exist for racers who have not joined; a wrong code is refused
    assert rita.get(f"/api/races/{rid}").status_code == 404
    assert rid not in [r["id"] for r in rita.get("/api/races").json()]
    assert rita.post("/api/races/join", json={"code": "WRONGCODE"}).status_code == 404
    assert rita.post(f"/api/races/{rid}/submissions", json={"model": "fast"}).status_code == 404
    assert rita.post("/api/races/join", json={"code": code.lower()}).json()["id"] == rid
    link = ravi.get(f"/races/join/{code}")  # the link joins too
    assert link.status_code == 303 and link.headers["location"] == f"/races/{rid}"
    assert ravi.get("/races/join/WRONGCODE").status_code == 404
    assert "code" not in rita.get(f"/api/races/{rid}").json()
    # another facilitator cannot edit, close or delete it
    edit = gus.put(f"/api/races/{rid}", json={**settings, "name": "hijacked"})
    assert edit.status_code == 403 and "another facilitator" in edit.json()["detail"]["message"]
    assert gus.delete(f"/api/races/{rid}").status_code == 403

    racer_model(console, "rita", "fast", make_model)
    racer_model(console, "ravi", "quick", make_model)
    racer_model(console, "ravi", "lidar", make_model, sensor=["STATE", "SECTOR_LIDAR"])
    ravi_key = f"u{console.app.state.store.user_by_name('ravi').id}-quick"
    # someone else's model, a sensor the race does not allow, a model without checkpoint
    other = rita.post(f"/api/races/{rid}/submissions", json={"model": "quick"})
    assert other.status_code == 404 and "own models" in other.json()["detail"]["message"]
    assert rita.post(f"/api/races/{rid}/submissions", json={"model": ravi_key}).status_code == 404
    lidar = ravi.post(f"/api/races/{rid}/submissions", json={"model": "lidar"})
    assert lidar.status_code == 400 and "SECTOR_LIDAR" in lidar.json()["detail"]["message"]
    jobs_before = len(console.app.state.store.jobs())

    first = rita.post(f"/api/races/{rid}/submissions", json={"model": "fast"})
    assert first.status_code == 202, first.text
    assert ravi.post(f"/api/races/{rid}/submissions", json={"model": "quick"}).status_code == 202
    assert rita.post(f"/api/races/{rid}/submissions", json={"model": "fast"}).status_code == 202
    over = rita.post(f"/api/races/{rid}/submissions", json={"model": "fast"})
    assert over.status_code == 409 and over.json()["detail"]["field"] == "max_submissions"
    assert len(console.app.state.store.jobs()) == jobs_before + 3  # the refused one queued nothing
    job = console.app.state.store.job(first.json()["job"])
    from laplab.races.catalogue import track_key
    assert job.kind == "evaluate" and job.params["track"] == track_key("oval", "counterclockwise")
    assert job.params["trials"] == 2 and job.params["physics"] == "deepracer-v5"
    assert job.params["continuous"] is True and job.params["video"] is True

    subs = wait_done(fay, rid, 3)
    assert {s["state"] for s in subs} == {"done"}, subs
    assert all(len(s["laps"]) == 2 for s in subs)
    board = rita.get(f"/api/races/{rid}/leaderboard").json()
    ranked = board["entries"]
    assert [e["rank"] for e in ranked] == list(range(1, len(ranked) + 1))
    assert len({e["user_id"] for e in ranked}) == len(ranked) <= 2
    scores = [e["score"] for e in ranked]
    assert scores == sorted(scores)
    for entry in ranked:  # the board never names another racer's model
        assert entry["model"] is None or entry["user_id"] == console.app.state.store.user_by_name("rita").id
        assert entry["name"] is None or entry["name"] == "rita"  # another racer's login name: never
        assert entry["alias"] in ("Rita Racer", "Ravi Racer") and entry["initials"] == "RR"
    unranked = [s for s in wait_done(rita, rid, 2) if s["score"] is None]
    assert all(s["reason"] for s in unranked)
    csv_text = fay.get(f"/api/races/{rid}/leaderboard.csv").text
    assert csv_text.splitlines()[0].startswith("rank,racer,user,score_s,ranking") and len(csv_text.splitlines()) == len(ranked) + 1
    # racers see only their own submissions and files; the facilitator sees everyone's
    assert {s["user_id"] for s in rita.get(f"/api/races/{rid}/submissions").json()} == {console.app.state.store.user_by_name("rita").id}
    assert len(fay.get(f"/api/races/{rid}/submissions").json()) == 3
    ravi_sub = [s for s in subs if s["model"] == "quick"][0]
    assert rita.get(f"/api/races/{rid}/submissions/{ravi_sub['id']}").status_code == 404
    assert rita.get(f"/api/races/{rid}/submissions/{ravi_sub['id']}/video").status_code == 404
    assert ravi.get(f"/api/races/{rid}/submissions/{ravi_sub['id']}/video").status_code == 200
    replay = rita.get(f"/api/races/{rid}/replay").json()
    assert replay["laps"] and len(replay["laps"][0][0]) == 2
    # closing ends the window
    assert fay.post(f"/api/races/{rid}/close").json()["closed"] is True
    closed = ravi.post(f"/api/races/{rid}/submissions", json={"model": "quick"})
    assert closed.status_code == 409 and closed.json()["detail"]["field"] == "window"
    assert gus.post(f"/api/races/{rid}/clone").status_code == 404  # a private race he has not joined
    clone = console.admin.post(f"/api/races/{rid}/clone")
    assert clone.status_code == 201 and clone.json()["owner"] != race["owner"] and clone.json()["code"] != code
    assert clone.json()["laps"] == 2 and fay.get(f"/api/races/{clone.json()['id']}/submissions").status_code == 404
    assert console.admin.delete(f"/api/races/{clone.json()['id']}").json()["evaluations_stopped"] == 0
    # deleting a race stops its evaluations still queued or running
    short = fay.post("/api/races", json={"name": "Short-lived", "track": "oval", "laps": 1, "ranking": "best_lap"}).json()
    queued = ravi.post(f"/api/races/{short['id']}/submissions", json={"model": "quick"})
    assert queued.status_code == 202
    assert fay.delete(f"/api/races/{short['id']}").json()["evaluations_stopped"] == 1
    assert ravi.get(f"/api/races/{short['id']}").status_code == 404
    assert console.app.state.store.job(queued.json()["job"]).status in ("failed", "stopping", "interrupted", "done")


def test_quota_refuses_with_nothing_half_done(console, people, make_model):
    admin = console.admin
    sign_up(console, admin.post("/api/invites", json={"role": "racer"}).json()["code"], "quinn")
    quinn = token_client(console, "quinn")
    racer_model(console, "quinn", "fast", make_model)
    usage = quinn.get("/api/usage").json()
    assert usage["minutes_queued"] == 0 and usage["models"] == 1 and usage["storage_bytes"] > 0
    assert "quinn" in {u["user"] for u in admin.get("/api/usage").json()["users"]}
    assert quinn.get("/api/quotas").status_code == 403
    assert quinn.put("/api/users/quinn/quota", json={"minutes": 1000}).status_code == 403
    assert admin.put("/api/users/quinn/quota", json={"minutes": 1.0, "models": 1}).status_code == 200
    race = people["fay"].post("/api/races", json={"name": "Open race", "track": "oval", "laps": 1,
                                                     "ranking": "best_lap"}).json()
    refused = quinn.post(f"/api/races/{race['id']}/submissions", json={"model": "fast"})
    assert refused.status_code == 403 and "over your quota of 1 minutes" in refused.json()["detail"]["message"]
    assert quinn.get(f"/api/races/{race['id']}/submissions").json() == []  # nothing half-done
    model = quinn.post("/api/models", json={"name": "another", "track": "oval", "max_time_s": 10})
    assert model.status_code == 403 and "allows 1 models" in model.json()["detail"]["message"]
    assert quinn.get("/api/models/another").status_code == 404
    assert admin.put("/api/quotas", json={"global_minutes": -1}).status_code == 400


def test_pages_check_who_asks(console, people):
    rita, fay = people["rita"], people["fay"]
    for path in ("/races", "/profile", "/usage"):
        assert rita.get(path).status_code == 200
        assert console.client(None).get(path, headers={"accept": "application/json"}).status_code == 401
    assert rita.get("/races/new").status_code == 403 and rita.get("/invites").status_code == 403
    assert fay.get("/races/new").status_code == 200 and fay.get("/invites").status_code == 200
    assert console.client(None).get("/join/not-a-code").status_code == 410
    assert rita.get("/api/races/999999/leaderboard").status_code == 404
    paths = rita.get("/openapi.json").json()["paths"]
    for path in ("/api/races", "/api/races/{race_id}/submissions", "/api/races/{race_id}/leaderboard", "/api/invites",
                 "/api/users/{name}/role", "/api/usage", "/api/quotas", "/api/signup", "/api/tracks/catalogue"):
        assert path in paths, path
