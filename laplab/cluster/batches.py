"""Episodes from several rollout workers as one batch for the learner (pure numpy, no Ray).

Each worker returns an :class:`~laplab.train.collect.EpisodeBatch` of its own cars, time-major
(T_w, E_w). :func:`merge_batches` pads every piece to the longest T with ``valid=False`` steps (the
learners already skip steps where a car was not driving) and puts the episodes side by side:
(T, E_0 + E_1 + ...). The merged batch is a :class:`TaggedEpisodeBatch`: it also says, per episode,
which worker drove it, on which track, and with which policy version.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Sequence

import numpy as np

from laplab.train.collect import EpisodeBatch

# Fields of EpisodeBatch that are time-major (T, E, ...): padded with these values past an episode's end.
_TIME_MAJOR = {"actions": 0, "log_probs": 0.0, "values": 0.0, "rewards": 0.0, "terminated": False,
               "truncated": False, "valid": False, "bootstrap_values": 0.0}
_PER_EPISODE = ("total_reward", "progress", "status", "steps", "lap_time", "duration")


@dataclass
class TaggedEpisodeBatch(EpisodeBatch):
    """An :class:`EpisodeBatch` whose episodes (E,) carry ``worker`` (int), ``track`` (the track
    label, e.g. ``reInvent2019_track@reversed``) and ``policy_version`` (int: the learner's version of
    the weights every transition of that episode was acted with)."""

    worker: np.ndarray | None = None
    track: np.ndarray | None = None
    policy_version: np.ndarray | None = None


def _pad_time(array: np.ndarray, length: int, fill) -> np.ndarray:
    extra = length - array.shape[0]
    if extra == 0:
        return np.asarray(array)
    pad = np.full((extra, *array.shape[1:]), fill, dtype=array.dtype)
    return np.concatenate([array, pad])


def _merge_time_major(parts: list, length: int, fill) -> Any:
    if isinstance(parts[0], dict):
        return {k: _merge_time_major([p[k] for p in parts], length, fill) for k in parts[0]}
    return np.concatenate([_pad_time(np.asarray(p), length, fill) for p in parts], axis=1)


def tag(batch: EpisodeBatch, worker: int, track: str, policy_version: int) -> TaggedEpisodeBatch:
    """``batch`` with every episode tagged (no copy of the arrays)."""
    count = len(batch.status)
    values = {f.name: getattr(batch, f.name) for f in fields(EpisodeBatch)}
    return TaggedEpisodeBatch(**values, worker=np.full(count, worker, np.int64),
                              track=np.full(count, track, dtype=object),
                              policy_version=np.full(count, policy_version, np.int64))


def merge_batches(pieces: Sequence[EpisodeBatch]) -> TaggedEpisodeBatch:
    """One batch of the episodes of ``pieces`` in order (episode numbers of the simtrace continue
    from piece to piece); untagged pieces get worker = their index. Always copies (arrays that
    came out of Ray's object store are read-only)."""
    if not pieces:
        raise ValueError("merge_batches needs at least one batch")
    length = max(p.valid.shape[0] for p in pieces)
    merged: dict[str, Any] = {}
    for name, fill in _TIME_MAJOR.items():
        merged[name] = _merge_time_major([getattr(p, name) for p in pieces], length, fill)
    observations = [p.observations for p in pieces]
    merged["observations"] = None if observations[0] is None else _merge_time_major(observations, length, 0)
    for name in _PER_EPISODE:
        merged[name] = np.concatenate([getattr(p, name) for p in pieces])
    trace_parts, offset = [], 0
    for piece in pieces:
        part = dict(piece.trace)
        part["episode"] = np.asarray(part["episode"]) + offset
        trace_parts.append(part)
        offset += len(piece.status)
    merged["trace"] = {k: np.concatenate([p[k] for p in trace_parts]) for k in trace_parts[0]}
    merged["wall_seconds"] = max(p.wall_seconds for p in pieces)

    def tags(name: str, default) -> np.ndarray:
        return np.concatenate([np.asarray(getattr(p, name, None)) if getattr(p, name, None) is not None
                               else np.full(len(p.status), default(i)) for i, p in enumerate(pieces)])
    return TaggedEpisodeBatch(**merged, worker=tags("worker", lambda i: i).astype(np.int64),
                              track=tags("track", lambda i: "").astype(object),
                              policy_version=tags("policy_version", lambda i: -1).astype(np.int64))


def select_rows(columns: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, np.ndarray]:
    """The rows of simtrace ``columns`` where ``mask`` holds."""
    return {k: np.asarray(v)[mask] for k, v in columns.items()}
