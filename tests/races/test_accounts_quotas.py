"""Accounts and quotas on a bare console database: the roles migration of an old database,
invitations (one use, expiry, who may invite whom), passwords, profiles, and the quota ledger
(a job reserves its budget when queued and returns what it did not use when it ends)."""

from __future__ import annotations

import sqlite3
import time

import pytest

from laplab.jobs.accounts import AccountError, Accounts
from laplab.jobs.db import JobStore
from laplab.jobs.quotas import QuotaExceeded, Quotas


@pytest.fixture
def store(tmp_path):
    store = JobStore(tmp_path / "laplab.db")
    yield store
    store.close()


def test_old_database_gets_roles(tmp_path):
    path = tmp_path / "old.db"
    db = sqlite3.connect(path)
    db.executescript("CREATE TABLE users (id INTEGER PRIMARY KEY, name TEXT UNIQUE NOT NULL, "
                     "is_admin INTEGER NOT NULL DEFAULT 0, created REAL NOT NULL);"
                     "INSERT INTO users VALUES (1, 'boss', 1, 0), (2, 'kid', 0, 0);")
    db.commit()
    db.close()
    store = JobStore(path)
    assert [(u.name, u.role, u.is_admin) for u in store.users()] == [("boss", "admin", True), ("kid", "racer", False)]
    store.close()


def test_invites_one_use_expiry_and_who_invites(store):
    admin, _ = store.add_user("boss", is_admin=True)
    accounts = Accounts(store)
    fac_invite = accounts.create_invite(admin, "facilitator")
    fay = accounts.sign_up(fac_invite["code"], "fay", "fay-password", alias="Fay Jones", country="us")
    assert fay.role == "facilitator" and accounts.profile(fay.id).initials == "FJ"
    with pytest.raises(AccountError, match="already been used"):
        accounts.sign_up(fac_invite["code"], "other", "other-password")
    with pytest.raises(AccountError, match="cannot invite a admin"):
        accounts.create_invite(fay, "admin")
    racer_invite = accounts.create_invite(fay, "racer", lifetime_s=60)
    store.execute("UPDATE invites SET expires=? WHERE id=?", (time.time() - 1, racer_invite["id"]))
    with pytest.raises(AccountError, match="expired"):
        accounts.sign_up(racer_invite["code"], "late", "late-password")
    good = accounts.create_invite(fay, "racer")
    with pytest.raises(AccountError, match="password"):
        accounts.sign_up(good["code"], "short", "short")
    with pytest.raises(AccountError, match="name"):
        accounts.sign_up(good["code"], "fay", "another-password")  # taken: the invitation stays unused
    rita = accounts.sign_up(good["code"], "rita", "rita-password")
    assert accounts.user_for_password("rita", "rita-password") == rita
    assert accounts.user_for_password("rita", "wrong-password") is None
    with pytest.raises(AccountError, match="current password is wrong"):
        accounts.set_password(rita, "nope", "new-password")
    accounts.set_password(rita, "rita-password", "new-password")
    assert accounts.user_for_password("rita", "new-password") == rita
    assert {i["status"] for i in accounts.invites(admin)} == {"used", "expired"}
    assert [i["id"] for i in accounts.invites(fay)] == [good["id"], racer_invite["id"]]
    with pytest.raises(AccountError, match="only admin"):
        accounts.set_role("boss", "racer")
    assert accounts.set_role("rita", "facilitator").runs_races


def test_quota_ledger_reserves_then_returns(store):
    rita, _ = store.add_user("rita")
    quotas = Quotas(store)
    quotas.set_user_limits(rita.id, minutes=10.0, models=None)
    job = store.add_job("train", "u2-m", rita.id, {"max_time_s": 480.0})
    usage = quotas.usage(rita.id, 3600.0)
    assert usage.queued_min == pytest.approx(8.0) and usage.used_min == 0.0
    with pytest.raises(QuotaExceeded, match="reserves 3.0 compute minutes, over your quota of 10 minutes"):
        quotas.check_job(rita.id, "evaluate", {"trials": 1, "max_trial_time": 180.0}, 3600.0)
    store.update_job(job.id, status="done", started=100.0, finished=160.0)  # ran one minute of its eight
    usage = quotas.usage(rita.id, 3600.0)
    assert usage.queued_min == 0.0 and usage.used_min == pytest.approx(1.0)
    quotas.check_job(rita.id, "evaluate", {"trials": 1, "max_trial_time": 180.0}, 3600.0)
    quotas.set_settings({"global_minutes": 2.0})
    with pytest.raises(QuotaExceeded, match="the console's quota"):
        quotas.check_job(rita.id, "evaluate", {"trials": 1, "max_trial_time": 180.0}, 3600.0)
    quotas.set_settings({"global_minutes": None, "new_user_minutes": 5.0, "new_user_models": 2})
    newbie, _ = store.add_user("newbie")
    quotas.apply_new_user_quota(newbie.id)
    assert quotas.user_limits(newbie.id) == (5.0, 2)
    store.claim_model("u3-a", newbie.id)
    store.claim_model("u3-b", newbie.id)
    with pytest.raises(QuotaExceeded, match="allows 2 models and 2 exist"):
        quotas.check_job(newbie.id, "train", {"max_time_s": 60.0}, 3600.0)
    quotas.check_job(newbie.id, "resume", {"max_time_s": 60.0}, 3600.0)  # a resume makes no new model


def test_users_cli_roles(tmp_path, monkeypatch, capsys):
    from laplab.cli import main
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    assert main(["users", "add", "fay", "--role", "facilitator", "--no-sandbox"]) == 0
    assert main(["users", "add", "kid", "--no-sandbox"]) == 0
    assert main(["users", "add", "bad", "--admin", "--role", "racer"]) != 0
    capsys.readouterr()
    assert main(["users", "list"]) == 0
    listing = capsys.readouterr().out
    assert "fay  (facilitator)" in listing and "kid  (racer)" in listing and "admin  (admin)" in listing


def test_a_user_made_by_the_cli_gets_the_new_user_quota(tmp_path, monkeypatch):
    from laplab.cli import main
    from laplab.jobs.db import JobStore
    from laplab.jobs.quotas import Quotas
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    assert main(["users", "add", "first", "--no-sandbox"]) == 0  # makes the admin and the database
    store = JobStore()
    Quotas(store).set_settings({"new_user_minutes": 30.0, "new_user_models": 3})
    assert main(["users", "add", "second", "--no-sandbox"]) == 0
    store = JobStore()
    assert Quotas(store).user_limits(store.user_by_name("second").id) == (30.0, 3)
    assert Quotas(store).user_limits(store.user_by_name("admin").id) == (None, None)
