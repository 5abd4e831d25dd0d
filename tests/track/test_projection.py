"""Projection onto the centre line and the on-track test, against brute-force references.

Reference for the projection: every centre-line segment sampled densely (``SAMPLE_SPACING``), the
nearest sample of each point. Reference for the on-track test: matplotlib's point-in-polygon test
between the outer and inner border rings. Both run on every reference route (skipped when the
folder is absent), on the built-in tracks and on synthetic tracks, with a few dozen points per track.
"""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.path import Path as PolygonPath

from laplab.track.geometry import Track, track_from_route
from laplab.track.projection import (
    points_on_track, project_points, project_points_reference, track_arrays,
)
from laplab.track.registry import builtin_track_names, load_track

SAMPLE_SPACING = 0.002  # m between the dense reference samples
AMBIGUITY_ARC = 0.15  # m: two nearest candidates this far apart along the lap make a point ambiguous
POINTS_PER_TRACK = 48
BORDER_MARGIN = 0.01  # m: points this close to a border are not judged by the on-track comparison


def dense_samples(track: Track) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Samples at most SAMPLE_SPACING apart on every segment: (xy (S,2), arc (S,), segment (S,), tangent (S,2))."""
    seg_len = np.diff(track.arc_length)
    counts = np.maximum(np.ceil(seg_len / SAMPLE_SPACING).astype(np.int64), 1)
    segment = np.repeat(np.arange(seg_len.size), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    t = (np.arange(segment.size) - first) / counts[segment]
    a, b = track.centerline[:-1], track.centerline[1:]
    xy = a[segment] + t[:, None] * (b - a)[segment]
    arc = track.arc_length[segment] + t * seg_len[segment]
    tangent = (b - a)[segment]
    return xy, arc, segment, tangent


def cyclic_gap(a: np.ndarray, b: np.ndarray, length: float) -> np.ndarray:
    d = np.abs(np.mod(a - b, length))
    return np.minimum(d, length - d)


def probe_points(track: Track, count: int, seed: int) -> np.ndarray:
    """Points around a track: most within 1.5 widths of the centre line, some anywhere near it."""
    rng = np.random.default_rng(seed)
    near = count * 3 // 4
    s = rng.uniform(0.0, track.length, near)
    heading = track.heading_at(s)
    normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    offset = rng.uniform(-1.5, 1.5, near) * track.nominal_width
    lo, hi = track.centerline.min(axis=0) - 1.0, track.centerline.max(axis=0) + 1.0
    anywhere = rng.uniform(lo, hi, (count - near, 2))
    return np.vstack([track.point_at(s) + offset[:, None] * normal, anywhere])


def check_projection(track: Track, points: np.ndarray) -> list[str]:
    """Compare the numba projection of ``points`` with the dense-sampling reference; returns problems."""
    arrays = track_arrays(track)
    fast = project_points(arrays, points)
    xy, arc, segment, tangent = dense_samples(track)
    rel = points[:, None, :] - xy[None, :, :]
    d2 = np.einsum("psk,psk->ps", rel, rel)
    best = np.argmin(d2, axis=1)
    rows = np.arange(points.shape[0])
    d_ref = np.sqrt(d2[rows, best])
    far_along = cyclic_gap(arc[None, :], arc[best][:, None], track.length) > AMBIGUITY_ARC
    d_other = np.sqrt(np.where(far_along, d2, np.inf).min(axis=1))
    unambiguous = d_other > d_ref + SAMPLE_SPACING
    problems = []

    def report(mask, what):
        if mask.any():
            i = int(np.flatnonzero(mask)[0])
            problems.append(f"{track.name}: {int(mask.sum())} points with {what}; e.g. point {points[i].tolist()}: "
                            f"fast seg {fast.segment[i]} s {fast.arc_length[i]:.5f} lat {fast.lateral[i]:.5f}, "
                            f"reference seg {segment[best[i]]} s {arc[best[i]]:.5f} d {d_ref[i]:.5f}")

    # The exact distance lies between the nearest sample's distance and that minus half a spacing.
    report((fast.distance > d_ref + 1e-9) | (fast.distance < d_ref - 0.5 * SAMPLE_SPACING - 1e-9), "a wrong distance")
    report(np.abs(np.abs(fast.lateral) - fast.distance) > 1e-9, "|lateral| != distance")
    # The reported arc length names a centre-line point at exactly the reported distance.
    foot = track.point_at(fast.arc_length)
    report(np.abs(np.linalg.norm(points - foot, axis=1) - fast.distance) > 1e-7, "an arc length off its foot point")
    report((fast.arc_length < 0) | (fast.arc_length >= track.length), "an arc length outside [0, length)")
    # closest_waypoints = [segment, segment + 1] bracket the projection by arc length.
    s = np.where((fast.arc_length < 1e-9) & (fast.segment == track.num_waypoints - 2), track.length, fast.arc_length)
    report((fast.segment < 0) | (fast.segment > track.num_waypoints - 2)
           | (track.arc_length[np.clip(fast.segment, 0, track.num_waypoints - 2)] > s + 1e-9)
           | (track.arc_length[np.clip(fast.segment, 0, track.num_waypoints - 2) + 1] < s - 1e-9),
           "a segment that does not hold the projection")
    gap = cyclic_gap(fast.arc_length, arc[best], track.length)
    report(unambiguous & (gap > AMBIGUITY_ARC + SAMPLE_SPACING), "the wrong arc length")
    # Away from waypoints, the segment must be the reference sample's segment.
    near_waypoint = cyclic_gap(arc[best][:, None], track.arc_length[None, :], track.length).min(axis=1) < 2 * SAMPLE_SPACING
    report(unambiguous & ~near_waypoint & (gap < 4 * SAMPLE_SPACING) & (fast.segment != segment[best]),
           "the wrong segment")
    ref_side = np.sign(tangent[best, 0] * rel[rows, best, 1] - tangent[best, 1] * rel[rows, best, 0])
    report(unambiguous & (d_ref > 0.01) & (np.sign(fast.lateral) != ref_side), "the wrong side (sign of lateral)")
    if unambiguous.mean() < 0.7:
        problems.append(f"{track.name}: only {unambiguous.mean():.0%} of the probe points are unambiguous")
    return problems


def check_hints(track: Track, points: np.ndarray, seed: int) -> list[str]:
    """Hinted (windowed) projection must equal the global one for good, nearby, random and far hints."""
    arrays = track_arrays(track)
    full = project_points(arrays, points)
    n_seg = track.num_waypoints - 1
    rng = np.random.default_rng(seed)
    hint_sets = {
        "exact": full.segment,
        "nearby": (full.segment + rng.integers(-4, 5, full.segment.size)) % n_seg,
        "random": rng.integers(0, n_seg, full.segment.size),
        "opposite": (full.segment + n_seg // 2) % n_seg,
        "out of range": full.segment + 3 * n_seg,
    }
    problems = []
    for name, hints in hint_sets.items():
        hinted = project_points(arrays, points, hints)
        bad = ((cyclic_gap(hinted.arc_length, full.arc_length, track.length) > 1e-9)
               | (np.abs(hinted.lateral - full.lateral) > 1e-12))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            problems.append(f"{track.name}: {name} hints change {int(bad.sum())} projections, e.g. point "
                            f"{points[i].tolist()} hint {hints[i]}: s {hinted.arc_length[i]} vs {full.arc_length[i]}")
    return problems


def check_on_track(track: Track, points: np.ndarray) -> tuple[int, float, str]:
    """Disagreements with the polygon test beyond BORDER_MARGIN: (count, worst border distance m, example)."""
    fast = points_on_track(track_arrays(track), points)
    polygon = (PolygonPath(track.outer).contains_points(points)
               & ~PolygonPath(track.inner).contains_points(points))
    border = np.sqrt(np.minimum(_sq_distance_to_polyline(points, track.inner),
                                _sq_distance_to_polyline(points, track.outer)))
    wrong = (fast != polygon) & (border > BORDER_MARGIN)
    if not wrong.any():
        return 0, 0.0, ""
    i = int(np.flatnonzero(wrong)[np.argmax(border[wrong])])
    example = f"point {points[i].round(4).tolist()} is {border[i]:.3f} m from a border, on_track={fast[i]}"
    return int(wrong.sum()), float(border[wrong].max()), example


def _sq_distance_to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    a, b = line[:-1], line[1:]
    seg = b - a
    rel = points[:, None, :] - a[None]
    t = np.clip(np.einsum("psk,sk->ps", rel, seg) / np.maximum(np.einsum("sk,sk->s", seg, seg), 1e-18), 0, 1)
    diff = rel - t[..., None] * seg[None]
    return np.einsum("psk,psk->ps", diff, diff).min(axis=1)


def border_probe_points(track: Track, count: int, seed: int) -> np.ndarray:
    """Points concentrated around both borders (where an on-track test can go wrong)."""
    rng = np.random.default_rng(seed)
    s = rng.uniform(0.0, track.length, count)
    heading = track.heading_at(s)
    normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    side = rng.choice([-1.0, 1.0], count)
    offset = side * (0.5 * track.nominal_width + rng.uniform(-0.15, 0.15, count))
    return track.point_at(s) + offset[:, None] * normal


def synthetic_tracks(circle_route, stadium_route, coarse: bool = True) -> list[Track]:
    tracks = [track_from_route(circle_route(), "circle"), track_from_route(circle_route(ccw=False), "circle_cw"),
              track_from_route(stadium_route(), "stadium")]
    if coarse:  # 36 degrees of turn per waypoint in the ends
        tracks.append(track_from_route(stadium_route(spacing=0.7, radius=1.2), "coarse_stadium"))
    return tracks


# ---------------------------------------------------------------- synthetic and built-in tracks


def test_projection_on_a_circle_is_exact(circle_track):
    """Known answers: arc length = angle x chord ratio, lateral = radius - |p| (left = inside on a CCW circle)."""
    rng = np.random.default_rng(1)
    angle = rng.uniform(0, 2 * np.pi, 200)
    radius = rng.uniform(2.2, 3.8, 200)
    points = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    proj = project_points(track_arrays(circle_track), points)
    sagitta = 3.0 * (1 - np.cos(np.pi / 400))
    np.testing.assert_allclose(proj.lateral, 3.0 - radius, atol=2 * sagitta)
    np.testing.assert_allclose(proj.arc_length / circle_track.length, angle / (2 * np.pi), atol=1e-3)
    expected = np.floor(angle / (2 * np.pi / 400)).astype(int)
    inside = radius < 3.0  # outside the circle a point near a vertex projects onto the vertex (either segment)
    np.testing.assert_array_equal(proj.segment[inside], expected[inside])
    assert (np.abs(proj.segment - expected) <= 1).all()
    cw = circle_track.reversed()
    back = project_points(track_arrays(cw), points)
    np.testing.assert_allclose(back.lateral, -proj.lateral, atol=1e-12)  # left and right swap
    np.testing.assert_allclose(back.arc_length, np.mod(cw.length - proj.arc_length, cw.length), atol=1e-9)


def test_projection_matches_dense_sampling_on_synthetic_and_builtin_tracks(circle_route, stadium_route):
    tracks = synthetic_tracks(circle_route, stadium_route) + [load_track(n) for n in builtin_track_names()]
    tracks += [t.reversed() for t in tracks[-2:]]
    problems = []
    for k, track in enumerate(tracks):
        points = probe_points(track, 4 * POINTS_PER_TRACK, seed=k)
        problems += check_projection(track, points) + check_hints(track, points, seed=k)
    assert not problems, "\n".join(problems)


def test_projection_with_zero_length_segments(circle_route):
    route = circle_route(num_points=120)
    route = np.insert(route, 30, route[30], axis=0)
    route = np.insert(route, 90, route[90], axis=0)
    track = track_from_route(route, "repeats", remove_repeats=False)
    assert (np.diff(track.arc_length) == 0).sum() == 2
    points = probe_points(track, 200, seed=3)
    problems = check_projection(track, points) + check_hints(track, points, seed=3)
    assert not problems, "\n".join(problems)


def test_numba_projection_matches_numpy_reference():
    track = load_track("technical")
    points = probe_points(track, 2000, seed=11)  # above the parallel threshold
    for batch in (points, points[:50]):  # parallel and serial loops
        fast = project_points(track_arrays(track), batch)
        ref = project_points_reference(track, batch)
        np.testing.assert_allclose(fast.arc_length, ref.arc_length, atol=1e-9)
        np.testing.assert_allclose(fast.lateral, ref.lateral, atol=1e-9)
        np.testing.assert_allclose(fast.distance, ref.distance, atol=1e-9)
        assert np.mean(fast.segment == ref.segment) > 0.99  # ties at waypoints may pick either side


def test_projection_of_the_closing_point_reports_arc_zero(stadium_track):
    proj = project_points(track_arrays(stadium_track), stadium_track.centerline[[0, -1]])
    np.testing.assert_allclose(proj.arc_length, 0.0, atol=1e-12)
    np.testing.assert_allclose(proj.distance, 0.0, atol=1e-12)


def test_bad_point_shapes_are_rejected(stadium_track):
    with pytest.raises(ValueError, match=r"shape \(M, 2\)"):
        project_points(track_arrays(stadium_track), np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"shape \(M, 2\)"):
        points_on_track(track_arrays(stadium_track), np.zeros(4))


def _on_track_failures(tracks: list[Track]) -> list[str]:
    failures = []
    for k, track in enumerate(tracks):
        for t in (track, track.reversed()):
            points = np.vstack([probe_points(t, 300, seed=k), border_probe_points(t, 300, seed=k)])
            count, worst, example = check_on_track(t, points)
            if count:
                failures.append(f"{t.name}: {count} disagreements, up to {worst:.3f} m inside/outside; {example}")
    return failures


def test_on_track_matches_polygon_on_synthetic_and_builtin_tracks(circle_route, stadium_route):
    tracks = synthetic_tracks(circle_route, stadium_route, coarse=False)
    failures = _on_track_failures(tracks + [load_track(n) for n in builtin_track_names()])
    assert not failures, "\n".join(failures)


def test_on_track_matches_polygon_where_waypoints_are_coarse(stadium_route):
    """Half circles of 1.2 m radius drawn with 5 segments (36 degrees of turn per waypoint, like the coarse
    hamption/thunder_hill routes): between two waypoints the border chord lies w (1 - cos 18 deg) = 2.4 cm
    nearer the centre line than the waypoint widths say; the on-track test must still follow the border."""
    failures = _on_track_failures([track_from_route(stadium_route(spacing=0.7, radius=1.2), "coarse_stadium")])
    assert not failures, "\n".join(failures)


def test_on_track_known_answers(circle_track):
    angle = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    unit = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    arrays = track_arrays(circle_track)
    assert points_on_track(arrays, 3.0 * unit).all()
    assert points_on_track(arrays, 2.52 * unit).all() and points_on_track(arrays, 3.48 * unit).all()
    assert not points_on_track(arrays, 2.48 * unit).any() and not points_on_track(arrays, 3.52 * unit).any()
    assert not points_on_track(arrays, np.zeros((1, 2))).any()


# ---------------------------------------------------------------- every reference route


def test_projection_matches_dense_sampling_on_reference_tracks(reference_tracks, reference_tracks_dir):
    from laplab.track.geometry import load_route_file
    tracks = list(reference_tracks.values())
    # Routes with their repeated point kept (zero-length segments), as older DeepRacer loaded them.
    tracks += [load_route_file(reference_tracks_dir / f"{n}.npy", remove_repeats=False, name=f"{n}(raw)")
               for n in ("Oval_track", "reInvent2019_track")]
    problems = []
    for k, track in enumerate(tracks):
        points = probe_points(track, POINTS_PER_TRACK, seed=100 + k)
        problems += check_projection(track, points) + check_hints(track, points, seed=k)
    assert not problems, "\n".join(problems[:30])


def test_on_track_matches_polygon_on_reference_tracks(reference_tracks):
    failures = []
    for k, track in enumerate(reference_tracks.values()):
        points = np.vstack([probe_points(track, 150, seed=k), border_probe_points(track, 250, seed=k)])
        count, worst, example = check_on_track(track, points)
        if count:
            failures.append(f"{track.name}: {count}/400 disagreements, up to {worst:.3f} m from a border; {example}")
    assert not failures, f"{len(failures)} tracks disagree with the polygon test:\n" + "\n".join(failures)


# ---------------------------------------------------------------- clearance (the step kernel's shortcut)


def _points_within_clearance(arrays, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points, each within its centre segment's clearance of a point of that segment; (P, 2), (P,)."""
    rng = np.random.default_rng(seed)
    seg = rng.integers(0, arrays.segments.shape[0], count)
    on_segment = arrays.segments[seg, :2] + rng.uniform(0, 1, count)[:, None] * arrays.segments[seg, 2:4]
    angle = rng.uniform(0, 2 * np.pi, count)
    radius = 0.999 * arrays.clearance[seg] * np.sqrt(rng.uniform(0, 1, count))
    return on_segment + radius[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1), seg


