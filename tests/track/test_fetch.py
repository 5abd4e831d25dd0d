"""``laplab tracks fetch`` against local HTTP servers (127.0.0.1, ephemeral port): never the internet."""

from __future__ import annotations

import functools
import http.server
import io
import json
import socket
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from laplab.cli import main
from laplab.track import fetch, registry
from laplab.track.geometry import load_route_file

REFERENCE_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "reference-tracks"
OVAL_BYTES = (registry.BUILTIN_DIR / "oval.npy").read_bytes()


class QuietFileHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:
        pass


@contextmanager
def serve(handler):
    """Run ``handler`` on 127.0.0.1 (ephemeral port) in a thread; yields the base URL."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=5)


def npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def open_route() -> np.ndarray:
    """A valid (N, 6) array that is not a closed loop, like the simapp's Straight_track."""
    x = np.linspace(0.0, 5.0, 11)
    zeros = np.zeros_like(x)
    return np.stack([x, zeros, x, zeros + 0.5, x, zeros - 0.5], axis=1)


def mapped_handler(routes: dict[str, tuple[int, bytes]], hits: dict[str, int] | None = None):
    """Handler answering ``/<key>`` with the (status, body) in ``routes``; 404 for anything else."""
    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            key = self.path.lstrip("/")
            if hits is not None:
                hits[key] = hits.get(key, 0) + 1
            status, body = routes.get(key, (404, b"Not Found"))
            if callable(body):
                status, body = body()
            self.send_response(status)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args) -> None:
            pass
    return Handler


