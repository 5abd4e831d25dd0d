"""The console's JSON API against a real server: authentication, the authorisation matrix, CSRF,
bad inputs answered with laplab's messages, tracks, examples and the leaderboard."""

from __future__ import annotations

import sqlite3

import pytest


BROKEN_REWARD = "def reward_function(params):\n    speed = params['speed']\n    return speed / undefined_name\n"


def test_health_is_public_and_everything_else_needs_a_user(console):
    anonymous = console.client(None)
    assert anonymous.get("/api/health").status_code == 200
    assert anonymous.get("/login").status_code == 200
    routes = []
    for route in console.app.router.routes:
        routes += getattr(getattr(route, "original_router", None), "routes", [route])
    public = ("/api/health", "/login", "/login/password", "/join/{code}", "/api/signup", "/api/invites/check/{code}")
    routes = [r for r in routes if getattr(r, "path", None) and r.path not in public]  # sign-in and sign-up
    assert len(routes) > 25 and "/openapi.json" in [r.path for r in routes]
    for route in routes:
        path = (route.path.replace("{name}", "m").replace("{job_id}", "1").replace("{stamp}", "20240101000000")
                .replace("{path:path}", "console.css").replace("{race_id}", "1").replace("{submission_id}", "1"))
        for method in route.methods - {"HEAD"}:
            answer = anonymous.request(method, path, headers={"Accept": "application/json"})
            assert answer.status_code == 401, (method, path, answer.status_code)
    assert anonymous.get("/api/models", headers={"Authorization": "Bearer nope.wrong"}).status_code == 401


def test_openapi_lists_the_routes(console):
    spec = console.admin.get("/openapi.json").json()
    for path in ("/api/models", "/api/models/{name}", "/api/models/{name}/stop", "/api/models/{name}/clone",
                 "/api/models/{name}/exports", "/api/models/{name}/exports/{job_id}",
                 "/api/models/{name}/evaluations", "/api/models/{name}/evaluations/{job_id}",
                 "/api/models/{name}/events", "/api/models/{name}/download", "/api/reward/validate",
                 "/api/leaderboard", "/api/tracks", "/api/health"):
        assert path in spec["paths"], path


def test_tokens_are_stored_only_hashed(console, admin_token):
    _, token = console.app.state.store.add_user("hashcheck")
    secret = token.split(".", 1)[1]
    raw = console.app.state.store.path.read_bytes()
    wal = console.app.state.store.path.with_name("laplab.db-wal")
    raw += wal.read_bytes() if wal.exists() else b""
    assert secret.encode() not in raw and admin_token.encode() not in raw
    rows = sqlite3.connect(console.app.state.store.path).execute("SELECT hash FROM tokens").fetchall()
    assert rows and all(r[0].startswith("$argon2") for r in rows)


def test_browser_login_gives_an_httponly_samesite_cookie_and_csrf_guards_writes(console, admin_token):
    import httpx
    with httpx.Client(base_url=console.url, timeout=60) as browser:
        assert browser.post("/login", data={"token": "wrong"}).status_code == 401
        answer = browser.post("/login", data={"token": admin_token})
        assert answer.status_code == 303
        cookie = answer.headers["set-cookie"].lower()
        assert "httponly" in cookie and "samesite=strict" in cookie
        assert browser.get("/api/models").status_code == 200
        page = browser.get("/")
        assert page.status_code == 200 and "Your models" in page.text
        csrf = page.text.split('name="csrf-token" content="', 1)[1].split('"', 1)[0]
        body = {"source": "def reward_function(params):\n    return 1.0\n"}
        assert browser.post("/api/reward/validate", json=body).status_code == 403
        assert browser.post("/api/reward/validate", json=body, headers={"X-CSRF-Token": "forged"}).status_code == 403
        good = browser.post("/api/reward/validate", json=body, headers={"X-CSRF-Token": csrf})
        assert good.status_code == 200 and good.json()["ok"] is True


def test_jupyter_style_login_link(console, admin_token):
    import httpx
    with httpx.Client(base_url=console.url, timeout=60) as browser:
        answer = browser.get(f"/login?token={admin_token}")
        assert answer.status_code == 303 and browser.get("/api/me").json()["admin"] is True


