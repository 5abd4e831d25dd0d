"""Failed logins are counted in the console's database: a restart of the server does not forget them."""

from __future__ import annotations

import pytest

from laplab.console.limits import LoginThrottle, LoginThrottled


def test_a_blocked_key_stays_blocked_after_a_restart_and_others_are_not(tmp_path):
    database = tmp_path / "console.sqlite"
    throttle = LoginThrottle(database, attempts=3, window_s=60.0)
    for _ in range(3):
        throttle.check("abc123")
        throttle.failed("abc123")
    with pytest.raises(LoginThrottled, match="too many failed logins"):
        throttle.check("abc123")
    throttle.close()
    restarted = LoginThrottle(database, attempts=3, window_s=60.0)  # a new server process on the same database
    with pytest.raises(LoginThrottled) as blocked:
        restarted.check("abc123")
    assert 1 <= blocked.value.retry_after_s <= 60
    restarted.check("someone-else")


def test_failures_older_than_the_window_do_not_count(tmp_path, monkeypatch):
    clock = [1000.0]
    monkeypatch.setattr("laplab.console.limits.time.time", lambda: clock[0])
    throttle = LoginThrottle(tmp_path / "db.sqlite", attempts=2, window_s=10.0)
    throttle.failed("k")
    clock[0] += 11
    throttle.failed("k")
    throttle.check("k")  # one failure within the window
    throttle.failed("k")
    with pytest.raises(LoginThrottled) as blocked:
        throttle.check("k")
    assert blocked.value.retry_after_s == 10
    clock[0] += 10.5
    throttle.check("k")
