"""What a job's rollout workers are doing: a small JSON file in the model folder, and a progress board.

``<model>/logs/workers.json`` lists the workers of the job's current (or last) session, rewritten
(atomically) when something changes: the workers started, one died and was restarted, an
iteration's episodes arrived, the job ended. It is what the console's model page shows::

    {"updated": 1764000000.0, "workers": [{"index": 0, "track": "classic_2018", "state": "alive",
      "host": "node-a", "node_ip": "10.0.0.5", "node_id": "…", "pid": 4242, "actor_id": "…",
      "restarts": 0, "episodes": 40, "iteration": 10, "cause": null}, …]}

``state`` is ``starting``, ``alive``, ``restarting`` (died; a new actor is collecting its share
again), ``dead`` (died too often: the job stopped) or ``stopped`` (the job ended). ``episodes``
counts the episodes the worker delivered in this session, ``iteration`` the last iteration it
delivered, ``cause`` the last death's reason.

:class:`ProgressBoard` is a tiny Ray actor the workers tell, about four times a second while they
collect, how many of their episodes are done; the learner reads it to report the collection phase's
progress (episodes done / ``num_episodes_between_training``) as the in-process collector does. When
the learner has a live view to feed (a console job), the workers also post their cars' poses there
about 15 times a second, and the learner reads them at that rate.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

WORKER_STATES = ("starting", "alive", "restarting", "dead", "stopped")
REPORT_INTERVAL_S = 0.25  # a worker tells the board at most this often
POSES_INTERVAL_S = 1 / 15  # the cars' poses for a live view: the console's 15 Hz


@dataclass
class WorkerRecord:
    """One rollout worker as the model page shows it (see the module docstring)."""

    index: int
    track: str
    state: str = "starting"
    host: str | None = None
    node_ip: str | None = None
    node_id: str | None = None
    pid: int | None = None
    actor_id: str | None = None
    restarts: int = 0
    episodes: int = 0
    iteration: int | None = None
    cause: str | None = None

    def place(self, where: dict | None) -> None:
        """Take the worker's process facts (:meth:`RolloutWorker.where`)."""
        for key in ("host", "node_ip", "node_id", "pid", "actor_id"):
            if where and where.get(key) is not None:
                setattr(self, key, where[key])


def workers_file(model_root: Path | str) -> Path:
    return Path(model_root) / "logs" / "workers.json"


def write_workers(path: Path, records: list[WorkerRecord], since_iteration: int = 0) -> None:
    """Rewrite ``path`` with ``records`` of a session that started after iteration ``since_iteration``
    (a reader never sees half a file). Not :func:`laplab.store.atomic.atomic_write_json`: this runs
    every iteration for a display, and its fsyncs would cost the collection step for nothing."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    document = {"updated": time.time(), "since_iteration": int(since_iteration), "workers": [asdict(r) for r in records]}
    temporary.write_text(json.dumps(document, indent=1))
    temporary.replace(path)


def read_workers(model_root: Path | str, last_iteration: int | None = None) -> list[dict]:
    """The workers of a model's last Ray session: empty for an in-process model, an unreadable file,
    or when the model's ``last_iteration`` came after that session (a later session collected in-process)."""
    try:
        document = json.loads(workers_file(model_root).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []
    rows = document.get("workers") if isinstance(document, dict) else None
    rows = [row for row in rows if isinstance(row, dict)] if isinstance(rows, list) else []
    if last_iteration is not None and rows:
        delivered = [row["iteration"] for row in rows if isinstance(row.get("iteration"), int)]
        if last_iteration > max([int(document.get("since_iteration") or 0), *delivered]):
            return []
    return rows


class ProgressBoard:
    """The rollout workers' episode counts of the running iteration (a Ray actor with no CPU)."""

    def __init__(self):
        self.counts: dict[int, tuple[int, int, int]] = {}  # worker -> (policy version, episodes done, env steps)
        # worker -> (policy version, poses (N_w, 3), sim s, its cars' race obstacles or None)
        self.poses: dict[int, tuple[int, object, float, object]] = {}

    def report(self, index: int, version: int, done: int, steps: int) -> None:
        self.counts[index] = (version, done, steps)

    def post_poses(self, index: int, version: int, poses, sim_time: float, obstacles=None) -> None:
        """Worker ``index``'s cars now: ``poses`` (N_w, 3) x m, y m, yaw rad; ``sim_time`` s into its
        collection; ``obstacles``: its cars' race obstacles (a :class:`laplab.sim.obstacles.Obstacles`
        of (N_w, K) arrays), None in a time trial."""
        self.poses[index] = (version, poses, sim_time, obstacles)

    def read_poses(self, version: int) -> dict[int, tuple[object, float, object]]:
        """Worker index -> (poses (N_w, 3), sim time s, obstacles or None) posted in the iteration acted
        with ``version``."""
        return {i: (poses, t, obstacles) for i, (v, poses, t, obstacles) in self.poses.items() if v == version}

    def read(self, version: int) -> dict[int, tuple[int, int]]:
        """Worker index -> (episodes done, env steps) in the iteration acted with ``version``."""
        return {i: (done, steps) for i, (v, done, steps) in self.counts.items() if v == version}
