"""Track geometry: DeepRacer routes, validation, arc length, widths, direction.

A DeepRacer route is a float64 array ``(N, 6)`` in metres: centre line x, y | inner border x, y |
outer border x, y, closed when row 0 equals row N-1. :class:`Track` holds the validated arrays and
everything derived from them once (arc length, perpendicular widths, driving direction).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from laplab.errors import UserError

CLOSE_TOLERANCE = 1e-6  # m: first and last rows closer than this close the loop
MAX_WAYPOINTS = 2000  # DeepRacer's routes have 50-400 rows; 2,000 is one every 5 cm on a 100 m loop
MIN_ROAD_WIDTH = 0.05  # m between the borders at a waypoint (DeepRacer's tracks: 0.6-1.1 m)


class TrackError(UserError, ValueError):
    """A route file or array that is not a valid DeepRacer track."""

    default_field = "track"


@dataclass(frozen=True, eq=False)
class Track:
    """A closed DeepRacer track, driven in the order of its waypoints.

    Arrays (N = number of waypoints, the closing point included, so row 0 == row N-1):
      centerline, inner, outer: (N, 2) float64, metres.
      arc_length: (N,) cumulative centre-line length at each waypoint; [0] = 0, [-1] = length.
      left_width, right_width: (N,) perpendicular distance from each centre point to the border on
        the driver's left / right (in the driving direction), metres.
      road_width: (N,) DeepRacer's ``track_width``: distance between the nearest points of the two
        borders to each centre point, metres.
    """

    name: str
    centerline: np.ndarray
    inner: np.ndarray
    outer: np.ndarray
    source: str = "array"
    is_ccw: bool = field(init=False)
    arc_length: np.ndarray = field(init=False, repr=False)
    left_width: np.ndarray = field(init=False, repr=False)
    right_width: np.ndarray = field(init=False, repr=False)
    road_width: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        seg = np.diff(self.centerline, axis=0)
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        ccw = signed_area(self.centerline) > 0
        left, right = (self.inner, self.outer) if ccw else (self.outer, self.inner)
        set_ = object.__setattr__
        set_(self, "is_ccw", bool(ccw))
        set_(self, "arc_length", arc)
        set_(self, "left_width", perpendicular_distance(self.centerline, left, side=+1.0))
        set_(self, "right_width", perpendicular_distance(self.centerline, right, side=-1.0))
        set_(self, "road_width", nearest_border_width(self.centerline, self.inner, self.outer))
        for name in ("centerline", "inner", "outer", "arc_length", "left_width", "right_width", "road_width"):
            getattr(self, name).flags.writeable = False

    @property
    def length(self) -> float:
        """Centre-line length, m (DeepRacer's ``track_length``)."""
        return float(self.arc_length[-1])

    @property
    def width(self) -> np.ndarray:
        """(N,) perpendicular width at each waypoint, m."""
        return self.left_width + self.right_width

    @property
    def nominal_width(self) -> float:
        """Median perpendicular width, m (what the track tables quote)."""
        return float(np.median(self.width))

    @property
    def direction(self) -> str:
        """``"ccw"`` or ``"cw"``: the sense in which the car goes round."""
        return "ccw" if self.is_ccw else "cw"

    @property
    def num_waypoints(self) -> int:
        return int(self.centerline.shape[0])

    def route(self) -> np.ndarray:
        """The track as a DeepRacer route array (N, 6)."""
        return np.hstack([self.centerline, self.inner, self.outer])

    def reversed(self) -> "Track":
        """The same track driven the other way (DeepRacer's ``REVERSE_DIR``)."""
        name = self.name[:-9] if self.name.endswith("@reversed") else f"{self.name}@reversed"
        return Track(name, self.centerline[::-1].copy(), self.inner[::-1].copy(),
                     self.outer[::-1].copy(), source=self.source)

    def point_at(self, s: np.ndarray) -> np.ndarray:
        """Centre-line points at arc lengths ``s`` (any shape, m, wrapped), shape ``s.shape + (2,)``."""
        s = np.mod(np.asarray(s, dtype=np.float64), self.length)
        x = np.interp(s, self.arc_length, self.centerline[:, 0])
        y = np.interp(s, self.arc_length, self.centerline[:, 1])
        return np.stack([x, y], axis=-1)

    def heading_at(self, s: np.ndarray) -> np.ndarray:
        """Centre-line direction (rad) at arc lengths ``s`` (segment direction, wrapped)."""
        s = np.mod(np.asarray(s, dtype=np.float64), self.length)
        seg = np.clip(np.searchsorted(self.arc_length, s, side="right") - 1, 0, self.num_waypoints - 2)
        d = self.centerline[seg + 1] - self.centerline[seg]
        return np.arctan2(d[..., 1], d[..., 0])


def signed_area(polygon: np.ndarray) -> float:
    """Shoelace area of a closed polyline (N, 2), m^2; positive when counter-clockwise."""
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))


