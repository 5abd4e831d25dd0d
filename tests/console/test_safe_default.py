"""Safe by default: a console whose jobs would run unconfined serves only its admin, unless its
operator says otherwise with ``laplab serve --no-sandbox``; then every page says so."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from laplab.console.safety import NO_SANDBOX_BANNER, NO_SANDBOX_REFUSAL
from laplab.jobs.confinement import bubblewrap_works

PAGES = ("/", "/create", "/leaderboard")
BANNER_START = NO_SANDBOX_BANNER.split(":")[0]  # "Jobs on this console are NOT sandboxed (laplab serve --no-sandbox)"


def test_without_the_sandbox_only_the_admin_logs_in(tmp_path, serve_console):
    with serve_console(tmp_path, workers=1, seed_numba=False, sandbox=False,
                       allow_unsandboxed=False) as console:
        bob = console.add_user("bob")
        refused = bob.get("/api/models")
        assert refused.status_code == 403, refused.text
        message = refused.json()["detail"]["message"]
        assert message == NO_SANDBOX_REFUSAL
        assert "apt-get install bubblewrap" in message and "--no-sandbox" in message and "\n" not in message
        token = bob.headers["authorization"].split()[1]
        login = bob.get("/login", params={"token": token}, follow_redirects=False)
        assert login.status_code == 403 and "laplab_session" not in login.headers.get("set-cookie", "")
        assert "apt-get install bubblewrap" in login.text
        assert console.admin.get("/api/models").status_code == 200
        page = console.admin.get("/")
        assert page.status_code == 200 and "unsandboxed-banner" in page.text


def test_no_sandbox_lets_users_in_with_a_banner_on_every_page(tmp_path, serve_console):
    with serve_console(tmp_path, workers=1, seed_numba=False, sandbox=False, allow_unsandboxed=True) as console:
        bob = console.add_user("bob")
        assert bob.get("/api/models").status_code == 200
        for path in PAGES:
            page = bob.get(path)
            assert page.status_code == 200 and BANNER_START in page.text, path
        assert BANNER_START in console.client(None).get("/login").text


@pytest.mark.skipif(not bubblewrap_works(), reason="bubblewrap cannot build its sandbox here")
def test_a_sandboxed_console_admits_users_without_a_banner(tmp_path, serve_console):
    with serve_console(tmp_path, workers=1, seed_numba=False) as console:
        bob = console.add_user("bob")
        assert bob.get("/api/models").status_code == 200
        assert "unsandboxed-banner" not in bob.get("/").text


def _users_add(home, path: str, *extra: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "LAPLAB_HOME": str(home), "PATH": path}
    return subprocess.run([sys.executable, "-m", "laplab.cli", "users", "add", *extra], env=env,
                          capture_output=True, text=True, timeout=120)


def test_users_add_refuses_a_user_when_no_sandbox_is_available(tmp_path):
    no_bwrap = str(tmp_path / "empty-bin")  # PATH without bwrap: the sandbox is not available
    os.mkdir(no_bwrap)
    refused = _users_add(tmp_path / "home", no_bwrap, "carol")
    assert refused.returncode != 0
    assert "not created" in refused.stderr and "apt-get install bubblewrap" in refused.stderr, refused.stderr
    assert "Traceback" not in refused.stderr
    assert _users_add(tmp_path / "home", no_bwrap, "root2", "--admin").returncode == 0  # an admin is fine
    forced = _users_add(tmp_path / "home", no_bwrap, "carol", "--no-sandbox")
    assert forced.returncode == 0, forced.stderr
    if bubblewrap_works():
        assert _users_add(tmp_path / "home", os.environ["PATH"], "dave").returncode == 0
