"""``laplab raceline`` in-process through ``laplab.cli.main``, and the race-line cache behind it."""

from __future__ import annotations

import csv
import re

import numpy as np
import pytest
from PIL import Image

from laplab.cli import main
from laplab.commands.raceline import output_stem
from laplab.track import raceline_cache
from laplab.track.raceline import FAST_SETTINGS, RaceLineSettings, compute_raceline_for_track
from laplab.track.raceline_cache import (cache_folder, clear_memory_cache, optimal_lap_time, raceline_cache_path,
                                         raceline_for, raceline_key)
from laplab.track.registry import load_track
from laplab.vehicle.params import DEEPRACER


@pytest.fixture
def home(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    clear_memory_cache()
    yield tmp_path / "home"
    clear_memory_cache()


def number_after(label: str, text: str) -> float:
    match = re.search(rf"{label}\s+([\d.]+)", text)
    assert match, f"no {label!r} in output:\n{text}"
    return float(match.group(1))


def test_prints_lap_times_and_writes_waypoints_csv_and_plot(home, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["raceline", "classic_2018", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    track = load_track("classic_2018")
    line = compute_raceline_for_track(track)
    assert number_after("optimal lap time", text) == pytest.approx(line.lap_time, abs=1e-3)
    assert number_after("centre-line lap time", text) == pytest.approx(line.centerline_lap_time, abs=1e-3)
    assert number_after("race line length", text) == pytest.approx(line.length, abs=1e-2)
    assert line.lap_time < line.centerline_lap_time

    waypoints = np.load(out / "classic_2018-raceline.npy")
    assert waypoints.shape == line.points.shape and np.allclose(waypoints, line.points)
    assert np.array_equal(waypoints[0], waypoints[-1])
    with open(out / "classic_2018-raceline.csv", newline="") as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ["x", "y", "speed"] and len(rows) == len(line.points) + 1
    assert np.allclose(np.array(rows[1:], dtype=float)[:, 2], line.speeds, atol=1e-6)
    with Image.open(out / "classic_2018-raceline.png") as image:
        assert image.size[0] > 300
    for suffix in (".npy", ".csv", ".png"):
        assert str(out / f"classic_2018-raceline{suffix}") in text
    assert len(list(cache_folder().glob("raceline-classic_2018-*.npz"))) == 1


def test_second_run_reads_the_cache(home, tmp_path, capsys, monkeypatch):
    assert main(["raceline", "oval", "--fast", "--out", str(tmp_path)]) == 0
    first = capsys.readouterr().out
    clear_memory_cache()
    monkeypatch.setattr(raceline_cache, "compute_raceline_for_track",
                        lambda *a, **k: pytest.fail("solved again instead of read from the cache"))
    assert main(["raceline", "oval", "--fast", "--out", str(tmp_path)]) == 0
    second = capsys.readouterr().out
    assert "loaded from the cache" in second and "solved in" in first
    assert number_after("optimal lap time", first) == number_after("optimal lap time", second)


@pytest.mark.parametrize("physics, tolerance", [("classic", 0.03), ("6", 0.035)])
def test_drive_reproduces_the_predicted_lap_time(home, tmp_path, capsys, physics, tolerance):
    # laplab's classic car follows a line within centimetres; DeepRacer's answer late, and the follower makes up for it
    assert main(["raceline", "technical@reversed", "--fast", "--drive", "--physics", physics,
                 "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    ratios = [float(r) for r in re.findall(r"= ([\d.]+) x predicted", text)]
    assert len(ratios) == 2 and all(0.995 <= r <= 1.0 + tolerance for r in ratios), text
    assert (tmp_path / "technical-reversed-raceline.npy").is_file()


@pytest.mark.parametrize("argv, message", [
    (["classic_2018", "--margin", "-0.1"], "--margin"),
    (["classic_2018", "--margin", "0.6"], "too narrow"),
    (["classic_2018", "--physics", "bus"], "--physics 'bus': write 4, 5 or 6"),
    (["no_such_track"], "unknown track 'no_such_track'"),
])
def test_bad_input_is_one_clear_error(home, tmp_path, capsys, argv, message):
    assert main(["raceline", *argv, "--out", str(tmp_path)]) == 2
    assert message in capsys.readouterr().err
    assert not list(tmp_path.glob("*-raceline.*"))


def test_output_stem_is_a_safe_file_name():
    assert output_stem("classic_2018@reversed") == "classic_2018-reversed"
    assert output_stem("my track/1") == "my-track-1"


# --- the cache ---------------------------------------------------------------------------------

def test_cached_line_equals_the_solved_one_and_is_read_back_without_solving(home, monkeypatch):
    track = load_track("oval")
    solved = raceline_for(track, settings=FAST_SETTINGS)
    path = raceline_cache_path(track, settings=FAST_SETTINGS)
    assert path.is_file() and path.parent == home / "cache"
    clear_memory_cache()
    monkeypatch.setattr(raceline_cache, "compute_raceline_for_track",
                        lambda *a, **k: pytest.fail("solved again instead of read from the cache"))
    loaded = raceline_for(track, settings=FAST_SETTINGS)
    assert loaded is not solved
    for name in ("points", "speeds", "curvature", "arc_length", "times", "offsets"):
        assert np.array_equal(getattr(loaded, name), getattr(solved, name)), name
        assert not getattr(loaded, name).flags.writeable
    assert loaded.lap_time == solved.lap_time and loaded.centerline_lap_time == solved.centerline_lap_time
    assert loaded.steering_feasible == solved.steering_feasible


def test_key_follows_track_car_margin_and_settings(home):
    track = load_track("oval")
    base = raceline_key(track)
    variants = [raceline_key(track.reversed()), raceline_key(track, DEEPRACER.with_(max_lateral_acceleration=4.0)),
                raceline_key(track, margin=0.1), raceline_key(track, settings=FAST_SETTINGS),
                raceline_key(load_track("speedway_23"))]
    assert len({base, *variants}) == len(variants) + 1
    assert raceline_key(load_track("oval")) == base == raceline_key(track, DEEPRACER, 0.05, RaceLineSettings())


def test_unreadable_entry_is_solved_again_and_replaced(home):
    track = load_track("oval")
    path = raceline_cache_path(track, settings=FAST_SETTINGS)
    path.parent.mkdir(parents=True)
    path.write_bytes(b"not an npz file")
    line = raceline_for(track, settings=FAST_SETTINGS)
    assert line.lap_time == pytest.approx(compute_raceline_for_track(track, settings=FAST_SETTINGS).lap_time)
    clear_memory_cache()
    assert raceline_for(track, settings=FAST_SETTINGS).lap_time == line.lap_time
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary files left


def test_optimal_lap_time_is_the_default_lines_time_by_name_or_track(home):
    track = load_track("classic_2018")
    expected = compute_raceline_for_track(track).lap_time
    assert optimal_lap_time(track) == pytest.approx(expected, rel=1e-12)
    assert optimal_lap_time("classic_2018", DEEPRACER) == pytest.approx(expected, rel=1e-12)
    slower_car = DEEPRACER.with_(max_lateral_acceleration=3.0)
    assert optimal_lap_time(track, slower_car) > expected
