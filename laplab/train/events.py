"""What a training job reports, and the interface of those who listen.

The :class:`~laplab.train.trainer.Trainer` knows nothing of files, terminals or web pages: it hands
these events to its listeners (:meth:`Trainer.subscribe`). The model folder's files are written by one
listener (:class:`laplab.train.recorder.ModelFolderRecorder`); a terminal display, a web console or an
object store are others. A listener implements any subset of the ``on_*`` methods of
:class:`TrainerListener`; they run in the trainer's thread, in subscription order, and should return
quickly (``on_poses`` runs after every simulation step of the collection and of the evaluation laps).
Listeners that write files are wrapped in :class:`laplab.train.background.BackgroundListeners`, which
hands their events to one writer thread; the trainer waits for a listener's ``wait()`` (when it has
one) at the end of each run, so events must not change after they are handed over.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Protocol

import numpy as np


@dataclass
class IterationReport:
    """What one iteration did; handed to every callback."""

    iteration: int
    episodes: int  # training episodes so far
    env_steps: int  # training steps so far
    mean_reward: float
    mean_progress: float
    completion_rate: float  # fraction of this iteration's training episodes that lapped
    eval_progress: float | None  # mean progress of the greedy evaluation laps, %; None: not evaluated
    eval_completed: int
    eval_episodes: int
    best_lap_time: float | None  # best lap (training or evaluation) so far, s
    eval_lap_time: float | None  # mean lap time of this iteration's completed evaluation laps
    steps_per_second: float  # env steps per wall second this iteration (collection + training)
    elapsed_s: float
    time_left_s: float
    losses: dict[str, float] = field(default_factory=dict)
    # wall seconds of this iteration spent collecting episodes, learning, on evaluation laps and on
    # handing the results to the listeners (writing logs and the checkpoint)
    seconds: dict[str, float] = field(default_factory=dict)
    # mean progress of the evaluation laps per track of a multi-track job ({} with one track)
    eval_progress_by_track: dict[str, float] = field(default_factory=dict)
    # the time limit or a stop request cut this iteration's learning or evaluation short: the checkpoint
    # holds the (partly) trained networks, unevaluated (eval_episodes is 0)
    partial: bool = False

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON values: a figure that is not a number (the losses of an iteration whose
        learning the time limit cut before its first minibatch are NaN) becomes None (JSON null)."""
        return _finite_or_none(asdict(self))


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@dataclass(frozen=True)
class IterationEpisodes:
    """The episodes of iteration ``iteration`` (1-based): ``training`` and ``evaluation`` are
    :class:`laplab.train.collect.EpisodeBatch` objects; ``first_episode`` counts the training episodes
    of the job before this iteration (simtrace episode numbers continue from it)."""

    iteration: int
    first_episode: int
    training: Any
    evaluation: Any

    def training_trace(self) -> dict[str, np.ndarray]:
        """The training episodes' simtrace columns, episodes numbered across the whole job."""
        trace = dict(self.training.trace)
        trace["episode"] = trace["episode"] + self.first_episode
        return trace


@dataclass(frozen=True)
class CheckpointReady:
    """A checkpoint to keep: ``write(path)`` writes it (the networks' weights; straight to the file: a
    camera network is tens of MB); ``write_resume(path)``, when given, writes what resuming from it
    needs besides (optimizer state, target networks), kept for the last checkpoint only. ``metric``:
    mean progress of the iteration's evaluation laps (None for checkpoint 0 and a partial iteration);
    ``lap_time``: their mean lap time when all of them lapped."""

    iteration: int
    env_steps: int
    episodes: int
    metric: float | None
    lap_time: float | None
    write: Callable[[Any], None]
    write_resume: Callable[[Any], None] | None = None


@dataclass(frozen=True)
class PhaseProgress:
    """Where a running iteration stands, sent about once a second: ``phase`` is ``"collect"``
    (``done`` / ``total`` episodes of the iteration's ``num_episodes_between_training``, ``env_steps``
    driven so far in it), ``"learn"`` (``done`` / ``total`` gradient steps or minibatches; ``total`` 0
    before the first) or ``"evaluate"`` (greedy evaluation laps done / run);
    ``elapsed_s``: wall seconds since the job started."""

    iteration: int
    phase: str
    done: int
    total: int
    env_steps: int
    elapsed_s: float


@dataclass(frozen=True)
class PosesFrame:
    """The cars of the collection after one step: ``poses`` (N, 3) x m, y m, yaw rad of the model
    origins, and ``sim_time`` (s since this iteration's collection began); ``evaluation``: the cars are
    the iteration's evaluation laps (greedy policy), not its training episodes; ``obstacles``: each
    car's race obstacles (a :class:`laplab.sim.obstacles.Obstacles` of (N, K) arrays: boxes, bots),
    None in a time trial; ``obstacles_move``: they drive (head-to-bot's bots), else they stand."""

    iteration: int
    poses: np.ndarray
    sim_time: float
    evaluation: bool = False
    obstacles: Any = None
    obstacles_move: bool = False


class TrainerListener(Protocol):
    """Every method is optional; see the module docstring."""

    def on_poses(self, frame: PosesFrame) -> None: ...

    def on_progress(self, progress: PhaseProgress) -> None: ...

    def on_episodes(self, episodes: IterationEpisodes) -> None: ...

    def on_checkpoint(self, checkpoint: CheckpointReady) -> None: ...

    def on_iteration(self, report: IterationReport) -> None: ...

    def on_error(self, message: str) -> None: ...
