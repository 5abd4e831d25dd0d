"""Tokens can be revoked and users disabled or removed, with `laplab users` (another process, while
the console runs) and from the console by the admin; the change takes effect at once."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest


@pytest.fixture(scope="module")
def accounts(tmp_path_factory, serve_console):
    home = tmp_path_factory.mktemp("accounts-home")
    with serve_console(home, workers=1, seed_numba=False) as console:
        console.home = home
        yield console


def _users(home, *argv: str) -> subprocess.CompletedProcess:
    done = subprocess.run([sys.executable, "-m", "laplab.cli", "users", *argv], env={**os.environ, "LAPLAB_HOME": str(home)},
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done


def _until(check, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        assert time.monotonic() < deadline, "the change did not reach the running console"
        time.sleep(0.1)


def _session(console, token: str):
    login = console.client(None).get("/login", params={"token": token}, follow_redirects=False)
    assert login.status_code == 303, login.text
    client = console.client(None)
    client.cookies.set("laplab_session", login.cookies["laplab_session"])
    return client


def test_revoking_with_the_cli_ends_tokens_and_sessions_of_a_running_console(accounts):
    _, token = accounts.app.state.store.add_user("bob")
    bob, browser = accounts.client(token), _session(accounts, token)
    assert bob.get("/api/me").status_code == 200 and browser.get("/api/me").status_code == 200
    _users(accounts.home, "revoke", "bob")
    _until(lambda: bob.get("/api/me").status_code == 401)
    assert browser.get("/api/me").status_code == 401


def test_one_token_can_be_revoked_and_the_others_keep_working(accounts):
    store = accounts.app.state.store
    user, first = store.add_user("two-tokens")
    second = store.add_token(user.id, "laptop")
    assert accounts.client(first).get("/api/me").status_code == 200
    assert accounts.client(second).get("/api/me").status_code == 200
    listed = _users(accounts.home, "list", "--tokens").stdout
    assert first.split(".")[0] in listed and "laptop" in listed and first.split(".")[1] not in listed
    _users(accounts.home, "revoke", "two-tokens", first.split(".")[0])
    _until(lambda: accounts.client(first).get("/api/me").status_code == 401)
    assert accounts.client(second).get("/api/me").status_code == 200


def test_a_disabled_user_is_refused_until_enabled(accounts):
    _, token = accounts.app.state.store.add_user("carol")
    carol = accounts.client(token)
    assert carol.get("/api/models").status_code == 200
    _users(accounts.home, "disable", "carol")
    _until(lambda: carol.get("/api/models").status_code == 401)
    assert "(disabled)" in _users(accounts.home, "list").stdout
    _users(accounts.home, "enable", "carol")
    _until(lambda: carol.get("/api/models").status_code == 200)


def test_a_removed_user_is_gone_and_their_models_pass_to_the_admin(accounts):
    store = accounts.app.state.store
    dave, token = store.add_user("dave")
    store.claim_model("daves-model", dave.id)
    (accounts.home / "models" / "daves-model").mkdir(parents=True)
    assert accounts.client(token).get("/api/models/daves-model").status_code == 200
    _users(accounts.home, "remove", "dave")
    _until(lambda: accounts.client(token).get("/api/me").status_code == 401)
    assert "dave" not in _users(accounts.home, "list").stdout.split()
    accounts.app.state.service.models_changed()
    owners = {m["name"]: m["owner"] for m in accounts.admin.get("/api/models").json()}
    assert owners["daves-model"] == "admin"


def test_the_admin_manages_accounts_from_the_console(accounts):
    created = accounts.admin.post("/api/users", json={"name": "erin"})
    assert created.status_code == 201, created.text
    erin = accounts.client(created.json()["token"])
    assert erin.get("/api/me").json()["name"] == "erin"
    assert erin.get("/api/users").status_code == 403
    assert erin.post("/api/users", json={"name": "mallory"}).status_code == 403
    names = [u["name"] for u in accounts.admin.get("/api/users").json()]
    assert "erin" in names
    assert accounts.admin.post("/api/users/admin/disable").status_code == 409  # not yourself
    assert accounts.admin.post("/api/users/erin/disable").status_code == 200
    assert erin.get("/api/me").status_code == 401
    assert accounts.admin.post("/api/users/erin/enable").status_code == 200
    assert erin.get("/api/me").status_code == 200
    token_id = created.json()["token"].split(".")[0]
    assert accounts.admin.delete(f"/api/users/erin/tokens/{token_id}").json()["revoked"] == 1
    assert erin.get("/api/me").status_code == 401
    fresh = accounts.admin.post("/api/users/erin/tokens").json()["token"]
    assert accounts.client(fresh).get("/api/me").status_code == 200
    assert accounts.admin.delete("/api/users/erin").status_code == 200
    assert accounts.client(fresh).get("/api/me").status_code == 401
    assert accounts.admin.delete("/api/users/nobody").status_code == 404


def test_disabling_a_user_stops_their_jobs(accounts):
    _, token = accounts.app.state.store.add_user("busy")
    busy = accounts.client(token)
    created = busy.post("/api/models", json={"name": "long-one", "max_time_s": 600,
                                             "hyperparameters": {"num_episodes_between_training": 2}})
    assert created.status_code == 201, created.text
    job_id = created.json()["job"]["id"]
    _users(accounts.home, "disable", "busy")
    store = accounts.app.state.store
    _until(lambda: store.job(job_id).status not in ("queued", "running"), timeout_s=10)
    _until(lambda: store.job(job_id).status not in ("stopping",), timeout_s=120)  # it stops, keeping its model
