"""laplab's built-in tracks: our own designs, written as recipes and built into DeepRacer routes.

A recipe is a sequence of centre-line pieces driven counter-clockwise from the start point
(heading +x): ``Straight(length)`` and ``Arc(turn_deg, radius)`` (positive turn = left). Arcs join
straights tangentially, so the centre line is C1 (its heading is continuous). The turns of a closed
CCW loop add up to +360 deg. Exactly two straights may leave their length open
(``Straight(None)``); they are solved so that the loop closes exactly. ``build_route`` samples the
centre line at uniform arc length (``spacing``), offsets the borders by half the width along the
exact normal of the centre line (inner border on the driver's left) and returns the (N, 6) route.
``scripts/make_builtin_tracks.py`` writes the routes to ``laplab/track/data``; see ``docs/tracks.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

BORDER_MARGIN = 0.15  # m: smallest allowed gap between an arc's centre and the inner border
ROUND_DECIMALS = 6  # routes are rounded to 1 um so that files are byte-stable across machines
PLACEMENT_CORNER = 0.5  # m: the outer border's bounding box starts at (0.5, 0.5)


class DesignError(ValueError):
    """A track recipe that cannot be built (it does not close, or its borders would overlap)."""


@dataclass(frozen=True)
class Straight:
    """A straight piece, ``length`` in m; ``None`` = solved so that the loop closes."""

    length: float | None


@dataclass(frozen=True)
class Arc:
    """A circular piece turning ``turn_deg`` degrees (positive = left) on a centre-line ``radius`` in m."""

    turn_deg: float
    radius: float


Segment = Straight | Arc


@dataclass(frozen=True)
class TrackDesign:
    """Recipe of one built-in track: pieces of the centre line, width and waypoint spacing (m)."""

    name: str
    description: str
    width: float
    segments: tuple[Segment, ...]
    spacing: float = 0.15


def _fail(design: TrackDesign, message: str) -> DesignError:
    return DesignError(f"track design {design.name!r}: {message}")


def _check_segments(design: TrackDesign) -> None:
    if not (math.isfinite(design.width) and design.width > 0):
        raise _fail(design, f"width must be a positive number of metres, got {design.width!r}.")
    if not (math.isfinite(design.spacing) and 0.02 <= design.spacing <= 0.5):
        raise _fail(design, f"spacing must lie in [0.02, 0.5] m, got {design.spacing!r}.")
    min_radius = design.width / 2 + BORDER_MARGIN
    for index, seg in enumerate(design.segments):
        if isinstance(seg, Arc):
            if not (math.isfinite(seg.radius) and seg.radius >= min_radius):
                raise _fail(design, f"segment {index} {seg}: radius must be >= half width + "
                                    f"{BORDER_MARGIN} m = {min_radius:.3f} m, or the inner border folds over.")
            if not (math.isfinite(seg.turn_deg) and seg.turn_deg != 0):
                raise _fail(design, f"segment {index} {seg}: turn_deg must be a non-zero number.")
        elif isinstance(seg, Straight):
            if seg.length is not None and not (math.isfinite(seg.length) and seg.length > 0):
                raise _fail(design, f"segment {index} {seg}: length must be positive (or None to solve it).")
        else:
            raise _fail(design, f"segment {index} is {seg!r}, not a Straight or an Arc.")
    total_turn = sum(seg.turn_deg for seg in design.segments if isinstance(seg, Arc))
    if abs(total_turn - 360.0) > 1e-9:
        raise _fail(design, f"the turns add up to {total_turn} deg; a closed counter-clockwise loop needs 360.")


def _segment_displacements(segments: tuple[Segment, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start heading (rad), unit direction (for straights) and displacement (m) of each piece; (S,), (S,2), (S,2)."""
    headings, directions, displacements = [], [], []
    heading = 0.0
    for seg in segments:
        headings.append(heading)
        direction = np.array([math.cos(heading), math.sin(heading)])
        directions.append(direction)
        if isinstance(seg, Straight):
            displacements.append(direction * (seg.length or 0.0))
        else:
            turn = math.radians(seg.turn_deg)
            chord = 2 * seg.radius * abs(math.sin(turn / 2))
            mid = heading + turn / 2
            displacements.append(chord * np.array([math.cos(mid), math.sin(mid)]))
            heading += turn
    return np.array(headings), np.array(directions), np.array(displacements)


