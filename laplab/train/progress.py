"""A terminal progress display for training jobs (a trainer callback and listener)."""

from __future__ import annotations

import time

from rich.console import Console

from laplab.train.events import PhaseProgress
from laplab.train.trainer import IterationReport, Trainer, TrainResult

PHASE_LINE_INTERVAL_S = 5.0  # between iteration rows, a line on the running phase at most this often
_PHASES = {"collect": ("collecting", "episodes"), "learn": ("learning", "gradient steps"),
           "evaluate": ("evaluating", "laps")}

_HEADER = (f"{'iter':>5} {'episodes':>8} {'steps':>8} {'reward':>9} {'progress':>8} {'laps %':>6} "
           f"{'eval':>9} {'best lap':>9} {'steps/s':>8} {'left':>6}")


def _clock(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60}:{seconds % 60:02d}"


class ProgressPrinter:
    """Prints one row per iteration: iteration, episodes, steps, mean reward and progress, % of
    episodes that lapped, evaluation laps completed, best lap so far, env steps/s, time left; and,
    while an iteration runs, a line on its phase (episodes collected / num_episodes_between_training,
    then gradient steps) when nothing was printed for ``PHASE_LINE_INTERVAL_S`` (the first at once).
    It subscribes itself to ``trainer`` for those (:class:`laplab.train.events.PhaseProgress`).
    ``location``: where the summary says the model is (an object store's URL; None: the model folder)."""

    def __init__(self, console: Console, trainer: Trainer, quiet: bool = False, location: str | None = None):
        self.console, self.trainer, self.quiet = console, trainer, quiet
        self.location = location
        self._printed_header = False
        self._last_line = float("-inf")
        trainer.subscribe(self)
        if not quiet:
            cfg = trainer.config
            meta = trainer.metadata
            console.print(f"training [bold]{trainer.folder.name}[/bold] on {cfg.track} with "
                          f"{meta.training_algorithm}, sensors {'+'.join(meta.sensors)}, "
                          f"{meta.action_space.kind} actions; stop after {_clock(cfg.max_time_s)} "
                          f"or {cfg.episode_limit} episodes. Ctrl-C stops and keeps the model.")

    def on_progress(self, progress: PhaseProgress) -> None:
        now = time.monotonic()
        if self.quiet or progress.phase not in _PHASES or now - self._last_line < PHASE_LINE_INTERVAL_S:
            return
        self._last_line = now
        verb, unit = _PHASES[progress.phase]
        of = f"{progress.done}/{progress.total}" if progress.total else "starting"
        steps = f", {progress.env_steps} env steps" if progress.env_steps else ""
        self.console.print(f"  iteration {progress.iteration}: {verb}, {unit} {of}{steps} "
                           f"({_clock(progress.elapsed_s)} elapsed)", style="dim")

    def __call__(self, report: IterationReport) -> None:
        if self.quiet:
            return
        self._last_line = time.monotonic()
        if not self._printed_header:
            self.console.print(_HEADER, style="bold")
            self._printed_header = True
        best = f"{report.best_lap_time:.3f}s" if report.best_lap_time else "-"
        evaluated = "  -" if report.eval_progress is None else f"{report.eval_progress:3.0f}"
        self.console.print(
            f"{report.iteration:5d} {report.episodes:8d} {report.env_steps:8d} {report.mean_reward:9.2f} "
            f"{report.mean_progress:7.1f}% {100 * report.completion_rate:5.0f}% "
            f"{report.eval_completed:>3d}/{report.eval_episodes:<1d} {evaluated}% "
            f"{best:>9} {report.steps_per_second:8.0f} {_clock(report.time_left_s):>6}"
            + ("  (cut short by the time limit: not evaluated)" if report.partial else ""))

    def summary(self, result: TrainResult) -> None:
        reasons = {"max_time": "reached the time limit", "max_episodes": "reached the episode limit",
                   "avg_score": "reached the average score", "stopped": "stopped on request",
                   "reward_error": "stopped: the reward function failed"}
        best = f"{result.best_lap_time:.3f} s" if result.best_lap_time else "none yet"
        self.console.print(f"{self.trainer.folder.name}: {reasons.get(result.stop_reason, result.stop_reason)} after "
                           f"{result.iterations} iterations, {result.episodes} episodes, {result.env_steps} steps "
                           f"in {_clock(result.elapsed_s)}; best lap {best}. "
                           f"Model: {self.location or self.trainer.folder.root}")
        if result.error:
            self.console.print(f"[red]reward function error[/red] (also in {self.trainer.folder.error_file}):")
            self.console.print(result.error, markup=False)
