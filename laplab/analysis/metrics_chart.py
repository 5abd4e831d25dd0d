"""DeepRacer's training chart from ``TrainingMetrics.json`` rows: what the console's reward graph and
the SageMaker notebook's metrics cell show, drawn while a job runs.

Input: the rows of ``metrics/TrainingMetrics.json`` (DeepRacer's keys: ``phase``, ``episode``,
``reward_score``, ``completion_percentage``); output: a matplotlib Figure (no pyplot state).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from laplab.analysis.plots import moving_average


def _column(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    return np.array([float(row.get(key, np.nan)) for row in rows], dtype=np.float64)


def training_metrics_figure(rows: list[dict[str, Any]], title: str = "", window: int = 20) -> Figure:
    """Two panels over training episodes: reward per episode with its moving average over ``window``
    episodes; training progress (%) per episode with its moving average and the evaluation laps'
    progress (%). Before the first iteration the panels say that nothing is in yet."""
    figure = Figure(figsize=(11, 4.2))
    reward_ax, progress_ax = figure.subplots(1, 2)
    training = [row for row in rows if row.get("phase", "training") == "training"]
    evaluation = [row for row in rows if row.get("phase") == "evaluation"]
    if not training:
        for ax in (reward_ax, progress_ax):
            ax.text(0.5, 0.5, "no episodes yet: the first iteration is still collecting",
                    ha="center", va="center", transform=ax.transAxes, color="0.4")
    else:
        episode = _column(training, "episode")
        reward, progress = _column(training, "reward_score"), _column(training, "completion_percentage")
        reward_ax.scatter(episode, reward, s=6, color="0.6", alpha=0.6, linewidths=0, label="episode")
        reward_ax.plot(episode, moving_average(reward, window), color="#d62728", lw=2,
                       label=f"moving average ({window} episodes)")
        progress_ax.scatter(episode, progress, s=6, color="0.6", alpha=0.6, linewidths=0, label="training episode")
        progress_ax.plot(episode, moving_average(progress, window), color="#d62728", lw=2,
                         label=f"training, moving average ({window})")
        if evaluation:  # an iteration's evaluation laps share its last episode number: one mean each
            at, laps = _column(evaluation, "episode"), _column(evaluation, "completion_percentage")
            iterations = np.unique(at)
            means = np.array([laps[at == episode].mean() for episode in iterations])
            progress_ax.plot(iterations, means, "o-", color="#2ca02c", ms=3.5, lw=1.4,
                             label="evaluation laps (mean per iteration)")
        for ax in (reward_ax, progress_ax):
            ax.legend(loc="upper left", fontsize=8)
    reward_ax.set(title="reward per episode", xlabel="training episode", ylabel="total reward")
    progress_ax.set(title="progress per episode", xlabel="training episode", ylabel="progress (%)", ylim=(-3, 103))
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    return figure