def resolve_segments(design: TrackDesign) -> tuple[Segment, ...]:
    """The recipe with every open straight given the length that closes the loop."""
    _check_segments(design)
    open_indices = [i for i, seg in enumerate(design.segments) if isinstance(seg, Straight) and seg.length is None]
    _, directions, displacements = _segment_displacements(design.segments)
    gap = -displacements.sum(axis=0)
    segments = list(design.segments)
    if len(open_indices) == 2:
        basis = directions[open_indices].T  # (2, 2): columns = directions of the open straights
        if abs(np.linalg.det(basis)) < 1e-6:
            raise _fail(design, f"the open straights {open_indices} are parallel; their lengths cannot close the loop.")
        lengths = np.linalg.solve(basis, gap)
        if np.any(lengths <= 0.05):
            raise _fail(design, f"closing the loop needs open straight lengths {lengths.round(3).tolist()} m; "
                                "each must be at least 0.05 m (must be positive): change the other pieces.")
        for index, length in zip(open_indices, lengths):
            segments[index] = Straight(float(length))
    elif open_indices:
        raise _fail(design, f"{len(open_indices)} open straights (length None); use exactly 0 or 2.")
    else:
        error = float(np.hypot(*gap))
        if error > 1e-9:
            raise _fail(design, f"the loop misses its start by {error:.6f} m; leave two straights open (None).")
    return tuple(segments)


def segment_lengths(segments: tuple[Segment, ...]) -> np.ndarray:
    """Centre-line length of each resolved piece, m, shape (S,)."""
    return np.array([seg.length if isinstance(seg, Straight) else math.radians(abs(seg.turn_deg)) * seg.radius
                     for seg in segments], dtype=np.float64)


def centerline_poses(segments: tuple[Segment, ...], s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (M,2) in m and headings (M,) in rad of the centre line at arc lengths ``s`` (M,) in m.

    Starts at the origin heading +x; ``segments`` must be resolved (no open straights).
    """
    lengths = segment_lengths(segments)
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    headings, _, displacements = _segment_displacements(segments)
    origins = np.concatenate([np.zeros((1, 2)), np.cumsum(displacements, axis=0)[:-1]])
    curvature = np.array([0.0 if isinstance(seg, Straight) else math.copysign(1.0 / seg.radius, seg.turn_deg)
                          for seg in segments])
    index = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(segments) - 1)
    t = s - starts[index]
    h0, k, origin = headings[index], curvature[index], origins[index]
    heading = h0 + k * t
    is_arc = k != 0
    safe_k = np.where(is_arc, k, 1.0)
    dx = np.where(is_arc, (np.sin(heading) - np.sin(h0)) / safe_k, t * np.cos(h0))
    dy = np.where(is_arc, (np.cos(h0) - np.cos(heading)) / safe_k, t * np.sin(h0))
    return origin + np.stack([dx, dy], axis=1), heading


def crossing_segment_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(M, K) bool: segment i of polyline ``a`` (M+1, 2) crosses or touches segment k of ``b`` (K+1, 2)."""
    a0, a1 = a[:-1, None, :], a[1:, None, :]
    b0, b1 = b[None, :-1, :], b[None, 1:, :]

    def orientation(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])

    straddle_a = orientation(a0, a1, b0) * orientation(a0, a1, b1) <= 0
    straddle_b = orientation(b0, b1, a0) * orientation(b0, b1, a1) <= 0
    # Bounding boxes keep distant collinear pieces of one straight (orientations ~0) apart.
    boxes_meet = np.all((np.maximum(a0, a1) >= np.minimum(b0, b1)) & (np.maximum(b0, b1) >= np.minimum(a0, a1)),
                        axis=2)
    return straddle_a & straddle_b & boxes_meet


def _check_borders(design: TrackDesign, inner: np.ndarray, outer: np.ndarray) -> None:
    """Raise if a closed border (N, 2) crosses itself or the other border (the track overlaps itself)."""
    for label, border in (("inner", inner), ("outer", outer)):
        crossings = crossing_segment_pairs(border, border)
        count = len(border) - 1
        i, k = np.indices((count, count))
        gap = np.abs(i - k)
        crossings &= (gap > 1) & (gap < count - 1)  # neighbouring segments share a point
        if crossings.any():
            first, second = np.argwhere(crossings)[0]
            raise _fail(design, f"the {label} border crosses itself (segments {first} and {second}, near "
                                f"{border[first].round(2).tolist()}): two parts of the track overlap.")
    if crossing_segment_pairs(inner, outer).any():
        raise _fail(design, "the inner and outer borders cross: two parts of the track overlap.")


