"""The listener that keeps a training job in its model folder (deepracer-for-cloud's layout).

It writes what deepracer-utils reads (``training-simtrace/<k>-iteration.csv``, ``TrainingMetrics.json``,
checkpoints with ``deepracer_checkpoints.json``), laplab's per-iteration log and ``error.txt``;
:class:`RobomakerLogRecorder` writes the robomaker-format log the community's log tools parse.
"""

from __future__ import annotations

import numpy as np

from laplab.store.atomic import atomic_write_json, read_json
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import ModelFolder
from laplab.store.metrics import TrainingMetricsWriter
from laplab.store.robomaker_log import RobomakerLogWriter, robomaker_log_path
from laplab.store.simtrace import SimtraceWriter, compile_renderer
from laplab.train.events import CheckpointReady, IterationEpisodes, IterationReport


class ModelFolderRecorder:
    """Writes a job's events into ``folder``. ``iteration`` and ``episodes``: where the job starts
    (a resumed job: its checkpoint's), so records written after that checkpoint by a job that was
    killed are dropped and rewritten. ``workers`` > 1 (rollout workers on Ray) switches the folder to
    deepracer-for-cloud's multi-worker layout: each worker's training simtrace under
    ``<worker>/training-simtrace/``; a folder once in that layout stays in it."""

    def __init__(self, folder: ModelFolder, iteration: int = 0, episodes: int = 0, workers: int = 1):
        self.folder = folder
        self.checkpoints = CheckpointStore(folder)
        self.per_worker = workers > 1 or bool(folder.simtrace_workers())
        if self.per_worker:
            _use_worker_layout(folder)
        if iteration > 0 or episodes > 0:
            self._drop_records_after(iteration, episodes)
        self.metrics = TrainingMetricsWriter(folder.training_metrics)
        self._iteration_rows = self._read_iteration_log(iteration)

    def prepare(self) -> None:
        """Compile the simtrace renderer (seconds on a cold numba cache), on the writer thread as the job
        starts (:class:`laplab.train.background.BackgroundListeners`), before the first iteration's rows."""
        compile_renderer()

    @property
    def iterations_log(self):
        """laplab's per-iteration log (losses, entropy, rates), beside DeepRacer's metrics."""
        return self.folder.metrics_dir / "laplab-iterations.json"

    def _drop_records_after(self, iteration: int, episodes: int) -> None:
        """A job killed between writing an iteration's logs and its checkpoint left logs of an
        iteration the checkpoint does not have: remove them so the resumed job rewrites them."""
        for k in self.folder.list_training_iterations():
            if k >= iteration:
                for path in self.folder.training_simtrace_files(k):
                    path.unlink()
        path = self.folder.training_metrics
        if path.exists():
            data = read_json(path)
            # Rows of later iterations carry larger episode numbers (evaluation rows carry the last
            # training episode of their iteration), so this keeps exactly the checkpoint's history.
            data["metrics"] = [row for row in data.get("metrics", []) if int(row.get("episode", 0)) <= episodes]
            atomic_write_json(path, data, indent=None)

    def _read_iteration_log(self, iteration: int) -> list[dict]:
        """The log's rows up to the checkpoint this job starts from (read once, kept in memory)."""
        path = self.iterations_log
        rows = read_json(path)["iterations"] if path.exists() else []
        return [r for r in rows if r["iteration"] <= iteration]

    def on_episodes(self, episodes: IterationEpisodes) -> None:
        # deepracer-for-cloud numbers simtrace files from 0: iteration k (1-based) -> (k-1)-iteration.csv
        if self.per_worker:
            self._write_worker_simtraces(episodes)
        else:
            with SimtraceWriter(self.folder.training_simtrace(episodes.iteration - 1), fsync=False) as writer:
                writer.write_rows(episodes.training_trace())
        for append, b in ((self.metrics.append_training, episodes.training),
                          (self.metrics.append_evaluation, episodes.evaluation)):
            append(reward_score=b.total_reward, start_time=np.zeros(len(b.status)), metric_time=b.duration,
                   completion_percentage=b.progress, episode_status=b.status_names())

    def _write_worker_simtraces(self, episodes: IterationEpisodes) -> None:
        trace = episodes.training_trace()
        batch = episodes.training
        owner = getattr(batch, "worker", None)
        local_episode = np.asarray(batch.trace["episode"])
        row_worker = np.zeros(len(local_episode), np.int64) if owner is None else np.asarray(owner)[local_episode]
        for worker in np.unique(row_worker).tolist():
            keep = row_worker == worker
            path = self.folder.worker_training_simtrace(int(worker), episodes.iteration - 1)
            path.parent.mkdir(parents=True, exist_ok=True)
            with SimtraceWriter(path, fsync=False) as writer:
                writer.write_rows({k: np.asarray(v)[keep] for k, v in trace.items()})

    def on_checkpoint(self, checkpoint: CheckpointReady) -> None:
        self.checkpoints.save(checkpoint.write, iteration=checkpoint.iteration, steps=checkpoint.env_steps,
                              metric=checkpoint.metric, lap_time=checkpoint.lap_time,
                              resume=checkpoint.write_resume)

    def on_iteration(self, report: IterationReport) -> None:
        self._iteration_rows.append(report.to_dict())
        atomic_write_json(self.iterations_log, {"iterations": self._iteration_rows}, indent=None)

    def on_error(self, message: str) -> None:
        self.folder.write_error(message)


def _use_worker_layout(folder: ModelFolder) -> None:
    """Move single-worker simtrace files (a job that ran with one worker before) to worker 0's
    folder and remove the top-level ``training-simtrace/``: deepracer-utils takes a folder that has
    one for a single-worker model and would not see the workers' files."""
    top = folder.training_simtrace_dir
    worker_zero = folder.worker_training_simtrace_dir(0)
    worker_zero.mkdir(parents=True, exist_ok=True)
    if top.is_dir():
        for path in top.iterdir():
            path.replace(worker_zero / path.name)
        top.rmdir()


class RobomakerLogRecorder:
    """Writes ``logs/training/<time>-robomaker.log`` (one per job run) for deepracer-utils'
    ``load_robomaker_logs`` and deepracer-log-guru: an iteration's lines are written when its report
    (with the losses of the policy update) arrives."""

    def __init__(self, folder: ModelFolder, config):
        hyperparameters = config.hyper()
        self.learning_rate = hyperparameters.lr
        self.writer = RobomakerLogWriter(robomaker_log_path(folder.root), hyperparameters.to_dict(),
                                         config.model_metadata.to_dict(), str(config.track))
        self._episodes: IterationEpisodes | None = None

    def on_episodes(self, episodes: IterationEpisodes) -> None:
        self._episodes = episodes

    def on_iteration(self, report: IterationReport) -> None:
        episodes, self._episodes = self._episodes, None
        if episodes is None or episodes.iteration != report.iteration:
            return
        steps_before = report.env_steps - episodes.training.env_steps
        self.writer.write_iteration(episodes.iteration - 1, episodes.training_trace(), episodes.training,
                                    episodes.evaluation, episodes.first_episode, steps_before, report.losses,
                                    self.learning_rate)