def test_reward_validation_reports_the_line(console):
    answer = console.admin.post("/api/reward/validate", json={"source": BROKEN_REWARD, "track": "oval"})
    assert answer.status_code == 200
    result = answer.json()
    assert result["ok"] is False and result["errors"][0]["line"] == 3
    assert "undefined_name" in result["errors"][0]["message"] and "line 3" in result["errors"][0]["message"]
    syntax = console.admin.post("/api/reward/validate", json={"source": "def reward_function(params):\n    return (\n"})
    assert syntax.json()["ok"] is False and syntax.json()["errors"][0]["line"] in (2, 3)
    ok = console.admin.post("/api/reward/validate", json={"source": "def reward_function(params):\n    return 1.0\n"})
    assert ok.json()["ok"] is True and ok.json()["calls"] > 100


@pytest.mark.parametrize("body, status, field, words", [
    ({"name": "bad name"}, 400, "name", "invalid model name"),
    ({"name": "m-hp", "hyperparameters": {"num_epochs": 1}}, 400, "hyperparameters", "num_epochs"),
    ({"name": "m-hp2", "hyperparameters": {"learning_rate": 0.1}}, 400, "hyperparameters", "lr"),
    ({"name": "m-meta", "model_metadata": {"sensor": ["RADAR"]}}, 400, "model_metadata", "RADAR"),
    ({"name": "m-as", "model_metadata": {"action_space": [{"steering_angle": 90, "speed": 1}]}}, 400, "model_metadata", "steering"),
    ({"name": "m-track", "track": "no_such_track"}, 400, "track", "no_such_track"),
    ({"name": "m-path", "track": "/root/secret-route.npy"}, 400, "track", "unknown track"),
    ({"name": "m-time", "max_time_s": -5}, 400, "max_time_s", "max time"),
    ({"name": "m-reward", "reward_function": BROKEN_REWARD}, 400, "reward_function", "line 3"),
    ({"name": "m-unknown", "colour": "red"}, 422, "colour", "Extra inputs"),
    ({"name": "m-physics", "physics": "7b"}, 400, "physics", "physics '7b': write 4, 5 or 6"),
    ({"track": "oval"}, 422, "name", "Field required"),
])
def test_create_model_refuses_bad_input_with_laplabs_message(console, body, status, field, words):
    answer = console.admin.post("/api/models", json=body)
    assert answer.status_code == status, answer.text
    detail = answer.json()["detail"]
    assert detail["field"] == field and words.lower() in detail["message"].lower(), detail
    assert body.get("name") is None or body["name"] not in [m["name"] for m in console.admin.get("/api/models").json()]


def test_malformed_json_is_a_422_with_a_message(console):
    answer = console.admin.post("/api/models", content=b"{not json", headers={"Content-Type": "application/json"})
    assert answer.status_code == 422 and answer.json()["detail"]["message"]


def test_authorisation_matrix(console, make_model):
    alice, bob = console.add_user("alice"), console.add_user("bob")
    make_model("bob-model")
    console.app.state.store.claim_model("bob-model", console.app.state.store.user_by_name("bob").id)
    assert "bob-model" in [m["name"] for m in bob.get("/api/models").json()]
    assert "bob-model" not in [m["name"] for m in alice.get("/api/models").json()]
    for method, path, body in (("GET", "/api/models/bob-model", None), ("POST", "/api/models/bob-model/stop", None),
                               ("DELETE", "/api/models/bob-model", None), ("GET", "/api/models/bob-model/download", None),
                               ("GET", "/api/models/bob-model/events", None), ("GET", "/api/models/bob-model/evaluations", None),
                               ("POST", "/api/models/bob-model/evaluations", {"trials": 1}),
                               ("POST", "/api/models/bob-model/clone", {"name": "stolen"}),
                               ("POST", "/api/models/bob-model/resume", {}), ("GET", "/api/models/bob-model/log", None),
                               ("GET", "/models/bob-model", None), ("GET", "/models/bob-model/report", None),
                               ("GET", "/models/bob-model/report/", None), ("GET", "/models/bob-model/report/training.png", None),
                               ("POST", "/api/models/bob-model/exports", {"format": "car"}),
                               ("GET", "/api/models/bob-model/exports", None), ("GET", "/api/models/bob-model/exports/1/file", None),
                               ("GET", "/create?clone=bob-model", None)):
        answer = alice.request(method, path, json=body)
        assert answer.status_code == 404, (method, path, answer.status_code)
    assert bob.get("/api/models/bob-model").json()["status"] == "ready"
    assert console.admin.get("/api/models/bob-model").status_code == 200  # the admin (teacher) sees all
    # names are per user: alice may have a bob-model too, and the answer says nothing about bob's
    mine = alice.post("/api/models", json={"name": "bob-model", "max_time_s": 5,
                                         "hyperparameters": {"num_episodes_between_training": 2}})
    assert mine.status_code == 201, mine.text
    assert alice.post("/api/models", json={"name": "bob-model"}).status_code == 409  # her own, now
    alice.post("/api/models/bob-model/stop")
    assert bob.get("/api/models/bob-model/download?format=zip").status_code == 422
    assert bob.delete("/api/models/bob-model").status_code == 200
    assert bob.get("/api/models/bob-model").status_code == 404


