"""Track geometry: route validation, repeated points, arc length, widths, direction, reversal."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from laplab.track.geometry import (
    TrackError, load_route_file, remove_repeated_points, track_from_route, validate_route,
)
from laplab.track.registry import BUILTIN_DIR, builtin_track_names, load_track


# ---------------------------------------------------------------- validation errors


def test_valid_route_passes_validation_unchanged(circle_route):
    route = circle_route()
    checked = validate_route(route, "circle.npy")
    assert checked.dtype == np.float64 and checked.flags.c_contiguous
    np.testing.assert_array_equal(checked, route)


@pytest.mark.parametrize("shape", [(50, 5), (50, 7), (300,), (2, 50, 6)])
def test_wrong_shape_is_rejected(shape):
    with pytest.raises(TrackError, match=r"my\.npy.*shape \(N, 6\).*" + re.escape(str(shape))):
        validate_route(np.zeros(shape), "my.npy")


def test_nan_is_rejected_naming_row_and_column(circle_route):
    route = circle_route()
    route[17, 3] = np.nan
    with pytest.raises(TrackError, match=r"nan\.npy.*NaN/Inf.*row 17, column 3"):
        validate_route(route, "nan.npy")


def test_inf_is_rejected(circle_route):
    route = circle_route()
    route[5, 0] = np.inf
    with pytest.raises(TrackError, match="NaN/Inf"):
        validate_route(route)


def test_open_loop_is_rejected(circle_route):
    with pytest.raises(TrackError, match=r"open\.npy.*not a closed loop"):
        validate_route(circle_route()[:-1], "open.npy")


def test_nearly_closed_loop_is_closed_exactly(circle_route):
    route = circle_route()
    route[-1] += 1e-8  # well inside the closing tolerance
    checked = validate_route(route)
    np.testing.assert_array_equal(checked[-1], checked[0])


@pytest.mark.parametrize("ccw", [True, False])
def test_swapped_borders_are_rejected(circle_route, ccw):
    route = circle_route(ccw=ccw)
    swapped = route[:, [0, 1, 4, 5, 2, 3]]
    with pytest.raises(TrackError, match="swapped"):
        validate_route(swapped, "swapped.npy")


def test_borders_on_one_side_are_rejected(circle_route):
    route = circle_route(radius=3.0)
    unit = route[:, 0:2] / 3.0
    route[:, 2:4] = 2.4 * unit  # both borders inside the centre line
    route[:, 4:6] = 2.7 * unit
    with pytest.raises(TrackError, match="both sides"):
        validate_route(route, "oneside.npy")


@pytest.mark.parametrize("bad", [
    np.full((10, 6), "1.0"),                        # strings
    np.array([[object()] * 6] * 10, dtype=object),  # Python objects
    np.zeros((10, 6), dtype=np.complex128),         # complex numbers
])
def test_non_numeric_routes_are_rejected(bad):
    with pytest.raises(TrackError, match=r"real numbers.*dtype"):
        validate_route(bad, "weird.npy")


def test_too_few_rows_are_rejected():
    route = np.array([[0, 0, 0, 1, 0, -1], [1, 0, 1, 1, 1, -1], [0, 0, 0, 1, 0, -1]], dtype=float)
    with pytest.raises(TrackError, match="at least 4 rows"):
        validate_route(route)


def test_missing_and_corrupt_files_raise_track_error(tmp_path):
    with pytest.raises(TrackError, match="no such track file"):
        load_route_file(tmp_path / "absent.npy")
    corrupt = tmp_path / "corrupt.npy"
    corrupt.write_bytes(b"definitely not numpy")
    with pytest.raises(TrackError, match="corrupt.npy.*not a readable"):
        load_route_file(corrupt)
    with pytest.raises(TrackError, match="unknown track"):
        load_track("no_such_track_anywhere")


def test_open_reference_strip_is_rejected(reference_tracks_dir):
    with pytest.raises(TrackError, match="Straight_track.npy.*not a closed loop"):
        load_route_file(reference_tracks_dir / "Straight_track.npy")


# ---------------------------------------------------------------- repeated points


def test_repeated_point_removal_is_a_setting(circle_route):
    route = circle_route(num_points=100)
    repeated = np.insert(route, 40, route[39], axis=0)  # row 40 repeats row 39
    kept = track_from_route(repeated, "raw", remove_repeats=False)
    cleaned = track_from_route(repeated, "clean", remove_repeats=True)
    assert kept.num_waypoints == route.shape[0] + 1
    assert cleaned.num_waypoints == route.shape[0]
    np.testing.assert_array_equal(cleaned.centerline, route[:, 0:2])
    assert cleaned.length == pytest.approx(kept.length, abs=1e-12)
    assert kept.arc_length[40] == kept.arc_length[39]  # a zero-length segment
    np.testing.assert_array_equal(cleaned.centerline[-1], cleaned.centerline[0])  # closing row kept


def test_remove_repeated_points_keeps_the_closing_row(circle_route):
    route = circle_route(num_points=20)
    np.testing.assert_array_equal(remove_repeated_points(route), route)


def test_oval_track_repeated_point(reference_tracks_dir):
    path = reference_tracks_dir / "Oval_track.npy"
    raw = np.load(path)
    assert np.array_equal(raw[66, 0:2], raw[67, 0:2])
    current = load_route_file(path)
    legacy = load_route_file(path, remove_repeats=False)
    assert legacy.num_waypoints == raw.shape[0] == 102
    assert current.num_waypoints == raw.shape[0] - 1
    assert current.length == pytest.approx(legacy.length, abs=1e-12)
    np.testing.assert_array_equal(current.centerline[:67], raw[:67, 0:2])
    np.testing.assert_array_equal(current.centerline[67:], raw[68:, 0:2])  # indices shift by one after row 66


# ---------------------------------------------------------------- arc length, widths, direction


def test_circle_geometry_is_exact(circle_route):
    radius, width, n = 3.0, 1.0, 400
    track = track_from_route(circle_route(radius, width, n), "circle")
    chord = 2.0 * radius * math.sin(math.pi / n)
    np.testing.assert_allclose(np.diff(track.arc_length), chord, rtol=1e-9)
    assert track.arc_length[0] == 0.0
    assert track.length == pytest.approx(n * chord, rel=1e-12)
    np.testing.assert_allclose(track.left_width, 0.5 * width, atol=1e-9)
    np.testing.assert_allclose(track.right_width, 0.5 * width, atol=1e-9)
    np.testing.assert_allclose(track.width, width, atol=1e-9)
    assert track.nominal_width == pytest.approx(width, abs=1e-9)
    np.testing.assert_allclose(track.road_width, width, atol=1e-4)  # nearest border points: chord effects only


def test_widths_are_measured_perpendicular_not_row_paired(circle_route):
    """Outer border rows rotated by 5 rows: row i is no longer across from row i (old DeepRacer routes)."""
    route = circle_route(num_points=200)
    outer = np.roll(route[:-1, 4:6], 5, axis=0)
    route[:-1, 4:6], route[-1, 4:6] = outer, outer[0]
    track = track_from_route(route, "skewed")
    paired = np.linalg.norm(route[:, 2:4] - route[:, 4:6], axis=1)
    assert paired.mean() > 1.05  # the naive width is clearly wrong
    np.testing.assert_allclose(track.width, 1.0, atol=2e-3)
    np.testing.assert_allclose(track.road_width, 1.0, atol=2e-3)


def test_asymmetric_widths_follow_the_driving_direction(circle_route):
    route = circle_route(radius=3.0, num_points=300)
    unit = route[:, 0:2] / 3.0
    route[:, 2:4] = 2.8 * unit   # inner border 0.2 m from the centre line
    route[:, 4:6] = 3.7 * unit   # outer border 0.7 m from it
    ccw = track_from_route(route, "ccw")
    assert ccw.is_ccw and ccw.direction == "ccw"
    np.testing.assert_allclose(ccw.left_width, 0.2, atol=1e-9)  # CCW: the inner border is on the left
    np.testing.assert_allclose(ccw.right_width, 0.7, atol=1e-9)
    cw = ccw.reversed()
    assert not cw.is_ccw and cw.direction == "cw"
    np.testing.assert_allclose(cw.left_width, 0.7, atol=1e-9)
    np.testing.assert_allclose(cw.right_width, 0.2, atol=1e-9)


def test_reversed_track(stadium_track):
    back = stadium_track.reversed()
    assert back.name == "stadium@reversed" and back.reversed().name == "stadium"
    np.testing.assert_array_equal(back.centerline, stadium_track.centerline[::-1])
    np.testing.assert_array_equal(back.inner, stadium_track.inner[::-1])
    np.testing.assert_array_equal(back.outer, stadium_track.outer[::-1])
    assert back.length == pytest.approx(stadium_track.length, rel=1e-12)
    np.testing.assert_allclose(back.arc_length, stadium_track.length - stadium_track.arc_length[::-1], atol=1e-9)
    np.testing.assert_allclose(back.left_width, stadium_track.right_width[::-1], atol=1e-9)
    np.testing.assert_allclose(back.road_width, stadium_track.road_width[::-1], atol=1e-9)
    assert back.is_ccw != stadium_track.is_ccw
    twice = back.reversed()
    np.testing.assert_array_equal(twice.centerline, stadium_track.centerline)
    assert twice.is_ccw == stadium_track.is_ccw


def test_track_arrays_are_read_only(stadium_track):
    with pytest.raises(ValueError):
        stadium_track.centerline[0, 0] = 1.0
    with pytest.raises(ValueError):
        stadium_track.left_width[0] = 1.0


def test_point_and_heading_along_the_centre_line(stadium_track):
    track = stadium_track
    np.testing.assert_allclose(track.point_at(track.arc_length[:-1]), track.centerline[:-1], atol=1e-12)
    np.testing.assert_allclose(track.point_at(track.arc_length[5] + 3 * track.length), track.centerline[5],
                               atol=1e-9)
    assert track.point_at(np.zeros((2, 3))).shape == (2, 3, 2)
    # waypoint 0 sits in the middle of the bottom straight heading +x; the top straight heads -x
    np.testing.assert_allclose(track.point_at(0.0), [0.0, -2.0], atol=1e-12)
    assert track.heading_at(0.5) == pytest.approx(0.0, abs=1e-12)
    assert abs(track.heading_at(0.5 * track.length)) == pytest.approx(math.pi, abs=1e-9)
    assert track.heading_at(-0.5) == pytest.approx(0.0, abs=1e-12)  # wraps to the end of the lap


def test_route_round_trip(stadium_track):
    again = track_from_route(stadium_track.route(), "again")
    np.testing.assert_array_equal(again.centerline, stadium_track.centerline)
    np.testing.assert_array_equal(again.arc_length, stadium_track.arc_length)


# ---------------------------------------------------------------- built-in and reference tracks


def test_builtin_tracks_match_their_table():
    table = json.loads((BUILTIN_DIR / "builtin.json").read_text())
    assert set(builtin_track_names()) == set(table) and len(table) >= 5
    for name, entry in table.items():
        track = load_track(name)
        assert track.source.endswith(f"{name}.npy")
        assert track.length == pytest.approx(entry["length"], abs=2e-3), name
        assert track.nominal_width == pytest.approx(entry["width"], rel=5e-3), name
        np.testing.assert_allclose(track.road_width, entry["width"], rtol=0.01, err_msg=name)


def test_load_track_by_name_and_direction():
    forward = load_track("oval")
    for back in (load_track("oval", reverse=True), load_track("oval@reversed")):
        assert back.name == "oval@reversed"
        np.testing.assert_array_equal(back.centerline, forward.centerline[::-1])
        assert back.is_ccw != forward.is_ccw
    np.testing.assert_array_equal(load_track("oval@reversed", reverse=True).centerline, forward.centerline)


def test_reinvent_base_width(reference_tracks):
    track = reference_tracks["reinvent_base"]
    assert track.nominal_width == pytest.approx(0.762, abs=0.005)
    assert track.road_width.mean() == pytest.approx(0.761, abs=0.003)
    assert track.length == pytest.approx(17.709, abs=1e-3)
    assert track.direction == "ccw"


def _reference_table(folder) -> dict[str, tuple]:
    """README rows: file stem -> (rows, closed, direction, centre length m, perpendicular width mean m)."""
    pattern = re.compile(r"\|\s*(\S+)\.npy\s*\|\s*(\d+)x6\s*\|\s*(\w+)\s*\|\s*(\S+)\s*\|\s*([\d.]+)\s*\|"
                         r"\s*[\d.]+\s*\|\s*([\d.]+)\s*\(")
    table = {}
    for line in (folder / "README.md").read_text().splitlines():
        match = pattern.match(line)
        if match:
            stem, rows, closed, direction, length, width = match.groups()
            table[stem] = (int(rows), closed == "yes", direction.lower(), float(length), float(width))
    return table


def test_reference_tracks_match_the_published_table(reference_tracks_dir, reference_tracks):
    """Length, direction and DeepRacer track_width of every real route against the README table."""
    if not (reference_tracks_dir / "README.md").is_file():
        pytest.skip("reference tracks README absent")
    table = _reference_table(reference_tracks_dir)
    assert len(table) >= 100
    problems = []
    repeats = 0
    for stem, (rows, closed, direction, length, width) in table.items():
        if not closed:
            assert stem not in reference_tracks
            continue
        track = reference_tracks[stem]
        raw_rows = np.load(reference_tracks_dir / f"{stem}.npy").shape[0]
        repeats += raw_rows - track.num_waypoints
        if raw_rows != rows or raw_rows - track.num_waypoints not in (0, 1):
            problems.append(f"{stem}: {raw_rows} raw rows, {track.num_waypoints} waypoints, table says {rows}")
        if abs(track.length - length) > 1e-3:
            problems.append(f"{stem}: length {track.length:.4f} m, table {length}")
        if track.direction != direction:
            problems.append(f"{stem}: direction {track.direction}, table {direction}")
        if abs(track.road_width.mean() - width) > 2e-3:
            problems.append(f"{stem}: mean track_width {track.road_width.mean():.4f} m, table {width}")
    assert not problems, "\n".join(problems)
    assert repeats == 59  # the README: 59 of the 127 files repeat one interior centre point
