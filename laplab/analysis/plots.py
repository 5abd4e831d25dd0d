"""Report figures (matplotlib Agg, no pyplot state): each function draws one PNG and returns its path.

Inputs are the arrays of :mod:`laplab.analysis.loaders`; nothing here reads the model folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from laplab.analysis.loaders import Trace, TrainingHistory
from laplab.track.geometry import Track
from laplab.track.plot import draw_track

# Loss curves in the order a PPO user reads them; other reported entries follow alphabetically.
PREFERRED_LOSSES = ("entropy", "policy_loss", "value_loss", "approx_kl", "actor_loss", "critic_loss",
                    "clip_fraction", "explained_variance", "q_mean")
OFF_TRACK_STATUSES = ("off_track", "crashed", "reversed", "immobilized")


@dataclass(frozen=True)
class PlotStyle:
    """Figure settings. dpi: pixels per inch of the PNGs; track_figure_width: inches of a track figure;
    speed_cmap: colours of speeds; reward_cmap: colours of the reward map; heat_cells_across: reward-map
    cells across the road's nominal width; heat_min_visits: steps a cell needs to be coloured;
    max_trajectory_points: rows drawn per trajectory figure (the rest subsampled);
    moving_average_window: most iterations averaged by the trailing moving averages."""

    dpi: int = 100
    track_figure_width: float = 10.0
    speed_cmap: str = "plasma"
    reward_cmap: str = "viridis"
    heat_cells_across: float = 5.0
    heat_min_visits: int = 3
    max_trajectory_points: int = 40_000
    moving_average_window: int = 10


def _save(figure: Figure, path: Path, style: PlotStyle) -> Path:
    for ax in figure.axes:  # a legend without entries is a bare box: drop it
        legend = ax.get_legend()
        if legend is not None and not legend.get_texts():
            legend.remove()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=style.dpi, bbox_inches="tight")
    return path


def _track_figure(track: Track, style: PlotStyle, colorbar: bool = True) -> tuple[Figure, Axes]:
    points = np.vstack([track.inner, track.outer])
    span = np.maximum(points.max(axis=0) - points.min(axis=0), 1e-3)
    width = style.track_figure_width
    height = float(np.clip(width * span[1] / span[0] * (0.85 if colorbar else 1.0), 3.5, 1.4 * width)) + 0.8
    figure = Figure(figsize=(width, height))
    ax = figure.add_subplot()
    draw_track(ax, track)
    return figure, ax


def _line(ax: Axes, x: np.ndarray, y: np.ndarray, **kwargs) -> None:
    """A line that stays visible with a single point (markers when there are few points)."""
    marker = "o" if np.isfinite(y).sum() <= 12 else None
    ax.plot(x, y, marker=marker, markersize=3.5, **kwargs)


# ------------------------------------------------------------------------------------ training


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Mean of the finite values among the last ``window`` entries at each index (NaN where there are
    none); shape (I,)."""
    values = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(values)
    sums = np.cumsum(np.where(finite, values, 0.0))
    counts = np.cumsum(finite)
    window = max(int(window), 1)
    sums[window:] = sums[window:] - sums[:-window].copy()
    counts[window:] = counts[window:] - counts[:-window].copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


