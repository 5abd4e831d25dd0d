"""Top-down track drawings (matplotlib, no pyplot state): borders, centre line, start line, direction.

:func:`draw_track` draws onto any axes, so reports can overlay race lines or trajectories on the same
axes; :func:`plot_track` makes a figure, draws and saves it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
from matplotlib import patheffects
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import PathPatch
from matplotlib.path import Path as MplPath

from laplab.track.geometry import Track, centerline_normals


@dataclass(frozen=True)
class TrackPlotStyle:
    """Colours and sizes of a track drawing; ``metres_per_inch`` sets the figure size of a new figure."""

    road_color: str = "#d9d9d9"
    border_color: str = "#303030"
    centerline_color: str = "#e6a100"
    start_color: str = "#c00000"
    arrow_color: str = "#1f5fbf"
    border_width_pt: float = 1.4
    centerline_width_pt: float = 1.0
    num_arrows: int = 12
    index_font_size: float = 5.0
    metres_per_inch: float = 1.2
    max_figure_inches: float = 16.0
    dpi: int = 150


class TrackFigure(NamedTuple):
    """What :func:`plot_track` made: the saved file (None when not saved) and the axes drawn on."""

    path: Path | None
    ax: Axes


def draw_track(ax: Axes, track: Track, show_indices: bool = False,
               style: TrackPlotStyle = TrackPlotStyle()) -> Axes:
    """Draw ``track`` on ``ax`` in world metres (equal aspect) and return ``ax``.

    Road surface between the borders, both borders, the centre line dashed, the start line across the
    road at waypoint 0, ``style.num_arrows`` arrows in the driving direction along the centre line, and
    with ``show_indices`` each waypoint's index (the rows of ``track.centerline``, closing row left out).
    """
    # Matplotlib fills with the non-zero winding rule: the inner ring, run the opposite way round
    # from the outer one, cuts the infield out of the road surface.
    ring_outer, ring_inner = track.outer, track.inner[::-1]
    vertices = np.vstack([ring_outer, ring_inner])
    codes = np.full(vertices.shape[0], MplPath.LINETO, dtype=np.uint8)
    codes[0] = codes[ring_outer.shape[0]] = MplPath.MOVETO
    ax.add_patch(PathPatch(MplPath(vertices, codes), facecolor=style.road_color, edgecolor="none",
                           zorder=0, label="_road"))
    for border, label in ((track.inner, "inner border"), (track.outer, "outer border")):
        ax.plot(border[:, 0], border[:, 1], color=style.border_color, lw=style.border_width_pt,
                zorder=2, label=label)
    centre = track.centerline
    ax.plot(centre[:, 0], centre[:, 1], color=style.centerline_color, lw=style.centerline_width_pt,
            ls=(0, (5, 3)), zorder=3, label="centre line")
    _draw_start_line(ax, track, style)
    _draw_direction_arrows(ax, track, style)
    if show_indices:
        _draw_indices(ax, track, style)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{track.name}: {track.length:.2f} m, {track.nominal_width:.3f} m wide, "
                 f"{track.direction}, {track.num_waypoints} waypoints", fontsize=9)
    return ax


def plot_track(track: Track, path: str | Path | None, show_indices: bool = False, ax: Axes | None = None,
               style: TrackPlotStyle = TrackPlotStyle()) -> TrackFigure:
    """Draw ``track`` (on ``ax``, else on a new figure sized to the track) and save the figure to ``path``
    (PNG, or any format matplotlib infers from the suffix) unless ``path`` is None.

    Returns ``TrackFigure(path, ax)``; draw more on ``ax`` and save ``ax.figure`` again to overlay lines.
    """
    if ax is None:
        ax = Figure(figsize=_figure_inches(track, style), dpi=style.dpi).add_subplot()
    draw_track(ax, track, show_indices=show_indices, style=style)
    if path is None:
        return TrackFigure(None, ax)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ax.figure.savefig(path, dpi=style.dpi, bbox_inches="tight")
    return TrackFigure(path, ax)


def _figure_inches(track: Track, style: TrackPlotStyle) -> tuple[float, float]:
    points = np.vstack([track.inner, track.outer])
    span = np.maximum(points.max(axis=0) - points.min(axis=0), 1e-3)
    scale = min(1.0 / style.metres_per_inch, style.max_figure_inches / float(span.max()))
    width, height = np.maximum(span * scale, 3.0) + np.array([1.2, 1.0])  # room for axis labels
    return float(width), float(height)


def _draw_start_line(ax: Axes, track: Track, style: TrackPlotStyle) -> None:
    normal = centerline_normals(track.centerline)[0]  # unit left normal at waypoint 0
    centre = track.centerline[0]
    ends = np.stack([centre + normal * track.left_width[0], centre - normal * track.right_width[0]])
    ax.plot(ends[:, 0], ends[:, 1], color=style.start_color, lw=2.5, solid_capstyle="butt",
            zorder=5, label="start line")


def _draw_direction_arrows(ax: Axes, track: Track, style: TrackPlotStyle) -> None:
    count = max(1, style.num_arrows)
    s = (np.arange(count) + 0.5) * track.length / count
    points = track.point_at(s)
    heading = track.heading_at(s)
    size = 0.5 * track.nominal_width  # m: arrow length, half the road
    ax.quiver(points[:, 0], points[:, 1], np.cos(heading) * size, np.sin(heading) * size,
              angles="xy", scale_units="xy", scale=1.0, color=style.arrow_color, width=0.004,
              zorder=4, label="driving direction")


def _draw_indices(ax: Axes, track: Track, style: TrackPlotStyle) -> None:
    centre = track.centerline[:-1]
    ax.scatter(centre[:, 0], centre[:, 1], s=3, color=style.border_color, zorder=6, linewidths=0)
    # Labels sit on alternate sides of the centre line so neighbours do not overlap.
    normals = centerline_normals(track.centerline)[:-1]
    side = np.where(np.arange(centre.shape[0]) % 2 == 0, 1.0, -1.0)[:, None]
    anchors = centre + normals * side * 0.18 * track.nominal_width
    halo = [patheffects.withStroke(linewidth=1.5, foreground="white")]  # readable over lines
    for index, (x, y) in enumerate(anchors):
        ax.text(x, y, str(index), fontsize=style.index_font_size, ha="center", va="center", zorder=7,
                path_effects=halo)
