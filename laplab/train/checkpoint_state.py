"""A training job's checkpoint state: what a checkpoint and its resume state hold, written and read.

The trainer makes a checkpoint after every iteration (:func:`checkpoint_writer`, :func:`resume_writer`):
the state is copied when it is made and serialised by the function they return, which the model
folder's writer thread calls while training goes on (:mod:`laplab.train.background`).
"""

from __future__ import annotations

import torch

from laplab.agents.learner import Learner
from laplab.train.resume_codec import cpu_copy, pack_state

__all__ = ["checkpoint_writer", "load_checkpoint", "load_weights_only", "merge_resume_state", "resume_writer"]


def checkpoint_writer(learner: Learner, iteration: int, env_steps: int, episodes: int, best_lap_time: float | None):
    """A checkpoint (the learner's weights plus where the job stood), as a function that writes it to
    a path (straight to the file: a camera network's weights are tens of MB). The weights are copied
    now, so the function may run later, on the model folder's writer thread, while training goes on
    (:mod:`laplab.train.background`). Optimizer state and target networks are not in it: see
    :func:`resume_writer`."""
    state = {"learner": cpu_copy(learner.weights_state()), "iteration": iteration, "env_steps": env_steps,
             "episodes": episodes, "best_lap_time": best_lap_time}
    return lambda path: torch.save(state, path)


def resume_writer(learner: Learner):
    """What ``--resume`` needs beyond a checkpoint's weights (optimizers, target networks), as a
    function writing it to a path; kept for the last checkpoint only (:func:`merge_resume_state`). The
    state is copied now and compressed when the function runs (see :func:`checkpoint_writer`)."""
    weights = learner.weights_state()
    extra = cpu_copy({key: value for key, value in learner.state_dict().items() if key not in weights})
    return lambda path: torch.save({"learner": pack_state(extra)}, path)  # Adam's moments, compressed exactly


def merge_resume_state(state: dict, resume: dict | None) -> dict:
    """A checkpoint's state with its resume state (from :func:`resume_writer`) folded in."""
    if not resume:
        return state
    return {**state, "learner": {**state["learner"], **resume.get("learner", {})}}


def load_weights_only(learner: Learner, state: dict) -> None:
    """Start ``learner`` from the network weights in ``state`` (a clone: fresh optimizer, new
    hyperparameters, schedules from zero)."""
    learner.load_weights(state)


def load_checkpoint(path) -> dict:
    """Read a checkpoint written by :func:`checkpoint_writer`."""
    return torch.load(path, map_location="cpu", weights_only=True)  # tensors and plain data only: no code runs
