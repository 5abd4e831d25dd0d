"""The console's service: models (folders + owners) and the job scheduler, which feeds the live
event hub (:mod:`laplab.console.events`).

The scheduler runs in the server's event loop every ``TICK_S``: it collects ended jobs, tails the
running jobs' ``events.jsonl`` and ``poses.json`` into the :class:`EventHub`, and starts queued jobs
while fewer than ``workers`` run. Two jobs never share a model folder: a job waits while another
job of its model runs.
"""

from __future__ import annotations

import json
import os
import shutil
import threading
import time

from laplab.console.catalog import ModelCatalog, iso_time, read_json
from laplab.console.events import EventHub
from laplab.console.outcomes import (INTERRUPTED_BY_SHUTDOWN, TRAIN_KINDS, death_reason, time_left_s,  # noqa: F401
                                     without_paths)
from laplab.jobs.db import ACTIVE_STATUSES, Job, JobStore, User
from laplab.jobs.runner import JobRunner, job_folder, models_dir
from laplab.store.layout import list_models

TICK_S = 1.0 / 30.0
LIST_TTL_S = 0.25
QUEUE_CHECK_S = 1.0  # the scheduler reads the queue at least this often while a worker is free
CREDENTIALS_CHECK_S = 0.5  # how soon `laplab users revoke / disable / remove` takes effect in a running server
MODEL_STATUS = {"queued": "queued", "running": "training", "stopping": "stopping", "done": "ready",
                "failed": "failed", "interrupted": "interrupted"}


def model_key(user: User, name: str) -> str:
    """The folder (and job, database) name of ``user``'s model ``name``: model names are per user, so
    two users may both have ``my-first-model`` (``u7-my-first-model``, ``u9-my-first-model``). The
    admin's models (and the CLI's) keep their names."""
    return name if user.is_admin else f"u{user.id}-{name}"


def display_name(key: str, owner: int | None) -> str:
    """The name ``key``'s owner knows it by."""
    prefix = f"u{owner}-"
    return key[len(prefix):] if owner is not None and key.startswith(prefix) else key


