"""Limits a class needs: a cap on a training's max time, request bodies refused before they are
read past their limit, login attempts throttled per token id. A real server on a real socket."""

from __future__ import annotations

import socket
import time
from urllib.parse import urlparse

import pytest

from laplab.jobs.confinement import JobLimits


@pytest.fixture(scope="module")
def limited(tmp_path_factory, serve_console):
    with serve_console(tmp_path_factory.mktemp("limits-home"), workers=1, seed_numba=False) as console:
        yield console


def test_max_time_is_capped_at_24_hours_by_default(limited, make_model):
    over = limited.admin.post("/api/models", json={"name": "long", "max_time_s": 24 * 3600 + 1})
    assert over.status_code == 400, over.text
    detail = over.json()["detail"]
    assert detail["field"] == "max_time_s" and "--max-job-time" in detail["message"]
    assert "long" not in [m["name"] for m in limited.admin.get("/api/models").json()]
    make_model("capped-source")
    clone = limited.admin.post("/api/models/capped-source/clone", json={"name": "c2", "max_time_s": 10 ** 6})
    assert clone.status_code == 400 and clone.json()["detail"]["field"] == "max_time_s", clone.text
    resume = limited.admin.post("/api/models/capped-source/resume", json={"max_time_s": 10 ** 6})
    assert resume.status_code == 400 and resume.json()["detail"]["field"] == "max_time_s", resume.text


def test_the_cap_is_a_server_setting(tmp_path, serve_console):
    with serve_console(tmp_path, workers=1, seed_numba=False, limits=JobLimits.console(max_time_s=600)) as console:
        over = console.admin.post("/api/models", json={"name": "m", "max_time_s": 601})
        assert over.status_code == 400 and over.json()["detail"]["field"] == "max_time_s"


def _raw(url: str, request: bytes, timeout: float = 10.0) -> bytes:
    where = urlparse(url)
    with socket.create_connection((where.hostname, where.port), timeout=timeout) as sock:
        sock.sendall(request)
        answer = b""
        while b"\r\n\r\n" not in answer:
            chunk = sock.recv(65536)
            if not chunk:
                break
            answer += chunk
        return answer


def test_a_body_over_the_limit_is_refused_before_it_is_read(limited):
    # the body is announced (50 MB) and never sent: only a server that does not wait for it answers
    started = time.monotonic()
    answer = _raw(limited.url, b"POST /api/reward/validate HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                              b"Content-Length: 50000000\r\n\r\n")
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
    assert time.monotonic() - started < 5


def test_a_chunked_body_is_cut_at_the_limit(limited):
    sent = []

    def chunks():
        for _ in range(64):  # 4 MiB in 64 KiB pieces, no Content-Length
            sent.append(1)
            yield b"x" * 65536

    answer = limited.admin.post("/api/reward/validate", content=chunks(), headers={"Content-Type": "application/json"})
    assert answer.status_code == 413, answer.text
    assert "not read" in answer.json()["detail"]["message"]


def test_an_import_may_be_larger_than_a_json_request(limited):
    archive = b"\0" * (2 << 20)
    answer = limited.admin.post("/api/models/import", files={"file": ("m.tar.gz", archive)})
    assert answer.status_code == 400, answer.text  # read, and refused as an archive, not as a size


def test_failed_logins_are_throttled_per_token_id(limited):
    _, token = limited.app.state.store.add_user("throttled")
    _, other = limited.app.state.store.add_user("unaffected")
    token_id = token.split(".")[0]
    for attempt in range(5):
        wrong = limited.client(f"{token_id}.wrong-secret-{attempt}").get("/api/me")
        assert wrong.status_code == 401, wrong.text
    blocked = limited.client(token).get("/api/me")
    assert blocked.status_code == 429, blocked.text
    assert int(blocked.headers["retry-after"]) > 0 and "too many failed logins" in blocked.json()["detail"]["message"]
    page = limited.client(None).get("/login", params={"token": token})
    assert page.status_code == 429 and "too many failed logins" in page.text
    assert limited.client(other).get("/api/me").status_code == 200