def test_cli_models_show_up_owned_by_the_admin(console, make_model):
    make_model("cli-made")
    listed = {m["name"]: m for m in console.admin.get("/api/models").json()}
    assert listed["cli-made"]["owner"] == "admin" and listed["cli-made"]["status"] == "ready"
    assert listed["cli-made"]["track"] == "classic_2018" and listed["cli-made"]["sensor"] == ["STATE"]
    assert "cli-made" not in [m["name"] for m in console.add_user("carol").get("/api/models").json()]


def test_evaluation_requests_are_checked(console, make_model):
    make_model("eval-checks")
    assert console.admin.post("/api/models/eval-checks/evaluations", json={"trials": 9}).json()["detail"]["message"].startswith("trials")
    assert console.admin.post("/api/models/eval-checks/evaluations", json={"trials": 1, "track": "nowhere"}).status_code == 400
    assert console.admin.post("/api/models/eval-checks/evaluations", json={"off_track_penalty": -1}).status_code == 400
    assert console.admin.get("/api/models/eval-checks/evaluations/999").status_code == 404
    assert console.admin.post("/api/models/eval-checks/stop").status_code == 409
    from laplab.evaluate.trials import EvaluationError, EvaluationSettings
    with pytest.raises(EvaluationError) as raised:
        EvaluationSettings(crash_penalty=float("nan"))
    answer = console.admin.post("/api/models/eval-checks/evaluations", json={"crash_penalty": "NaN"})
    assert answer.status_code == 400 and answer.json()["detail"]["message"] == str(raised.value)  # the library's words
    forced = console.admin.post("/api/models/eval-checks/evaluations", json={"trials": 50, "force": True})
    assert forced.status_code == 422 and forced.json()["detail"]["field"] == "force"  # the console keeps 1..5 trials


def test_the_evaluate_request_is_evaluation_settings(console):
    """One definition: the API's Evaluate schema has EvaluationSettings' fields and defaults (but force)."""
    from dataclasses import fields

    from laplab.evaluate.trials import EvaluationSettings
    schema = console.admin.get("/openapi.json").json()["components"]["schemas"]["Evaluate"]
    expected = {f.name: f.default for f in fields(EvaluationSettings) if f.name != "force"}
    assert set(schema["properties"]) == set(expected) and schema["additionalProperties"] is False
    for name, default in expected.items():
        assert schema["properties"][name].get("default") == default, name


def test_tracks_examples_and_empty_leaderboard(console):
    tracks = console.admin.get("/api/tracks").json()
    oval = next(t for t in tracks if t["name"] == "oval")
    assert oval["length_m"] > 5 and 0.3 < oval["width_m"] < 2
    picture = console.admin.get(oval["picture"])
    assert picture.status_code == 200 and picture.content[:4] == b"\x89PNG"
    outline = console.admin.get("/api/tracks/oval/outline").json()
    assert len(outline["center"]) > 20 and len(outline["inner"]) == len(outline["center"])
    assert console.admin.get("/api/tracks/nowhere/outline").status_code == 404
    examples = console.admin.get("/api/reward/examples").json()
    assert {"follow_centerline", "lap_pace"} <= {e["name"] for e in examples}
    assert console.admin.get("/api/leaderboard?track=oval").json() in ([], [{"track": "oval", "entries": []}])


def test_import_refuses_a_file_that_is_not_an_archive(console):
    answer = console.admin.post("/api/models/import", files={"file": ("x.tar.gz", b"not a tarball")})
    assert answer.status_code == 400 and "gzip" in answer.json()["detail"]["message"]


def test_create_model_with_deepracers_car_of_a_generation(console):
    """The Create form's physics: the model trains with that car and its folder records it."""
    tiny = {"num_episodes_between_training": 4, "batch_size": 32, "num_epochs": 3}
    created = console.admin.post("/api/models", json={"name": "v4-car", "physics": "4", "max_time_s": 3,
                                                       "hyperparameters": tiny})
    assert created.status_code == 201, created.text
    model = console.wait_for(console.admin, "v4-car", ("ready", "failed"), timeout_s=300)
    assert model["status"] == "ready", model.get("error")
    detail = console.admin.get("/api/models/v4-car").json()
    assert detail["config"]["vehicle"] == "deepracer-v4" and detail["config"]["model_metadata"]["version"] == "4"