def build_route(design: TrackDesign) -> np.ndarray:
    """DeepRacer route of a design: (N, 6) float64 [centre x,y | inner x,y | outer x,y], closed, CCW.

    Waypoints lie at uniform arc length, about ``design.spacing`` apart; row N-1 repeats row 0.
    The track is shifted so its outer border's bounding box starts at (0.5, 0.5) m.
    """
    segments = resolve_segments(design)
    total = float(segment_lengths(segments).sum())
    count = max(int(round(total / design.spacing)), 16)
    s = np.arange(count) * (total / count)
    centre, heading = centerline_poses(segments, s)
    left = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    inner = centre + left * (design.width / 2)
    outer = centre - left * (design.width / 2)
    route = np.concatenate([centre, inner, outer], axis=1)
    corner = route[:, 4:6].min(axis=0)
    route -= np.tile(corner - PLACEMENT_CORNER, 3)
    route = np.round(route, ROUND_DECIMALS) + 0.0  # + 0.0 turns -0.0 into 0.0
    route = np.concatenate([route, route[:1]], axis=0)
    _check_borders(design, route[:, 2:4], route[:, 4:6])
    return route


def route_length(route: np.ndarray) -> float:
    """Centre-line length of a route, m."""
    return float(np.linalg.norm(np.diff(route[:, 0:2], axis=0), axis=1).sum())


S, A = Straight, Arc

DESIGNS: dict[str, TrackDesign] = {
    design.name: design
    for design in (
        TrackDesign(
            name="oval",
            description="Beginner oval: two 4 m straights joined by two half circles of 1.5 m radius.",
            width=1.067,
            segments=(S(2.0), A(180, 1.5), S(4.0), A(180, 1.5), S(2.0)),
        ),
        TrackDesign(
            name="classic_2018",
            description="re:Invent-2018-style loop (default track): a long start straight, two tight "
                        "corners up to the back straight, a left-right step, a tight left and a fast "
                        "diagonal bend back to the start.",
            width=0.76,
            segments=(
                S(2.8), A(90, 0.9), S(2.23), A(90, 0.6), S(1.8), A(45, 0.8), S(0.7), A(-45, 0.8),
                S(1.8), A(135, 0.65), S(None), A(45, 1.0), S(None),
            ),
        ),
        TrackDesign(
            name="speedway_23",
            description="Tri-oval speedway: a kinked front stretch, two long fast ends and a back "
                        "straight; flowing, speed-limited by grip in the ends.",
            width=1.067,
            segments=(
                A(12, 3.5), S(None), A(80, 1.6), S(0.5), A(88, 1.8), S(5.4),
                A(88, 1.8), S(0.5), A(80, 1.6), S(None), A(12, 3.5),
            ),
        ),
        TrackDesign(
            name="technical",
            description="Technical circuit: a left-right chicane, a tight hairpin at the end of an "
                        "infield tongue and six 90-degree corners; rewards braking and precise lines.",
            width=1.067,
            segments=(
                S(1.6), A(90, 1.3), S(1.4), A(50, 0.85), A(-50, 0.85), S(1.6), A(90, 0.9), S(3.3),
                A(90, 1.1), S(0.4), A(90, 0.9), S(1.3), A(-180, 0.8), S(1.3), A(90, 0.9), S(None),
                A(90, 1.2), S(None),
            ),
        ),
        TrackDesign(
            name="grand_tour",
            description="Grand tour, ~60 m: a long back straight ending in a hairpin, a left-right "
                        "step on the climb, esses on the way down, an infield step and a short main "
                        "straight; a long lap for endurance and race-line work.",
            width=1.067,
            segments=(
                S(5.0), A(90, 1.5), S(4.0), A(45, 2.0), S(2.0), A(-45, 2.0), S(1.0), A(-90, 1.2),
                S(3.0), A(180, 0.9), S(14.0), A(90, 1.5), S(1.0), A(40, 2.0), A(-80, 2.0),
                A(40, 2.0), S(None), A(90, 1.2), S(1.5), A(-90, 1.2), S(1.0), A(90, 1.2), S(None),
            ),
            spacing=0.16,
        ),
    )
}
