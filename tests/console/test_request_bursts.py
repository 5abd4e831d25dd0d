"""Many pages and scripts at once: a new token is checked with argon2 once, not once per request
in flight; `GET /api/models` builds one list at a time, and a stale list is answered at once while
a new one is built in the background."""

from __future__ import annotations

import json
import threading
import time

import pytest

pytest.importorskip("fastapi")
httpx = pytest.importorskip("httpx")

TOKEN = "list-test-token"


@pytest.fixture()
def app_and_service(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    monkeypatch.setenv("LAPLAB_ADMIN_TOKEN", TOKEN)
    from laplab.console.app import create_app
    app = create_app(1, sandbox=False, warm_cache=False)
    return app, app.state.service


def _counting_builder(service, gate: threading.Event | None = None):
    calls = []

    def build(user):
        calls.append(user.id)
        if gate is not None:
            assert gate.wait(30)
        else:
            time.sleep(0.2)
        return [{"name": f"build-{len(calls)}", "created": None}]

    service._visible_models = build
    return calls


def test_requests_arriving_together_share_one_build(app_and_service):
    _, service = app_and_service
    calls = _counting_builder(service)
    admin = service.store.admin()
    bodies = []
    threads = [threading.Thread(target=lambda: bodies.append(service.visible_models_json(admin))) for _ in range(20)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert len(calls) == 1 and len(bodies) == 20 and len(set(bodies)) == 1


def test_a_stale_list_is_answered_at_once_and_rebuilt_once_in_the_background(app_and_service):
    from fastapi.testclient import TestClient

    app, service = app_and_service
    gate = threading.Event()
    with TestClient(app, headers={"Authorization": f"Bearer {TOKEN}"}) as client:
        service._visible_models = lambda user: [{"name": "first", "created": None}]
        assert [m["name"] for m in client.get("/api/models").json()] == ["first"]
        calls = _counting_builder(service, gate)
        admin = service.store.admin()
        built_at, body = service._list_cache[admin.id]
        service._list_cache[admin.id] = (built_at - 60, body)  # stale
        answers = [client.get("/api/models").json() for _ in range(10)]  # the build is held by the gate
        assert all([m["name"] for m in a] == ["first"] for a in answers)
        gate.set()
        deadline = time.monotonic() + 30
        while json.loads(service._list_cache[admin.id][1])[0]["name"] != "build-1" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert [m["name"] for m in client.get("/api/models").json()] == ["build-1"]
        assert calls == [admin.id]


def test_a_status_change_is_never_hidden_by_a_build_that_started_before_it(app_and_service):
    _, service = app_and_service
    admin = service.store.admin()
    gate = threading.Event()
    _counting_builder(service, gate)
    builder = threading.Thread(target=service.visible_models_json, args=(admin,))
    builder.start()
    time.sleep(0.1)
    service.models_changed()  # e.g. a job finished while the list was being built
    gate.set()
    builder.join(30)
    assert service.cached_models_json(admin) == (None, False)


def test_requests_with_a_new_token_arriving_together_share_one_argon2_check(app_and_service, monkeypatch):
    from laplab.jobs import users as db  # the accounts' half of the job store
    _, service = app_and_service
    real_hasher, checks = db._hasher, []

    class CountingHasher:
        def verify(self, hashed, token):
            checks.append(token)
            time.sleep(0.1)
            return real_hasher().verify(hashed, token)

    monkeypatch.setattr(db, "_hasher", CountingHasher)
    users = []
    threads = [threading.Thread(target=lambda: users.append(service.store.user_for_token(TOKEN))) for _ in range(20)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert len(users) == 20 and {u.name for u in users} == {service.store.admin().name}
    assert checks == [TOKEN]
    assert service.store.user_for_token("not-a-token") is None
