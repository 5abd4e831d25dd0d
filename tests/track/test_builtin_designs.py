"""Built-in track designs: the recipes build valid DeepRacer routes and the shipped files match them."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from laplab.track.designs import (
    DESIGNS, Arc, DesignError, Straight, TrackDesign, build_route, centerline_poses, resolve_segments,
    route_length,
)

DATA_DIR = Path(__file__).resolve().parents[2] / "laplab" / "track" / "data"

# name -> (min length, max length, nominal width), all in m
SPECS = {
    "oval": (16.0, 20.0, 1.067),
    "classic_2018": (17.4, 18.0, 0.76),
    "speedway_23": (22.5, 23.5, 1.067),
    "technical": (20.0, 30.0, 1.067),
    "grand_tour": (58.0, 62.0, 1.067),
}


@pytest.fixture(scope="module")
def routes() -> dict[str, np.ndarray]:
    return {name: build_route(design) for name, design in DESIGNS.items()}


def _segments_cross(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """(M, K) bool: segment a_i (rows of (M,2) ends) properly crosses or touches segment b_k."""
    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])
    a0, a1 = a0[:, None, :], a1[:, None, :]
    b0, b1 = b0[None, :, :], b1[None, :, :]
    d1, d2 = orient(a0, a1, b0), orient(a0, a1, b1)
    d3, d4 = orient(b0, b1, a0), orient(b0, b1, a1)
    # The bounding-box test keeps far-apart collinear pieces of one straight (orientations ~0) apart.
    boxes_meet = np.all((np.maximum(a0, a1) >= np.minimum(b0, b1)) & (np.maximum(b0, b1) >= np.minimum(a0, a1)),
                        axis=2)
    return boxes_meet & (d1 * d2 <= 0) & (d3 * d4 <= 0)


def self_intersections(loop: np.ndarray) -> int:
    """Number of crossing pairs of non-adjacent segments of a closed polyline (N, 2), row 0 == row N-1."""
    start, end = loop[:-1], loop[1:]
    count = len(start)
    crosses = _segments_cross(start, end, start, end)
    i, k = np.indices((count, count))
    gap = np.abs(i - k)
    non_adjacent = (gap > 1) & (gap < count - 1)
    return int(np.count_nonzero(crosses & non_adjacent) // 2)


def nearest_distance(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """(M,) distance from each point (M, 2) to the nearest point of a polyline (K, 2), m."""
    a, b = polyline[:-1][None], polyline[1:][None]
    ab = b - a
    t = np.clip(np.sum((points[:, None] - a) * ab, axis=2) / np.sum(ab * ab, axis=2), 0.0, 1.0)
    nearest = a + t[..., None] * ab
    return np.min(np.linalg.norm(points[:, None] - nearest, axis=2), axis=1)


def cross_2d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def signed_area(loop: np.ndarray) -> float:
    return 0.5 * float(np.sum(loop[:-1, 0] * loop[1:, 1] - loop[1:, 0] * loop[:-1, 1]))


def test_intersection_check_detects_a_figure_eight():
    t = np.linspace(0.01, 2 * np.pi + 0.01, 81)  # the crossing falls inside segments
    figure_eight = np.stack([np.sin(t), np.sin(t) * np.cos(t)], axis=1)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    assert self_intersections(figure_eight) >= 1
    assert self_intersections(circle) == 0


def test_the_five_builtin_names_exist():
    assert set(DESIGNS) == set(SPECS)
    for name, design in DESIGNS.items():
        assert design.name == name and design.description


@pytest.mark.parametrize("name", sorted(SPECS))
def test_route_format_closed_finite_ccw(routes, name):
    route = routes[name]
    assert route.dtype == np.float64 and route.ndim == 2 and route.shape[1] == 6
    assert 100 <= route.shape[0] <= 400
    assert np.all(np.isfinite(route))
    assert np.array_equal(route[0], route[-1])
    for column in (0, 2, 4):
        assert signed_area(route[:, column:column + 2]) > 0
    assert signed_area(route[:, 2:4]) < signed_area(route[:, 0:2]) < signed_area(route[:, 4:6])
    spacing = np.linalg.norm(np.diff(route[:, 0:2], axis=0), axis=1)
    assert spacing.min() > 0.1 and spacing.max() < 0.2
    assert np.ptp(spacing) < 0.01 * spacing.mean()  # uniform arc length; chords on arcs are a bit shorter


@pytest.mark.parametrize("name", sorted(SPECS))
def test_length_and_perpendicular_width(routes, name):
    route = routes[name]
    low, high, width = SPECS[name]
    assert DESIGNS[name].width == width
    assert low <= route_length(route) <= high
    centre = route[:-1, 0:2]
    across = nearest_distance(centre, route[:, 2:4]) + nearest_distance(centre, route[:, 4:6])
    assert np.all(np.abs(across / width - 1.0) < 0.02), (across.min(), across.max())


@pytest.mark.parametrize("name", sorted(SPECS))
def test_borders_are_simple_and_never_cross(routes, name):
    route = routes[name]
    inner, outer = route[:, 2:4], route[:, 4:6]
    assert self_intersections(inner) == 0
    assert self_intersections(outer) == 0
    assert self_intersections(route[:, 0:2]) == 0
    assert not _segments_cross(inner[:-1], inner[1:], outer[:-1], outer[1:]).any()


@pytest.mark.parametrize("name", sorted(SPECS))
def test_separate_parts_of_the_track_keep_apart(routes, name):
    """Centre points more than two widths apart along the lap are at least width + 0.2 m apart."""
    route = routes[name]
    width = SPECS[name][2]
    centre = route[:-1, 0:2]
    s = np.arange(len(centre)) * route_length(route) / len(centre)
    along = np.abs(s[:, None] - s[None, :])
    along = np.minimum(along, route_length(route) - along)
    distance = np.linalg.norm(centre[:, None] - centre[None, :], axis=2)
    assert distance[along > 2 * width].min() >= width + 0.2


@pytest.mark.parametrize("name", sorted(SPECS))
def test_inner_border_on_the_drivers_left(routes, name):
    route = routes[name]
    centre = route[:-1, 0:2]
    tangent = np.roll(centre, -1, axis=0) - np.roll(centre, 1, axis=0)
    to_inner = route[:-1, 2:4] - centre
    to_outer = route[:-1, 4:6] - centre
    assert np.all(cross_2d(tangent, to_inner) > 0)
    assert np.all(cross_2d(tangent, to_outer) < 0)


@pytest.mark.parametrize("name", sorted(SPECS))
def test_committed_file_matches_the_recipe(routes, name):
    path = DATA_DIR / f"{name}.npy"
    shipped = np.load(path, allow_pickle=False)
    assert shipped.dtype == np.float64
    assert np.array_equal(shipped, routes[name]), f"{path} is stale: run scripts/make_builtin_tracks.py"


def test_catalogue_matches_the_designs(routes):
    catalogue = json.loads((DATA_DIR / "builtin.json").read_text())
    assert set(catalogue) == set(DESIGNS)
    for name, entry in catalogue.items():
        assert entry["description"] == DESIGNS[name].description
        assert entry["width"] == DESIGNS[name].width
        assert entry["length"] == pytest.approx(route_length(routes[name]), abs=1e-3)


def test_building_twice_gives_identical_bytes():
    for design in DESIGNS.values():
        assert build_route(design).tobytes() == build_route(design).tobytes()


def test_arc_geometry_matches_a_circle():
    """A circle of radius 2 built from four quarter arcs: every point 2 m from the centre (0, 2)."""
    segments = (Arc(90, 2.0),) * 4
    s = np.linspace(0.0, 4 * math.pi, 50)
    points, heading = centerline_poses(segments, s)
    np.testing.assert_allclose(np.linalg.norm(points - [0.0, 2.0], axis=1), 2.0, atol=1e-12)
    np.testing.assert_allclose(heading, s / 2.0, atol=1e-12)


def test_open_straights_are_solved_to_close_the_loop():
    design = TrackDesign("box", "", 1.0, (Straight(3.0), Arc(90, 1.0), Straight(None), Arc(90, 1.0),
                                          Straight(None), Arc(90, 1.0), Straight(2.0), Arc(90, 1.0)))
    lengths = [seg.length for seg in resolve_segments(design) if isinstance(seg, Straight)]
    assert lengths == pytest.approx([3.0, 2.0, 3.0, 2.0])


@pytest.mark.parametrize("segments, message", [
    ((Straight(2.0), Arc(180, 1.5), Straight(2.0), Arc(90, 1.5)), "add up to 270"),
    ((Straight(2.0), Arc(180, 0.5), Straight(2.0), Arc(180, 0.5)), "radius must be"),
    ((Straight(2.0), Arc(180, 1.5), Straight(3.0), Arc(180, 1.5)), "misses its start"),
    ((Straight(None), Arc(180, 1.5), Straight(None), Arc(180, 1.5)), "parallel"),
    ((Straight(None), Arc(180, 1.0), Straight(5.0), Arc(90, 1.5), Straight(None), Arc(90, 1.5)),
     "must be positive"),
    ((Straight(None), Arc(360, 1.5)), "exactly 0 or 2"),
])
def test_bad_recipes_raise_a_clear_error(segments, message):
    with pytest.raises(DesignError, match=message) as info:
        build_route(TrackDesign("bad", "", 1.0, segments))
    assert "'bad'" in str(info.value)


def test_a_recipe_whose_parts_overlap_is_refused():
    """technical with a 3.8 m infield tongue: the hairpin runs into the chicane."""
    segments = list(DESIGNS["technical"].segments)
    assert segments[11] == Straight(1.3) and segments[13] == Straight(1.3)
    segments[11] = segments[13] = Straight(3.8)
    with pytest.raises(DesignError, match="border crosses itself"):
        build_route(dataclasses.replace(DESIGNS["technical"], segments=tuple(segments)))


def test_builtins_load_through_the_track_registry():
    registry = pytest.importorskip("laplab.track.registry")
    for name, (_, _, width) in SPECS.items():
        track = registry.load_track(name)
        assert track.is_ccw
        assert track.nominal_width == pytest.approx(width, rel=0.02)