class ConsoleService:
    """Everything the API routes call: who owns what, what runs, what changed."""

    def __init__(self, store: JobStore, runner: JobRunner, workers: int):
        self.store, self.runner, self.workers = store, runner, max(1, int(workers))
        self.hub = EventHub()
        self.catalog = ModelCatalog()
        self._event_offsets: dict[int, int] = {}
        self._poses_mtime: dict[tuple[int, str], int] = {}  # (job, poses.json / obstacles.json) -> mtime
        self.interrupted_at_start = store.interrupt_running()
        self._list_cache: dict[int, tuple[float, bytes]] = {}
        self._list_lock = threading.Lock()
        self._list_generation = 0
        self._list_refreshing: set[int] = set()
        self._queue_changed, self._queue_checked = True, 0.0  # the queue is read when it may have changed
        self._credentials_checked = 0.0
        self.server_stopping = False  # set by the app's shutdown: jobs it stops become `interrupted`

    # -- models ------------------------------------------------------------------------------------

    def owners(self) -> dict[str, int]:
        """Model name -> owner id; models made by the CLI belong to the admin."""
        records = self.store.model_records()
        admin = self.store.admin()
        names = set(list_models(models_dir())) | set(records)
        return {n: int(records[n]["owner"]) if n in records else (admin.id if admin else 0) for n in names}

    def resolve(self, user: User, name: str) -> str | None:
        """The key of the model ``user`` calls ``name`` (None when there is none they may see): their own
        model of that name; for the admin also any model by its key (what the admin's list shows)."""
        owners = self.owners()
        key = model_key(user, name)
        if key in owners and (user.is_admin or owners[key] == user.id):
            return key
        if name in owners and (user.is_admin or owners[name] == user.id):  # the admin; a model from before per-user names
            return name
        return None

    def can_see(self, user: User, name: str) -> bool:
        return self.resolve(user, name) is not None

    def handle(self, key: str, owner: int | None, viewer: User | None) -> str:
        """How ``viewer`` names model ``key`` (its owner: their own name; the admin: the key)."""
        return display_name(key, owner) if viewer is None or viewer.id == owner else key

    def model_status(self, name: str, summary: dict, jobs: list[Job] | None = None) -> tuple[str, Job | None]:
        jobs = jobs if jobs is not None else self.store.jobs(model=name, kind=TRAIN_KINDS)
        train_jobs = [j for j in jobs if j.kind in TRAIN_KINDS]
        if train_jobs:
            return MODEL_STATUS[train_jobs[-1].status], train_jobs[-1]
        return ("failed" if summary.get("error") else "ready"), None

    def describe(self, name: str, owner: int | None = None, jobs: list[Job] | None = None,
                 records: dict | None = None, viewer: User | None = None) -> dict:
        """Model ``name`` (its key) as ``viewer`` sees it (``name``: what they call it; None: its owner)."""
        summary = dict(self.catalog.summary(name))
        status, job = self.model_status(name, summary, jobs)
        record = (records if records is not None else self.store.model_records()).get(name)
        owner = owner if owner is not None else self.owners().get(name)
        summary.update(name=self.handle(name, owner, viewer), status=status,
                       description=record["description"] if record else "", owner=self._user_name(owner),
                       progress=job.progress if job else (100.0 if status == "ready" else 0.0),
                       job=job.to_dict() if job else None)
        if not summary["exists"] and job is not None:  # queued: nothing on disk yet, show what was asked
            meta = job.params.get("model_metadata") or {}
            summary.update(track=job.params.get("track") or "classic_2018", sensor=meta.get("sensor", ["STATE"]),
                           algorithm=meta.get("training_algorithm", "clipped_ppo"), max_time_s=job.params.get("max_time_s"))
        if job is not None and job.status == "queued":  # its place in the line: 1 = next to start
            summary["queue_position"] = 1 + sum(1 for j in self.store.jobs(status=("queued",)) if j.id < job.id)
        if job is not None and job.error and status in ("failed", "interrupted"):
            summary["error"] = summary.get("error") or job.error
        summary["error"] = without_paths(summary.get("error"))
        if summary["created"] is None and record is not None:
            summary["created"] = iso_time(record["created"])
        return summary

    @staticmethod
    def queued_config(job: Job) -> tuple[dict | None, str | None]:
        """(the laplab.json a queued training job will write, its reward function): what a model's page
        shows before the job starts. (None, None) for a job whose configuration is not all in its request."""
        from dataclasses import fields

        from laplab.train.request import TrainRequest
        if job.kind != "train":  # a clone's configuration comes from its source when it starts
            return None, None
        names = {f.name for f in fields(TrainRequest)}
        try:
            request = TrainRequest.from_mapping({k: v for k, v in job.params.items() if k in names or k == "vehicle"})
            config = request.to_config().to_dict()
        except (TypeError, ValueError):
            return None, None
        reward = job_folder(job.id) / "reward_function.py"
        return config, reward.read_text(encoding="utf-8") if reward.is_file() else None

    def _user_name(self, user_id: int | None) -> str | None:
        user = self.store.user_by_id(user_id, enabled=False) if user_id is not None else None
        return user.name if user else None

    def cached_models_json(self, user: User) -> tuple[bytes | None, bool]:
        """(the JSON of :meth:`visible_models_json` last built for ``user`` or None, whether it is at
        most ``LIST_TTL_S`` old). A status change drops it; progress within a status may be
        ``LIST_TTL_S`` plus one rebuild old."""
        hit = self._list_cache.get(user.id)
        if hit is None:
            return None, False
        return hit[1], time.monotonic() - hit[0] < LIST_TTL_S

    def visible_models_json(self, user: User) -> bytes:
        """The models ``user`` sees, newest first, as JSON (blocking). One build at a time: many
        requests arriving together wait for the same build instead of each making their own."""
        with self._list_lock:
            body, fresh = self.cached_models_json(user)
            if body is not None and fresh:
                return body
            now, generation = time.monotonic(), self._list_generation
            body = json.dumps(self._visible_models(user), separators=(",", ":")).encode()
            if generation == self._list_generation:
                self._list_cache[user.id] = (now, body)
            return body

    def claim_list_refresh(self, user: User) -> bool:
        """True once per stale list: the caller then rebuilds it in the background (see
        :meth:`visible_models_json`), and :meth:`list_refreshed` releases the claim."""
        if user.id in self._list_refreshing:
            return False
        self._list_refreshing.add(user.id)
        return True

    def list_refreshed(self, user: User) -> None:
        self._list_refreshing.discard(user.id)

    def models_changed(self) -> None:
        """Drop the cached model lists (a status changed, a model was added or removed); a build
        that started before this is not kept."""
        self._list_generation += 1
        self._list_cache.clear()

    def _visible_models(self, user: User) -> list[dict]:
        all_jobs = self.store.jobs(kind=TRAIN_KINDS)
        by_model: dict[str, list[Job]] = {}
        for job in all_jobs:
            by_model.setdefault(job.model, []).append(job)
        records = self.store.model_records()
        out = [self.describe(name, owner, by_model.get(name, []), records, user)
               for name, owner in sorted(self.owners().items()) if user.is_admin or owner == user.id]
        return sorted(out, key=lambda m: m["created"] or "", reverse=True)

    def active_job(self, name: str) -> Job | None:
        active = self.store.jobs(status=ACTIVE_STATUSES, model=name)
        return active[0] if active else None

    def delete_model(self, name: str) -> None:
        for job in self.store.jobs(model=name):
            shutil.rmtree(job_folder(job.id), ignore_errors=True)
        shutil.rmtree(models_dir() / name, ignore_errors=True)
        self.store.forget_model(name)
        self.models_changed()
        self.hub.streams.pop(name, None)

    # -- jobs ------------------------------------------------------------------------------------

    def submit(self, kind: str, model: str, owner: int, params: dict, reward_source: str | None = None) -> Job:
        job = self.store.add_job(kind, model, owner, params)
        self.models_changed()
        self._queue_changed = True
        folder = job_folder(job.id)
        folder.mkdir(parents=True, exist_ok=True)
        if reward_source is not None:
            (folder / "reward_function.py").write_text(reward_source, encoding="utf-8")
        self.hub.publish(model, "status", {"status": "queued", "job": job.id, "kind": kind})
        return job

    def stop(self, job: Job) -> None:
        if job.status == "queued":
            self.store.update_job(job.id, status="interrupted" if job.kind == "resume" else "failed",
                                  finished=time.time(), error="stopped before it started")
            self._publish_status(job.model, job.id, "stopped")
            return
        self.store.update_job(job.id, status="stopping")
        self._publish_status(job.model, job.id, "stopping")
        self.runner.stop(job)

    def stop_jobs_of_absent_users(self) -> None:
        """Stop the queued and running jobs of users disabled or removed (each keeps its model)."""
        for job in self.store.jobs(status=("queued", "running")):
            if self.store.user_by_id(job.owner) is None:
                self.stop(job)

    def _publish_status(self, model: str, job_id: int, status: str, **extra) -> None:
        self.models_changed()
        self.hub.publish(model, "status", {"status": status, "job": job_id, **extra})

    def tick(self) -> None:
        """One scheduler step (cheap: a few stats and small reads)."""
        if time.monotonic() - self._credentials_checked >= CREDENTIALS_CHECK_S:
            self._credentials_checked = time.monotonic()
            if self.store.credentials_changed():
                self.models_changed()
                self.stop_jobs_of_absent_users()
        for finished in self.runner.poll():
            self._finish(finished.job_id, finished.returncode, finished.error)
        running = self.store.jobs(status=("running", "stopping"))
        for job in running:
            self._tail(job)
        free = self.workers - len(running)
        now = time.monotonic()
        if free <= 0 or (not self._queue_changed and now - self._queue_checked < QUEUE_CHECK_S):
            return
        self._queue_changed, self._queue_checked = False, now
        busy_models = {j.model for j in running}
        for job in self.store.jobs(status=("queued",)):
            if free <= 0:
                break
            if job.model in busy_models:
                continue
            self._start(job)
            busy_models.add(job.model)
            free -= 1

    def _start(self, job: Job) -> None:
        folder = job_folder(job.id)
        folder.mkdir(parents=True, exist_ok=True)
        try:
            pid = self.runner.start(job)
        except OSError as exc:
            self.store.update_job(job.id, status="failed", finished=time.time(), error=f"could not start the job: {exc}")
            self._publish_status(job.model, job.id, "failed")
            return
        self.store.update_job(job.id, status="running", started=time.time(), pid=pid, log_path=str(folder / "log.txt"))
        self._publish_status(job.model, job.id, "training" if job.kind in TRAIN_KINDS else "running", kind=job.kind)

    def _tail(self, job: Job) -> None:
        folder = job_folder(job.id)
        events = folder / "events.jsonl"
        offset = self._event_offsets.get(job.id, 0)
        try:
            if events.stat().st_size > offset:
                with open(events, "rb") as handle:
                    handle.seek(offset)
                    chunk = handle.read()
                complete = chunk[:chunk.rfind(b"\n") + 1]
                self._event_offsets[job.id] = offset + len(complete)
                for line in complete.decode("utf-8", errors="replace").splitlines():
                    self._on_event(job, json.loads(line))
        except (OSError, ValueError):
            pass
        for name, publish in (("obstacles.json", self.hub.set_obstacles), ("poses.json", self.hub.set_poses)):
            path = folder / name  # the race's boxes (rewritten when they change), the cars (15 Hz)
            try:
                mtime = path.stat().st_mtime_ns
            except OSError:
                continue
            if mtime != self._poses_mtime.get((job.id, name)):
                self._poses_mtime[(job.id, name)] = mtime
                document = read_json(path)
                if document:
                    publish(job.model, document)

    def _on_event(self, job: Job, event: dict) -> None:
        if event.get("type") == "iteration":
            report = event["report"]
            total = report["elapsed_s"] + report["time_left_s"]
            progress = 100.0 * report["elapsed_s"] / total if total > 0 else 0.0
            self.store.update_job(job.id, progress=round(min(progress, 100.0), 2))
            keep = {k: report.get(k) for k in ("iteration", "episodes", "env_steps", "mean_reward", "mean_progress",
                                                "completion_rate", "eval_progress", "best_lap_time", "eval_lap_time",
                                                "steps_per_second", "elapsed_s", "time_left_s")}
            self.hub.publish(job.model, "iteration", {**keep, "job": job.id, "progress": progress, "t": event["t"]})
        elif event.get("type") == "phase":  # the running iteration: episodes collected, gradient steps, laps
            keep = {k: event.get(k) for k in ("iteration", "phase", "done", "total", "env_steps", "elapsed_s")}
            self.hub.publish(job.model, "phase", {**keep, "job": job.id})

    def _finish(self, job_id: int, returncode: int, runner_error: str | None = None) -> None:
        self._queue_changed = True
        job = self.store.job(job_id)
        if job is None:
            return
        self._tail(job)
        result = read_json(job_folder(job_id) / "result.json") or {}
        status = result.get("status")
        error = result.get("error")
        if runner_error is not None:  # the runner ended it (wall-clock limit), whatever it wrote last
            status, error = "failed", runner_error
        elif self.server_stopping and job.status == "running" and result.get("stop_reason") in (None, "stopped") \
                and status != "failed":  # stopped by the server's shutdown, not by its owner or its budget
            status, error = "interrupted", INTERRUPTED_BY_SHUTDOWN
        elif status not in ("done", "failed"):
            status = "failed"
            error = error or death_reason(job, returncode, getattr(self.runner, "limits", None))
        error = without_paths(error)
        self.store.update_job(job_id, status=status, finished=time.time(), error=error, result=result or None,
                              progress=100.0 if status == "done" else job.progress)
        self._event_offsets.pop(job_id, None)
        self._poses_mtime.pop((job_id, "poses.json"), None)
        self._poses_mtime.pop((job_id, "obstacles.json"), None)
        target = models_dir() / job.model
        if job.kind in ("train", "clone") and target.is_dir() and not any(target.iterdir()):
            target.rmdir()  # validation failed before anything was written
        model_status = MODEL_STATUS[status] if job.kind in TRAIN_KINDS else status
        self._publish_status(job.model, job_id, model_status, kind=job.kind, error=error)


def default_workers() -> int:
    """What this machine can run: one training per two cores (each uses a core plus its learner)."""
    return max(1, (os.cpu_count() or 2) // 2)


def threads_per_job(workers: int) -> int:
    """Each of ``workers`` jobs at a time gets its share of the cores as OpenMP threads for its camera
    learner and simulator (a camera job spends ~85 % of its time learning, ~1.8x faster on two threads
    than one)."""
    return max(1, (os.cpu_count() or 1) // max(1, int(workers)))
