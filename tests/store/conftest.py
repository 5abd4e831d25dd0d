"""Synthetic simtrace rows shared by the store tests."""

import numpy as np
import pytest


def make_simtrace_columns(first_episode: int, episode_lengths, continuous: bool, seed: int = 0):
    """Columns for consecutive episodes starting at `first_episode`; each episode's last step
    is done (off_track, or lap_complete for the longest)."""
    rng = np.random.default_rng(seed)
    lengths = np.asarray(episode_lengths)
    n_rows = int(lengths.sum())
    episode = np.repeat(np.arange(first_episode, first_episode + len(lengths)), lengths)
    starts = np.repeat(np.cumsum(lengths) - lengths, lengths)
    steps = np.arange(n_rows) - starts + 1
    done = steps == np.repeat(lengths, lengths)
    status = np.where(done, "off_track", "in_progress").astype(object)
    status[done & (np.repeat(lengths, lengths) == lengths.max())] = "lap_complete"
    action = rng.uniform([-30.0, 0.5], [30.0, 4.0], (n_rows, 2)) if continuous else rng.integers(0, 5, n_rows)
    return {
        "episode": episode,
        "steps": steps,
        "X": rng.uniform(-5, 5, n_rows),
        "Y": rng.uniform(-5, 5, n_rows),
        "yaw": rng.uniform(-180, 180, n_rows),
        "steer": action[:, 0] if continuous else rng.choice([-30.0, 0.0, 30.0], n_rows),
        "throttle": action[:, 1] if continuous else rng.choice([1.0, 2.0], n_rows),
        "action": action,
        "reward": rng.uniform(0, 2, n_rows),
        "done": done,
        "all_wheels_on_track": ~done,
        "progress": 100.0 * steps / lengths.max(),
        "closest_waypoint": rng.integers(0, 120, n_rows),
        "track_len": np.full(n_rows, 17.71),
        "tstamp": 10.0 + np.arange(n_rows) / 15.0,
        "episode_status": status.astype(str),
    }


@pytest.fixture
def simtrace_columns():
    return make_simtrace_columns
