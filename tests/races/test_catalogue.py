"""The track catalogue: DeepRacer on AWS's 62 official tracks by display name, mapped to simapp
routes; which way a route is drawn (from its geometry); ``laplab tracks fetch --names`` with a display
name, from a local mirror of the simapp's routes (skipped without /work/shared's copy)."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest

from laplab.cli import main
from laplab.races.catalogue import catalogue, display_names, drawn_counterclockwise, find, route_names, track_key
from laplab.track import registry
from laplab.track.fetch import shipped_route_names

REFERENCE_DIR = Path(__file__).resolve().parents[3] / "shared" / "reference-tracks"


def test_catalogue_has_deepracer_on_aws_tracks():
    tracks = catalogue()
    assert len(tracks) == 62 and len({t.name for t in tracks}) == 62 and len({t.route for t in tracks}) == 62
    shipped = set(shipped_route_names())
    assert all(t.route in shipped and set(t.variants) <= shipped for t in tracks)
    assert find("re:Invent 2018").route == "reinvent_base"
    assert find("smile speedway").route == "reInvent2019_track"
    assert find("Forever Raceway").route == "2024_reinvent_champ_ccw"
    assert find("2022_july_pro_cw").name == "DBro Super Raceway" and find("no such track") is None
    assert display_names()["2024_reinvent_champ_cw"] == "Forever Raceway (clockwise)"
    assert route_names(["Smile Speedway", "Oval_track", "reInvent2019_track_cw"]) == \
        ["reInvent2019_track", "Oval_track", "reInvent2019_track_cw"]


def test_direction_from_geometry():
    angle = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    circle = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    assert drawn_counterclockwise(circle) and not drawn_counterclockwise(circle[::-1])
    for name in registry.builtin_track_names():
        forward, backward = track_key(name, "counterclockwise"), track_key(name, "clockwise")
        assert {forward, backward} == {name, f"{name}@reversed"}


@pytest.mark.skipif(not REFERENCE_DIR.is_dir(), reason="no local copy of the simapp's routes")
def test_fetch_by_display_name(tmp_path, monkeypatch, capsys):
    import http.server
    import threading
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(REFERENCE_DIR)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/"
        assert main(["tracks", "fetch", "--base-url", url, "--names", "Smile Speedway,Forever Raceway"]) == 0
        assert "fetched 2" in capsys.readouterr().out
    finally:
        server.shutdown()
    assert (registry.user_track_dir() / "reInvent2019_track.npy").is_file()
    from laplab.console.tracks import track_list
    shown = {t["name"]: t["display_name"] for t in track_list()}
    assert shown["reInvent2019_track"] == "Smile Speedway" and shown["2024_reinvent_champ_ccw"] == "Forever Raceway"
    # the simapp's own _cw variant is drawn clockwise: a clockwise race drives it as it is
    assert track_key("2024_reinvent_champ_ccw", "counterclockwise") == "2024_reinvent_champ_ccw"
    assert drawn_counterclockwise(np.asarray(registry.load_track("2024_reinvent_champ_ccw").centerline))