def _clearance_failures(tracks: list[Track], count: int) -> list[str]:
    from laplab.track.projection import point_on_road_near
    failures = []
    for k, track in enumerate(tracks):
        for t in (track, track.reversed()):
            arrays = track_arrays(t)
            half_width = 0.5 * (t.left_width + t.right_width)
            if not (0.0 < arrays.clearance.min() and np.median(arrays.clearance) <= 1.001 * np.median(half_width)):
                failures.append(f"{t.name}: clearance {arrays.clearance.min():.3f}..{arrays.clearance.max():.3f} m")
            points, seg = _points_within_clearance(arrays, count, seed=k)
            near = np.array([point_on_road_near(x, y, arrays, s) for (x, y), s in zip(points, seg)])
            on = points_on_track(arrays, points)
            if not (near.all() and on.all()):
                failures.append(f"{t.name}: {(~near).sum()} / {(~on).sum()} of {count} points within the clearance "
                                "are off the road")
    return failures


def test_every_point_within_a_segments_clearance_is_on_the_road(circle_route, stadium_route):
    tracks = synthetic_tracks(circle_route, stadium_route, coarse=True) + [load_track(n) for n in builtin_track_names()]
    failures = _clearance_failures(tracks, 2000)
    assert not failures, "\n".join(failures)
    # the circle (radius 3 m, 1 m wide): a disk of the clearance reaches the borders and no further
    arrays = track_arrays(track_from_route(circle_route(), "circle"))
    np.testing.assert_allclose(arrays.clearance, 0.5, atol=0.01)


def test_every_point_within_a_segments_clearance_is_on_the_road_on_reference_tracks(reference_tracks):
    failures = _clearance_failures(list(reference_tracks.values()), 500)
    assert not failures, "\n".join(failures)


def test_clearance_is_zero_where_a_centre_segment_crosses_a_border():
    from laplab.track.projection import _border_clearance, _segment_table
    centre = _segment_table(np.array([[0.0, 0.0], [1.0, 0.0]]))
    crossing = _segment_table(np.array([[0.5, -1.0], [0.5, 1.0]]))
    apart = _segment_table(np.array([[0.5, 0.3], [2.0, 0.3]]))
    assert _border_clearance(centre, crossing, apart)[0] == 0.0
    assert _border_clearance(centre, apart, apart)[0] == pytest.approx(0.3)