def _window(iterations: int, style: PlotStyle) -> int:
    """Moving-average window: about a fifth of the run, at least 2, at most the style's."""
    return int(np.clip(iterations // 5, 2, max(style.moving_average_window, 2)))


def plot_training(history: TrainingHistory, path: Path, style: PlotStyle = PlotStyle()) -> Path:
    """Reward, progress, lap-completion rate and lap times per iteration (2 x 2 panels)."""
    figure = Figure(figsize=(12, 7.5))
    axes = figure.subplots(2, 2, sharex=True)
    x, window = history.iteration, _window(history.size, style)
    episodes = history.episodes
    train = episodes.training if episodes is not None else None
    for ax, values, per_episode, title, unit in (
            (axes[0, 0], history.mean_reward, None if episodes is None else episodes.reward, "total reward per episode", ""),
            (axes[0, 1], history.mean_progress, None if episodes is None else episodes.progress, "progress per episode", " (%)")):
        if per_episode is not None and train.any():
            ax.scatter(episodes.iteration[train], per_episode[train], s=6, color="0.65", alpha=0.5,
                       linewidths=0, label="training episodes")
        _line(ax, x, values, color="#1f77b4", lw=1.0, alpha=0.8, label="iteration mean")
        ax.plot(x, moving_average(values, window), color="#d62728", lw=2.2, label=f"moving average ({window} it.)")
        ax.set_title(title)
        ax.set_ylabel(title.split(" per")[0] + unit)
    _line(axes[0, 1], x, history.eval_progress, color="#2ca02c", lw=1.6, label="evaluation laps (greedy)")
    axes[0, 1].set_ylim(-3, 103)
    ax = axes[1, 0]
    _line(ax, x, 100 * history.completion_rate, color="#1f77b4", lw=1.0, alpha=0.8, label="training episodes")
    ax.plot(x, 100 * moving_average(history.completion_rate, window), color="#d62728", lw=2.2,
            label=f"training, moving average ({window} it.)")
    _line(ax, x, 100 * history.eval_completion_rate, color="#2ca02c", lw=1.6, label="evaluation laps (greedy)")
    ax.set_ylim(-3, 103)
    ax.set_title("lap-completion rate")
    ax.set_ylabel("laps completed (%)")
    ax = axes[1, 1]
    if episodes is not None:
        laps = train & episodes.lap_complete
        if laps.any():
            ax.scatter(episodes.iteration[laps], episodes.elapsed_s[laps], s=8, color="0.55", alpha=0.6,
                       linewidths=0, label="training laps")
    if np.isfinite(history.eval_lap_time).any():
        _line(ax, x, history.eval_lap_time, color="#2ca02c", lw=1.6, label="evaluation laps (mean)")
    ax.set_title("lap time of completed laps")
    ax.set_ylabel("lap time (s)")
    if not ax.has_data():
        ax.text(0.5, 0.5, "no completed lap yet", ha="center", va="center", transform=ax.transAxes, color="0.4")
    for ax in axes.flat:
        ax.grid(alpha=0.3)
        if ax.has_data() and ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="best")
    for ax in axes[1]:
        ax.set_xlabel("iteration")
    figure.tight_layout()
    return _save(figure, path, style)


def plot_losses(history: TrainingHistory, path: Path, style: PlotStyle = PlotStyle()) -> Path:
    """One panel per learner statistic (entropy, policy / value loss, approx_kl, ...), 3 per row."""
    names = [n for n in PREFERRED_LOSSES if n in history.losses]
    names += sorted(n for n in history.losses if n not in names)
    columns = 3
    rows = max(1, -(-len(names) // columns))
    figure = Figure(figsize=(12, 3.0 * rows))
    axes = np.atleast_1d(figure.subplots(rows, columns, sharex=True, squeeze=False)).reshape(-1)
    x, window = history.iteration, _window(history.size, style)
    for ax, name in zip(axes, names):
        values = history.losses[name]
        _line(ax, x, values, color="#1f77b4", lw=1.0, alpha=0.7)
        ax.plot(x, moving_average(values, window), color="#d62728", lw=2.0)
        finite = values[np.isfinite(values)]
        if finite.size and finite.min() > 0 and finite.max() / finite.min() > 100:
            ax.set_yscale("log")
        ax.set_title(name.replace("_", " "))
        ax.grid(alpha=0.3)
    for ax in axes[len(names):]:
        ax.set_axis_off()
    for ax in axes[max(0, len(names) - columns):len(names)]:
        ax.set_xlabel("iteration")
    if not names:
        axes[0].text(0.5, 0.5, "the trainer reported no losses", ha="center", va="center", color="0.4")
    figure.tight_layout()
    return _save(figure, path, style)


# -------------------------------------------------------------------------------- on the track


def _episode_segments(trace: Trace, max_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Line segments between consecutive (subsampled) rows of the same episode.

    Returns segments (S, 2, 2) m, the mean throttle of each (S,) m/s, and the row index where each
    segment starts (S,)."""
    stride = max(1, -(-trace.size // max(max_points, 2)))
    rows = np.arange(0, trace.size, stride)
    # Keep each episode's last row so off-track ends are drawn where they happened.
    keys = trace.iteration * 10**9 + trace.episode
    ends = np.flatnonzero(np.diff(keys, append=keys[-1] + 1) != 0) if trace.size else np.zeros(0, np.int64)
    rows = np.union1d(rows, ends)
    same = keys[rows[:-1]] == keys[rows[1:]]
    start, stop = rows[:-1][same], rows[1:][same]
    points = np.column_stack([trace.x, trace.y])
    segments = np.stack([points[start], points[stop]], axis=1)
    return segments, 0.5 * (trace.throttle[start] + trace.throttle[stop]), start


def _mark_off_track(ax: Axes, trace: Trace) -> None:
    off = np.isin(trace.status, list(OFF_TRACK_STATUSES))
    if off.any():
        ax.scatter(trace.x[off], trace.y[off], marker="x", s=28, color="#d62728", linewidths=1.5, zorder=8,
                   label="left the track / crashed")


def _speed_norm(speeds: np.ndarray) -> Normalize:
    low, high = (float(speeds.min()), float(speeds.max())) if speeds.size else (0.0, 1.0)
    if high - low < 0.05:
        low, high = low - 0.5, high + 0.5
    return Normalize(low, high)


def plot_trajectories(track: Track, trace: Trace, path: Path, title: str, style: PlotStyle = PlotStyle()) -> Path:
    """Episodes' paths on the track, coloured by the action's speed, with off-track points marked."""
    figure, ax = _track_figure(track, style)
    segments, speeds, _ = _episode_segments(trace, style.max_trajectory_points)
    lines = LineCollection(segments, cmap=style.speed_cmap, norm=_speed_norm(speeds), linewidths=1.1,
                           alpha=0.75, zorder=6)
    lines.set_array(speeds)
    ax.add_collection(lines)
    figure.colorbar(lines, ax=ax, label="speed of the action (m/s)", shrink=0.8)
    _mark_off_track(ax, trace)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(handles=[h for h, l in zip(*ax.get_legend_handles_labels()) if l.startswith("left")],
                  fontsize=8, loc="upper right")
    ax.set_title(title, fontsize=10)
    return _save(figure, path, style)


def reward_map_cell(track: Track, style: PlotStyle = PlotStyle()) -> float:
    """Side of a reward-map cell, m."""
    return track.nominal_width / style.heat_cells_across


def reward_grid(track: Track, trace: Trace, style: PlotStyle = PlotStyle()
                ) -> tuple[np.ndarray, np.ndarray, np.ma.MaskedArray]:
    """Mean step reward on square cells of :func:`reward_map_cell` covering the track.

    Returns the cell edges xs (C + 1,) and ys (R + 1,) in m, and the (R, C) means, masked where a
    cell saw fewer than ``style.heat_min_visits`` steps (rows outside the grid are ignored)."""
    cell_m = reward_map_cell(track, style)
    points = np.vstack([track.inner, track.outer])
    low = points.min(axis=0) - 2 * cell_m
    columns, rows = np.ceil((points.max(axis=0) + 2 * cell_m - low) / cell_m).astype(int)
    column = np.floor((trace.x - low[0]) / cell_m).astype(np.int64)
    row = np.floor((trace.y - low[1]) / cell_m).astype(np.int64)
    inside = (column >= 0) & (column < columns) & (row >= 0) & (row < rows)
    cell = row[inside] * columns + column[inside]
    sums = np.bincount(cell, weights=trace.reward[inside], minlength=rows * columns)
    visits = np.bincount(cell, minlength=rows * columns)
    mean = np.ma.masked_where(visits < style.heat_min_visits, sums / np.maximum(visits, 1))
    xs = low[0] + cell_m * np.arange(columns + 1)
    ys = low[1] + cell_m * np.arange(rows + 1)
    return xs, ys, mean.reshape(rows, columns)


def plot_reward_map(track: Track, trace: Trace, path: Path, title: str, style: PlotStyle = PlotStyle()) -> Path:
    """The :func:`reward_grid` drawn under the track's borders (blank: too few steps there)."""
    figure, ax = _track_figure(track, style)
    xs, ys, mean = reward_grid(track, trace, style)
    mesh = ax.pcolormesh(xs, ys, mean, cmap=style.reward_cmap, zorder=1, shading="flat")
    figure.colorbar(mesh, ax=ax, label="mean reward per step", shrink=0.8)
    ax.set_title(title, fontsize=10)
    return _save(figure, path, style)


def plot_action_usage(trace: Trace, action_space: dict | list, action_space_type: str, path: Path,
                      title: str, style: PlotStyle = PlotStyle()) -> Path:
    """Discrete: steps per action index, labelled ``steer deg / speed m/s``. Continuous: 2-D histogram
    of steering x speed over the space's ranges."""
    figure = Figure(figsize=(10, 4.8))
    ax = figure.add_subplot()
    if action_space_type == "discrete" and trace.action.ndim == 1:
        count = len(action_space)
        valid = (trace.action >= 0) & (trace.action < count)
        usage = np.bincount(trace.action[valid], minlength=count)
        share = 100.0 * usage / max(int(usage.sum()), 1)
        labels = [f"{a.get('steering_angle', 0):g}° / {a.get('speed', 0):g} m/s" for a in action_space]
        bars = ax.bar(np.arange(count), share, color="#1f77b4")
        ax.bar_label(bars, labels=[f"{s:.1f}%" for s in share], fontsize=8, padding=2)
        ax.set_xticks(np.arange(count), [f"{i}\n{label}" for i, label in enumerate(labels)],
                      fontsize=8 if count <= 12 else 6, rotation=0 if count <= 8 else 45)
        ax.set_xlabel("action index / steering angle / speed")
        ax.set_ylabel("share of steps (%)")
        ax.set_ylim(0, max(float(share.max()) * 1.15, 1.0))
    else:
        steer_range = (action_space.get("steering_angle", {}) if isinstance(action_space, dict) else {})
        speed_range = (action_space.get("speed", {}) if isinstance(action_space, dict) else {})
        steer_lim = (float(steer_range.get("low", trace.steer.min(initial=-30))),
                     float(steer_range.get("high", trace.steer.max(initial=30))))
        speed_lim = (float(speed_range.get("low", trace.throttle.min(initial=0))),
                     float(speed_range.get("high", trace.throttle.max(initial=4))))
        share, steer_edges, speed_edges = np.histogram2d(trace.steer, trace.throttle, bins=(31, 21),
                                                         range=(sorted(steer_lim), sorted(speed_lim)))
        share = 100.0 * share / max(share.sum(), 1.0)
        mesh = ax.pcolormesh(steer_edges, speed_edges, np.ma.masked_equal(share.T, 0.0), cmap="magma_r")
        figure.colorbar(mesh, ax=ax, label="share of steps (%)")
        ax.set_xlabel("steering angle (deg, + = left)")
        ax.set_ylabel("speed (m/s)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    figure.tight_layout()
    return _save(figure, path, style)


def plot_evaluation(track: Track, trace: Trace | None, path: Path, title: str,
                    raceline: np.ndarray | None = None, raceline_label: str = "race line",
                    style: PlotStyle = PlotStyle()) -> Path:
    """Each trial's path (one colour per trial) over the race line ``raceline`` (M, 2) m."""
    figure, ax = _track_figure(track, style, colorbar=False)
    if raceline is not None:
        ax.plot(raceline[:, 0], raceline[:, 1], color="#2ca02c", lw=5, alpha=0.35, zorder=5,
                solid_capstyle="round", label=raceline_label)
    if trace is not None and trace.size:
        colours = ["#1f77b4", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f"]
        for index, episode in enumerate(np.unique(trace.episode)):
            rows = trace.episode == episode
            ax.plot(trace.x[rows], trace.y[rows], color=colours[index % len(colours)], lw=1.3, zorder=6,
                    label=f"trial {int(episode) + 1}")
        _mark_off_track(ax, trace)
    handles, labels = ax.get_legend_handles_labels()
    wanted = [i for i, label in enumerate(labels) if label.startswith(("trial", "race", "left"))]
    if wanted:
        ax.legend([handles[i] for i in wanted], [labels[i] for i in wanted], fontsize=8, loc="upper right")
    ax.set_title(title, fontsize=10)
    return _save(figure, path, style)


def iteration_range_text(iterations: Sequence[int]) -> str:
    """``"iteration 7"`` or ``"iterations 3-7"``."""
    values = sorted(int(i) for i in iterations)
    if not values:
        return "no iteration"
    return f"iteration {values[0]}" if values[0] == values[-1] else f"iterations {values[0]}-{values[-1]}"