def centerline_normals(centerline: np.ndarray) -> np.ndarray:
    """(N, 2) unit left normals at each waypoint of a closed line (central differences)."""
    prev_pt = np.roll(centerline[:-1], 1, axis=0)
    next_pt = np.roll(centerline[:-1], -1, axis=0)
    tangent = next_pt - prev_pt
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    return np.vstack([normal, normal[:1]])


def perpendicular_distance(centerline: np.ndarray, border: np.ndarray, side: float) -> np.ndarray:
    """(N,) distance from each centre point along its normal (``side`` +1 left, -1 right) to ``border``.

    Intersects each normal ray with the border segments it crosses (an R-tree of the segments, so
    time and memory grow as N log N). Where a ray misses the border (a kink in an old route), falls
    back to the distance to the nearest border point.
    """
    import shapely

    normals = centerline_normals(centerline) * side
    tree = _segment_tree(border)
    nearest = np.linalg.norm(_nearest_points(centerline, border, tree) - centerline, axis=1)
    # A ray that hits farther than 3x the nearest border point (+5 cm) crossed a fold of the border:
    # that is not its width, so only the ray's first 3x nearest + 5 cm are searched.
    reach = 3.0 * nearest + 0.05
    rays = shapely.linestrings(np.stack([centerline, centerline + normals * reach[:, None]], axis=1))
    pts, segs = tree.query(rays, predicate="intersects")
    a, b = border[:-1][segs], border[1:][segs]
    seg, rel, nrm = b - a, a - centerline[pts], normals[pts]
    denom = nrm[:, 0] * seg[:, 1] - nrm[:, 1] * seg[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        safe = np.where(np.abs(denom) < 1e-12, np.nan, denom)
        t_ray = (rel[:, 0] * seg[:, 1] - rel[:, 1] * seg[:, 0]) / safe
        u_seg = (rel[:, 0] * nrm[:, 1] - rel[:, 1] * nrm[:, 0]) / safe
    hit = (t_ray > 0) & (u_seg >= -1e-9) & (u_seg <= 1 + 1e-9)
    t = np.full(centerline.shape[0], np.inf)
    np.minimum.at(t, pts[hit], t_ray[hit])
    return np.where(np.isfinite(t) & (t < reach), t, nearest)


def nearest_border_width(centerline: np.ndarray, inner: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """(N,) distance between the nearest inner and nearest outer border points of each centre point."""
    p_in = _nearest_points(centerline, inner)
    p_out = _nearest_points(centerline, outer)
    return np.linalg.norm(p_out - p_in, axis=1)


def _segment_tree(polyline: np.ndarray):
    """A shapely STRtree of the (M) segments of ``polyline`` (M+1, 2); tree index i = segment i."""
    import shapely
    return shapely.STRtree(shapely.linestrings(np.stack([polyline[:-1], polyline[1:]], axis=1)))


def _nearest_points(points: np.ndarray, polyline: np.ndarray, tree=None) -> np.ndarray:
    """(P, 2) nearest point of ``polyline`` (M+1, 2) to each of ``points`` (P, 2): N log N."""
    import shapely
    tree = _segment_tree(polyline) if tree is None else tree
    found, segments = tree.query_nearest(shapely.points(points), all_matches=False)
    nearest = np.empty(points.shape[0], dtype=np.int64)
    nearest[found] = segments
    a, b = polyline[:-1][nearest], polyline[1:][nearest]
    seg, rel = b - a, points - a
    t = np.clip((rel * seg).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-18), 0.0, 1.0)
    return a + t[:, None] * seg


def remove_repeated_points(route: np.ndarray) -> np.ndarray:
    """Drop interior rows whose centre point repeats the previous one (current DeepRacer behaviour).

    The closing row (equal to row 0) is kept. Returns a new array.
    """
    step = np.linalg.norm(np.diff(route[:, 0:2], axis=0), axis=1)
    keep = np.ones(route.shape[0], dtype=bool)
    keep[1:-1] = step[:-1] > 1e-9
    return route[keep].copy()


def validate_route(route: object, source: str = "array") -> np.ndarray:
    """Check a DeepRacer route and return it as a C-contiguous float64 ``(N, 6)`` array.

    Raises :class:`TrackError` naming ``source`` and what is wrong: shape, dtype, too many waypoints
    (:data:`MAX_WAYPOINTS`, checked before anything is copied), NaN/Inf, too few points, an open
    loop, no width between the borders, a line that crosses itself or another (O(N log N), with the
    crossing point), or borders that are not on both sides of the centre line.
    """
    array = np.asarray(route)
    if array.ndim != 2 or array.shape[1] != 6:
        raise TrackError(
            f"{source}: a DeepRacer route must be an array of shape (N, 6) "
            f"[centre x, y | inner x, y | outer x, y] in metres, but this one has shape {array.shape}.")
    if not np.issubdtype(array.dtype, np.number) or np.issubdtype(array.dtype, np.complexfloating):
        raise TrackError(f"{source}: route values must be real numbers (float64), got dtype {array.dtype}.")
    if array.shape[0] > MAX_WAYPOINTS:
        raise TrackError(
            f"{source}: the route has {array.shape[0]:,} waypoints; laplab accepts at most {MAX_WAYPOINTS:,} "
            f"(DeepRacer's tracks have 50 to 400, one every 5 to 50 cm). Resample it along the centre line, "
            f"e.g. keep every {-(-array.shape[0] // 1000)}th row, and close it again.")
    array = np.array(array, dtype=np.float64, order="C")  # a copy: the caller's array (or a read-only file map) is not touched
    bad = ~np.isfinite(array)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise TrackError(f"{source}: route has {int(bad.sum())} NaN/Inf values, the first at row {row}, "
                         f"column {col}; every coordinate must be a finite number of metres.")
    if array.shape[0] < 4:
        raise TrackError(f"{source}: a route needs at least 4 rows (a closed loop of 3 points), got {array.shape[0]}.")
    gap = float(np.abs(array[0] - array[-1]).max())
    if gap > CLOSE_TOLERANCE:
        raise TrackError(
            f"{source}: the route is not a closed loop: its last row differs from its first by up to "
            f"{gap:.4g} m. laplab drives closed tracks only; close it by appending the first row.")
    array[-1] = array[0]
    centre, inner, outer = array[:, 0:2], array[:, 2:4], array[:, 4:6]
    width = np.hypot(outer[:, 0] - inner[:, 0], outer[:, 1] - inner[:, 1])
    narrow = np.flatnonzero(width < MIN_ROAD_WIDTH)
    if narrow.size:
        row = int(narrow[np.argmin(width[narrow])])
        raise TrackError(
            f"{source}: the road has no width at row {row} (the inner and outer borders are {width[row]:.3f} m "
            f"apart{f', and at {narrow.size - 1} more rows' if narrow.size > 1 else ''}); a track needs a width "
            f"of at least {MIN_ROAD_WIDTH} m between its borders everywhere (DeepRacer's are 0.6 to 1.1 m wide).")
    _check_no_crossings(centre, inner, outer, source)
    normals = centerline_normals(centre)[:-1]
    side_inner = np.einsum("ij,ij->i", inner[:-1] - centre[:-1], normals)
    side_outer = np.einsum("ij,ij->i", outer[:-1] - centre[:-1], normals)
    opposite = np.sign(side_inner) * np.sign(side_outer) < 0
    if opposite.mean() < 0.9:
        worst = int(np.argmin(opposite))
        raise TrackError(
            f"{source}: the borders are not on both sides of the centre line ({100 * (1 - opposite.mean()):.0f}% "
            f"of rows have both borders on one side, e.g. row {worst}); columns must be centre | inner | outer.")
    if np.sign(np.median(side_inner)) == np.sign(signed_area(centre)) * -1:
        raise TrackError(
            f"{source}: columns 2:4 lie outside the loop and 4:6 inside: inner and outer borders are swapped.")
    return array


def _check_no_crossings(centre: np.ndarray, inner: np.ndarray, outer: np.ndarray, source: str) -> None:
    """Refuse a centre line or border that crosses itself (a figure-eight) or another one, naming the
    crossing point. GEOS's noding with a spatial index: O(N log N)."""
    import shapely
    from shapely.geometry import LineString, Polygon

    lines = {"centre line": centre, "inner border": inner, "outer border": outer}
    for name, points in lines.items():
        line = LineString(points)
        if not line.is_simple:
            reason = shapely.is_valid_reason(Polygon(points))
            where = _point_in(reason) or _point_in(str(shapely.union_all([line]).wkt))
            raise TrackError(
                f"{source}: the {name} crosses itself{f' at {where}' if where else ''} (a figure-eight or a "
                f"loop in the route); laplab drives tracks whose centre line and borders are simple closed "
                f"loops that never cross.")
    names = list(lines)
    for i in range(3):
        for j in range(i + 1, 3):
            a, b = LineString(lines[names[i]]), LineString(lines[names[j]])
            if a.intersects(b):
                point = a.intersection(b).representative_point()
                raise TrackError(
                    f"{source}: the {names[i]} and the {names[j]} cross at ({point.x:.3f}, {point.y:.3f}) m; the "
                    f"centre line must run between the borders all the way round (are columns swapped in "
                    f"part of the file?).")


def _point_in(text: str) -> str | None:
    import re
    match = re.search(r"\[\s*(-?[0-9.e+-]+)\s+(-?[0-9.e+-]+)", text or "")
    return f"({float(match.group(1)):.3f}, {float(match.group(2)):.3f}) m" if match else None


def track_from_route(route: object, name: str, source: str = "array",
                     remove_repeats: bool = True) -> Track:
    """Build a :class:`Track` from a route array after validating it.

    ``remove_repeats`` drops repeated interior centre points as current DeepRacer does; pass False for
    the raw rows (older DeepRacer: ``closest_waypoints`` indices then match the file's rows).
    """
    array = validate_route(route, source)
    if remove_repeats:
        array = remove_repeated_points(array)
    return Track(name, array[:, 0:2].copy(), array[:, 2:4].copy(), array[:, 4:6].copy(), source=source)


def read_route_file(path: Path) -> np.ndarray:
    """The array of a ``.npy`` route file, mapped read-only (:func:`validate_route` checks its size
    before anything is read); :class:`TrackError` when the file is missing or not a readable array."""
    if not path.is_file():
        raise TrackError(f"{path}: no such track file.")
    try:
        return np.load(path, allow_pickle=False, mmap_mode="r")
    except Exception as exc:  # numpy raises several kinds for corrupt files
        raise TrackError(f"{path}: not a readable .npy array ({exc}).") from None


def load_route_file(path: str | Path, remove_repeats: bool = True, name: str | None = None) -> Track:
    """Load and validate a DeepRacer ``.npy`` route file (its size is checked before it is read)."""
    path = Path(path)
    array = read_route_file(path)
    return track_from_route(array, name or path.stem, source=str(path), remove_repeats=remove_repeats)
