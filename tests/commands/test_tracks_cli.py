"""``laplab tracks list / show / import``: in-process through ``laplab.cli.main``, plus one entry-point run."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from laplab.cli import main
from laplab.track import registry
from laplab.track.plot import plot_track

BUILTINS = json.loads((registry.BUILTIN_DIR / "builtin.json").read_text())


@pytest.fixture
def home(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("LAPLAB_TRACKS_URL", raising=False)
    return tmp_path / "home"


def ring_route(points: int = 60, radius: float = 3.0, half_width: float = 0.5,
               repeat_row: int | None = None) -> np.ndarray:
    """Closed CCW circular route (points + 1 rows, last == first); optionally one interior row repeated."""
    angle = np.linspace(0.0, 2 * np.pi, points + 1)
    angle[-1] = 0.0
    unit = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    route = np.hstack([unit * radius, unit * (radius - half_width), unit * (radius + half_width)])
    if repeat_row is not None:
        route = np.insert(route, repeat_row, route[repeat_row], axis=0)
    return route


def save(path: Path, array) -> Path:
    np.save(path, array)
    return path


# ---------------------------------------------------------------------------------------------- list

def test_list_table_marks_default_and_sources(home, capsys):
    assert main(["tracks", "list"]) == 0
    out = capsys.readouterr().out
    for name in BUILTINS:
        assert name in out
    assert f"{registry.DEFAULT_TRACK} *" in out
    assert "built-in" in out and "ccw" in out


def test_list_json_matches_builtin_table(home, capsys):
    assert main(["tracks", "list", "--json"]) == 0
    rows = {row["name"]: row for row in json.loads(capsys.readouterr().out)}
    assert set(rows) == set(BUILTINS)
    assert [n for n, r in rows.items() if r["default"]] == [registry.DEFAULT_TRACK]
    for name, spec in BUILTINS.items():
        row = rows[name]
        assert row["source"] == "built-in" and row["error"] is None
        assert row["length_m"] == pytest.approx(spec["length"], abs=2e-3)
        assert row["width_m"] == pytest.approx(spec["width"], abs=5e-3)
        assert row["direction"] in ("cw", "ccw")
        assert row["waypoints"] == registry.load_track(name).num_waypoints


def test_list_shows_user_tracks_and_flags_broken_files(home, tmp_path, capsys):
    assert main(["tracks", "import", str(save(tmp_path / "ring.npy", ring_route()))]) == 0
    broken = registry.user_track_dir() / "broken.npy"
    broken.write_bytes(b"not numpy")
    capsys.readouterr()
    assert main(["tracks", "list", "--json"]) == 0
    rows = {row["name"]: row for row in json.loads(capsys.readouterr().out)}
    ring = rows["ring"]
    assert ring["source"] == "user" and ring["direction"] == "ccw" and ring["waypoints"] == 61
    assert ring["length_m"] == pytest.approx(2 * np.pi * 3.0, rel=2e-3)
    assert ring["width_m"] == pytest.approx(1.0, abs=1e-6)
    assert "not a readable .npy" in rows["broken"]["error"]
    assert main(["tracks", "list"]) == 0
    table = capsys.readouterr().out
    assert "ring" in table and "user" in table and "invalid" in table


def test_list_does_no_network_io(home, monkeypatch, capsys):
    def refuse(*args, **kwargs):
        raise AssertionError("network access attempted")
    monkeypatch.setattr(socket, "socket", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    assert main(["tracks", "list"]) == 0


# ---------------------------------------------------------------------------------------------- show

def test_show_writes_png_in_cwd_by_default(home, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["tracks", "show", "classic_2018", "--indices"]) == 0
    written = Path(capsys.readouterr().out.strip())
    assert written == tmp_path / "classic_2018.png"
    with Image.open(written) as image:
        assert image.format == "PNG" and min(image.size) > 300


def test_show_reversed_to_explicit_path(home, tmp_path, capsys):
    out = tmp_path / "figs" / "oval_rev.png"
    assert main(["tracks", "show", "oval", "--reversed", "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_show_rejects_unknown_track_and_non_png(home, tmp_path, capsys):
    assert main(["tracks", "show", "no_such_track"]) == 2
    assert "unknown track 'no_such_track'" in capsys.readouterr().err
    assert main(["tracks", "show", "oval", "--out", str(tmp_path / "oval.txt")]) == 2
    assert ".png" in capsys.readouterr().err


def test_plot_track_draws_start_line_across_waypoint_zero():
    track = registry.load_track("classic_2018")
    figure = plot_track(track, None, show_indices=True)
    assert figure.path is None
    lines = {line.get_label(): line for line in figure.ax.get_lines()}
    assert {"inner border", "outer border", "centre line", "start line"} <= set(lines)
    assert lines["centre line"].get_linestyle() != "-"
    start = np.asarray(lines["start line"].get_xydata())
    assert np.linalg.norm(start[0] - start[1]) == pytest.approx(track.width[0], rel=1e-9)
    # The start line crosses the centre line at waypoint 0, perpendicular to the first segment.
    assert np.linalg.norm(start.mean(axis=0) - track.centerline[0]) < 0.5 * track.width[0]
    heading = track.centerline[1] - track.centerline[0]
    across = start[1] - start[0]
    assert abs(np.dot(across, heading)) / (np.linalg.norm(across) * np.linalg.norm(heading)) < 0.05
    assert [t.get_text() for t in figure.ax.texts] == [str(i) for i in range(track.num_waypoints - 1)]


def test_plot_track_reuses_given_axes_for_overlays(tmp_path):
    track = registry.load_track("oval")
    first = plot_track(track, None)
    first.ax.plot(track.centerline[:, 0] * 0.99, track.centerline[:, 1] * 0.99, label="race line")
    again = plot_track(track.reversed(), tmp_path / "overlay.png", ax=first.ax)
    assert again.ax is first.ax and again.path == tmp_path / "overlay.png"
    assert "race line" in [line.get_label() for line in again.ax.get_lines()]
    assert again.path.stat().st_size > 1000


# ---------------------------------------------------------------------------------------------- import

def test_import_then_load_by_name(home, tmp_path, capsys):
    source = save(tmp_path / "my ring.npy", ring_route())
    assert main(["tracks", "import", str(source), "--name", "ring_a"]) == 0
    assert "imported ring_a" in capsys.readouterr().out
    track = registry.load_track("ring_a")
    assert track.source.startswith(str(registry.user_track_dir()))
    np.testing.assert_array_equal(np.load(registry.user_track_dir() / "ring_a.npy"), ring_route())


def test_import_removes_repeated_points_unless_asked_to_keep(home, tmp_path, capsys):
    source = save(tmp_path / "rep.npy", ring_route(repeat_row=20))
    assert main(["tracks", "import", str(source)]) == 0
    assert "removed 1 repeated" in capsys.readouterr().out
    assert np.load(registry.user_track_dir() / "rep.npy").shape == (61, 6)
    assert main(["tracks", "import", str(source), "--name", "rep_raw", "--keep-repeated-points"]) == 0
    np.testing.assert_array_equal(np.load(registry.user_track_dir() / "rep_raw.npy"), np.load(source))


def test_import_refuses_to_replace_without_overwrite(home, tmp_path, capsys):
    source = save(tmp_path / "ring.npy", ring_route())
    assert main(["tracks", "import", str(source)]) == 0
    wider = save(tmp_path / "wider.npy", ring_route(half_width=0.6))
    assert main(["tracks", "import", str(wider), "--name", "ring"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["tracks", "import", str(wider), "--name", "ring", "--overwrite"]) == 0
    assert registry.load_track("ring").nominal_width == pytest.approx(1.2)
    assert main(["tracks", "import", str(source), "--name", "oval"]) == 2
    assert "built-in" in capsys.readouterr().err


@pytest.mark.parametrize("content, message", [
    (ring_route()[:, :5], "shape (61, 5)"),
    (np.where(np.arange(61)[:, None] == 7, np.nan, ring_route()), "NaN/Inf values, the first at row 7"),
    (ring_route()[:-3], "not a closed loop"),
    (ring_route()[:, [0, 1, 4, 5, 2, 3]], "swapped"),
    (np.array(["a", "b"]), "shape (2,)"),
    (b"PK\x03\x04 definitely not numpy", "not a readable .npy"),
])
def test_import_rejects_bad_files_with_clear_message(home, tmp_path, capsys, content, message):
    path = tmp_path / "bad.npy"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        np.save(path, content)
    assert main(["tracks", "import", str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err and str(path) in err
    assert not registry.user_track_dir().exists() or not any(registry.user_track_dir().iterdir())


def test_import_missing_file(home, tmp_path, capsys):
    assert main(["tracks", "import", str(tmp_path / "nope.npy")]) == 2
    assert "no such file" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- entry point

def test_entry_point_tracks_list(tmp_path):
    exe = shutil.which("laplab")
    command = [exe] if exe else [sys.executable, "-c", "import sys; from laplab.cli import main; sys.exit(main())"]
    env = dict(os.environ, LAPLAB_HOME=str(tmp_path))
    done = subprocess.run(command + ["tracks", "list"], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert f"{registry.DEFAULT_TRACK} *" in done.stdout and "grand_tour" in done.stdout