@pytest.fixture
def home(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    monkeypatch.delenv(fetch.BASE_URL_ENV, raising=False)
    return tmp_path / "home"


def test_shipped_names_match_reference_folder():
    names = fetch.shipped_route_names()
    assert len(names) == len(set(names)) == 127
    fetch.check_route_names(names)
    if REFERENCE_DIR.is_dir():
        assert sorted(names) == sorted(p.stem for p in REFERENCE_DIR.glob("*.npy"))


@pytest.mark.skipif(not REFERENCE_DIR.is_dir(), reason=f"{REFERENCE_DIR} not present")
def test_fetch_all_reference_routes_from_local_mirror(home, capsys):
    handler = functools.partial(QuietFileHandler, directory=str(REFERENCE_DIR))
    with serve(handler) as url:
        # The mirror, like GitHub, has no index.json: the shipped name list is used.
        assert main(["tracks", "fetch", "--base-url", url]) == 0
        out = capsys.readouterr().out
        assert "names from the simapp route list shipped with laplab" in out
        assert "fetched 126, skipped 1, failed 0 (of 127)" in out
        assert "skipped Straight_track: not a drivable route" in out and "not a closed loop" in out
        # A second run finds everything in place.
        assert main(["tracks", "fetch", "--base-url", url, "--names", "Oval_track,reInvent2019_track"]) == 0
        assert "fetched 0, skipped 2, failed 0" in capsys.readouterr().out

    folder = registry.user_track_dir()
    stored = sorted(p.name for p in folder.iterdir())
    assert stored == sorted(p.name for p in REFERENCE_DIR.glob("*.npy") if p.stem != "Straight_track")
    assert (folder / "reInvent2019_track.npy").read_bytes() == (REFERENCE_DIR / "reInvent2019_track.npy").read_bytes()
    for name in ("reInvent2019_track", "Oval_track", "2022_summit_speedway_cw"):
        track = registry.load_track(name)
        assert track.length == pytest.approx(load_route_file(REFERENCE_DIR / f"{name}.npy").length)

    assert main(["tracks", "list", "--json"]) == 0
    rows = {row["name"]: row for row in json.loads(capsys.readouterr().out)}
    assert len(rows) == 126 + len(registry.builtin_track_names())
    assert rows["reInvent2019_track"]["source"] == "user" and rows["reInvent2019_track"]["error"] is None


def test_fetch_reports_each_failure_and_exits_1(home, capsys):
    routes = {
        "index.json": (200, json.dumps(["good_oval", "missing", "garbage", "Straight_track", "oval"]).encode()),
        "good_oval.npy": (200, OVAL_BYTES),
        "garbage.npy": (200, b"<html><body>rate limited</body></html>"),
        "Straight_track.npy": (200, npy_bytes(open_route())),
        "oval.npy": (200, OVAL_BYTES),
    }
    with serve(mapped_handler(routes)) as url:
        assert main(["tracks", "fetch", "--base-url", url]) == 1
    captured = capsys.readouterr()
    assert f"names from {url}index.json" in captured.out
    assert "fetched 1, skipped 2, failed 2 (of 5)" in captured.out
    assert f"failed  missing: {url}missing.npy: HTTP 404" in captured.err
    assert f"failed  garbage: {url}garbage.npy: not a readable .npy array" in captured.err
    assert "<html>" in captured.err  # the start of what came back, to tell a proxy's page apart
    assert "skipped Straight_track: not a drivable route" in captured.out
    assert "skipped oval: a built-in track has this name" in captured.out
    assert sorted(p.name for p in registry.user_track_dir().iterdir()) == ["good_oval.npy"]  # no temp files
    assert registry.load_track("good_oval").length == pytest.approx(registry.load_track("oval").length)


def test_fetch_uses_env_url_and_dest_and_keeps_changed_files(home, tmp_path, monkeypatch, capsys):
    routes = {"ring.npy": (200, OVAL_BYTES)}
    dest = tmp_path / "elsewhere"
    with serve(mapped_handler(routes)) as url:
        monkeypatch.setenv(fetch.BASE_URL_ENV, url.rstrip("/"))
        assert main(["tracks", "fetch", "--names", "ring.npy", "--dest", str(dest)]) == 0
        assert (dest / "ring.npy").read_bytes() == OVAL_BYTES
        assert not registry.user_track_dir().exists()
        (dest / "ring.npy").write_bytes(b"local edit")
        assert main(["tracks", "fetch", "--names", "ring", "--dest", str(dest)]) == 0
        assert "exists with other content; --overwrite replaces it" in capsys.readouterr().out
        assert (dest / "ring.npy").read_bytes() == b"local edit"
        assert main(["tracks", "fetch", "--names", "ring", "--dest", str(dest), "--overwrite"]) == 0
        assert (dest / "ring.npy").read_bytes() == OVAL_BYTES


def test_download_retries_a_server_error_once_but_not_a_404():
    answers = iter([(503, b"busy"), (200, OVAL_BYTES)])
    hits: dict[str, int] = {}
    routes = {"flaky.npy": (0, lambda: next(answers))}
    settings = fetch.FetchSettings(retries=1, retry_delay_s=0.0, timeout_s=5.0)
    with serve(mapped_handler(routes, hits)) as url:
        result = fetch.fetch_route("flaky", url, Path("/nonexistent-never-written"), settings,
                                   reserved_names=frozenset({"flaky"}))
        assert result.status == "skipped" and hits == {}  # reserved names are not even downloaded
        assert fetch.download(url + "flaky.npy", settings) == OVAL_BYTES
        with pytest.raises(Exception, match="404"):
            fetch.download(url + "absent.npy", settings)
    assert hits == {"flaky.npy": 2, "absent.npy": 1}


def test_unreachable_server_fails_clearly(home, capsys):
    with socket.socket() as probe:  # a port nobody listens on once closed
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    assert main(["tracks", "fetch", "--base-url", f"http://127.0.0.1:{port}/", "--names", "Oval_track"]) == 1
    assert f"failed  Oval_track: http://127.0.0.1:{port}/Oval_track.npy: cannot download" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["--names", "../../etc/passwd"], "may hold only letters"),
    (["--base-url", "ftp://example.com/routes/"], "must start with http://"),
])
def test_fetch_rejects_bad_arguments_before_any_download(home, capsys, argv, message):
    assert main(["tracks", "fetch", *argv]) == 2
    assert message in capsys.readouterr().err
