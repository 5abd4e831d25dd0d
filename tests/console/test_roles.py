"""Who may do what, checked in one place (:mod:`laplab.console.roles`): a racer (and where it applies a
facilitator) gets the refusal of each purpose, as JSON from the API and as the HTML error page from
the pages; every route but the few public ones depends on the signed-in user."""

from __future__ import annotations

import html

import pytest

from laplab.console.roles import PERMISSIONS

HTML = {"accept": "text/html"}
ACCOUNTS = "Only an admin can manage accounts"
INVITES = "Only an admin or a race facilitator can create invitations"
RACES = "Only an admin or a race facilitator can create and run races"


@pytest.fixture(scope="module")
def people(tmp_path_factory, serve_console):
    with serve_console(tmp_path_factory.mktemp("roles-home"), workers=1, seed_numba=False) as console:
        store = console.app.state.store
        clients = {name: console.client(store.add_user(name, role=role)[1])
                   for name, role in (("rosa", "racer"), ("fritz", "facilitator"), ("gina", "facilitator"))}
        yield console, clients


def refused_json(answer, message: str, role: str) -> None:
    assert answer.status_code == 403, answer.text
    assert answer.headers["content-type"].startswith("application/json")
    assert answer.json()["detail"]["message"].startswith(f"{message} (you are a {role})")


def refused_page(answer, message: str, role: str) -> None:
    assert answer.status_code == 403, answer.text
    assert answer.headers["content-type"].startswith("text/html")
    assert 'id="error-page"' in answer.text and f"{message} (you are a {role})" in html.unescape(answer.text)


def test_a_racer_gets_each_purposes_refusal_from_the_api(people):
    console, clients = people
    rosa = clients["rosa"]
    for method, path, body, message in (
            ("GET", "/api/users", None, ACCOUNTS), ("POST", "/api/users", {"name": "mallory"}, ACCOUNTS),
            ("POST", "/api/users/fritz/disable", None, ACCOUNTS), ("DELETE", "/api/users/fritz", None, ACCOUNTS),
            ("POST", "/api/users/fritz/role", {"role": "racer"}, PERMISSIONS["change roles"].refusal),
            ("GET", "/api/quotas", None, PERMISSIONS["manage quotas"].refusal),
            ("PUT", "/api/users/rosa/quota", {"minutes": 1000}, PERMISSIONS["manage quotas"].refusal),
            ("POST", "/api/invites", {"role": "racer"}, INVITES), ("GET", "/api/invites", None, INVITES),
            ("DELETE", "/api/invites/abc", None, INVITES),
            ("POST", "/api/races", {"name": "Mine", "track": "oval"}, RACES)):
        refused_json(rosa.request(method, path, json=body), message, "racer")
    assert console.app.state.store.user_by_name("mallory") is None  # nothing done
    assert console.app.state.store.user_by_name("fritz").role == "facilitator"
    # a facilitator invites (racers) and runs races, and manages no accounts
    fritz = clients["fritz"]
    refused_json(fritz.get("/api/users"), ACCOUNTS, "facilitator")
    assert fritz.post("/api/invites", json={"role": "racer"}).status_code == 201
    assert fritz.get("/api/invites").status_code == 200
    race = fritz.post("/api/races", json={"name": "Fritz's race", "track": "oval", "laps": 1, "ranking": "best_lap"})
    assert race.status_code == 201, race.text
    rid = race.json()["id"]
    for method, path in (("PUT", f"/api/races/{rid}"), ("POST", f"/api/races/{rid}/close"),
                         ("DELETE", f"/api/races/{rid}")):
        body = {"name": "taken", "track": "oval"} if method == "PUT" else None
        refused_json(rosa.request(method, path, json=body), RACES, "racer")
        other = clients["gina"].request(method, path, json=body)  # a facilitator, not this race's
        assert other.status_code == 403 and "belongs to another facilitator" in other.json()["detail"]["message"]
    assert rosa.get(f"/api/races/{rid}").json()["name"] == "Fritz's race"


def test_a_racer_gets_each_purposes_refusal_as_a_page(people):
    console, clients = people
    rosa, fritz = clients["rosa"], clients["fritz"]
    refused_page(rosa.get("/users", headers=HTML), ACCOUNTS, "racer")
    refused_page(fritz.get("/users", headers=HTML), ACCOUNTS, "facilitator")
    refused_page(rosa.get("/invites", headers=HTML), INVITES, "racer")
    refused_page(rosa.get("/races/new", headers=HTML), RACES, "racer")
    rid = fritz.post("/api/races", json={"name": "Page race", "track": "oval"}).json()["id"]
    refused_page(rosa.get(f"/races/{rid}/edit", headers=HTML), RACES, "racer")
    assert "belongs to another facilitator" in clients["gina"].get(f"/races/{rid}/edit", headers=HTML).text
    for path in ("/invites", "/races/new", f"/races/{rid}/edit"):
        assert fritz.get(path, headers=HTML).status_code == 200
    for path in ("/users", "/invites", "/races/new"):
        assert console.admin.get(path, headers=HTML).status_code == 200
    # the pages' refusals are JSON to a script that asks for JSON
    refused_json(rosa.get("/invites"), INVITES, "racer")


PUBLIC = {"/login", "/login/password", "/join/{code}", "/api/signup", "/api/invites/check/{code}", "/api/health",
          "/static", "/logout"}


def test_every_route_but_the_public_ones_depends_on_the_signed_in_user(people):
    from fastapi.routing import APIRoute

    from laplab.console.auth import current_user, require_user
    console, _ = people

    def asks_who(dependant) -> bool:
        return any(d.call in (current_user, require_user) or asks_who(d) for d in dependant.dependencies)
    unchecked = sorted(route.path for route in console.app.routes
                       if isinstance(route, APIRoute) and route.path not in PUBLIC and not asks_who(route.dependant))
    assert unchecked == []


def test_the_track_leaderboard_shows_display_names_not_login_names(people):
    from tests.evaluate.test_leaderboard import add_evaluation
    console, clients = people
    store, accounts = console.app.state.store, console.app.state.accounts
    rosa = store.user_by_name("rosa")
    accounts.update_profile(rosa, "Speedy Rosa", "IT", "#00aa00")
    add_evaluation(f"u{rosa.id}-fast", [10.0, 11.0, 12.0], track="oval")  # hand-made laps: no job to wait for
    store.claim_model(f"u{rosa.id}-fast", rosa.id)
    console.app.state.service.models_changed()
    for client, sees_model in ((clients["fritz"], False), (clients["rosa"], True)):
        entry = client.get("/api/leaderboard?track=oval").json()[0]["entries"][0]
        assert (entry["user"], entry["alias"], entry["initials"], entry["colour"], entry["country"]) == (
            "Speedy Rosa", "Speedy Rosa", "SR", "#00aa00", "IT")
        assert "rosa" not in {str(v) for v in entry.values()}  # the login name is nowhere on the board
        assert entry["model"] == ("fast" if sees_model else None)
