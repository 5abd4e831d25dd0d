"""Quotas as DeepRacer on AWS has them: compute minutes and model count, for the whole console, for
new users, and per user.

The ledger is the jobs table itself, so it cannot drift from what ran: a queued or running job
*reserves* its whole budget (:func:`job_budget_s`: a training's max time, an evaluation's trials x
max trial time); an ended job counts the time it ran (never more than its budget), so what it did
not use returns to the user the moment it ends. A job that would take a user (or the console) over
its minutes, or a new model over the user's model count, is refused with a :class:`QuotaExceeded`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from laplab.errors import UserError
from laplab.jobs.db import ACTIVE_STATUSES, Job, JobStore

_SCHEMA = """
CREATE TABLE IF NOT EXISTS quota_settings (key TEXT PRIMARY KEY, value REAL);
CREATE TABLE IF NOT EXISTS user_quotas (user_id INTEGER PRIMARY KEY, minutes REAL, models INTEGER);
"""
SETTINGS = ("global_minutes", "global_models", "new_user_minutes", "new_user_models")
MODEL_KINDS = ("train", "clone")  # the jobs that make a new model


class QuotaExceeded(UserError):
    """A job or model over a quota; the message names the quota and what is left."""
    default_field = "quota"


@dataclass(frozen=True)
class Usage:
    """A user's (or the console's) compute in minutes and models; limits None: unlimited."""
    used_min: float
    queued_min: float
    models: int
    storage_bytes: int
    minutes_limit: float | None
    models_limit: int | None

    def to_dict(self) -> dict:
        left = None if self.minutes_limit is None else max(0.0, self.minutes_limit - self.used_min - self.queued_min)
        return {"minutes_used": round(self.used_min, 2), "minutes_queued": round(self.queued_min, 2),
                "minutes_limit": self.minutes_limit, "minutes_left": None if left is None else round(left, 2),
                "models": self.models, "models_limit": self.models_limit, "storage_bytes": self.storage_bytes}


def job_budget_s(job_kind: str, params: dict, default_max_s: float) -> float:
    """The seconds a job reserves when queued: a training's ``max_time_s`` (``default_max_s``, the
    console's limit, when it names none), an evaluation's trials x max trial time, an export nothing."""
    if job_kind == "evaluate":
        return float(params.get("trials") or 3) * float(params.get("max_trial_time") or 600.0)
    if job_kind == "export":
        return 0.0
    budget = float(params.get("max_time_s") or 0.0)
    return budget if budget > 0 and math.isfinite(budget) else float(default_max_s)


def job_seconds(job: Job, default_max_s: float) -> tuple[float, float]:
    """(seconds used, seconds reserved) of one job."""
    budget = job_budget_s(job.kind, job.params, default_max_s)
    if job.status in ACTIVE_STATUSES:
        return 0.0, budget
    if job.started is None or job.finished is None:
        return 0.0, 0.0
    ran = max(0.0, job.finished - job.started)
    return (min(ran, budget) if budget > 0 else ran), 0.0


class Quotas:
    """The quota settings and per-user limits in the console database, and the checks."""

    def __init__(self, store: JobStore):
        self.store = store
        store.apply_schema(_SCHEMA)

    def settings(self) -> dict:
        saved = {r["key"]: r["value"] for r in self.store.select("SELECT * FROM quota_settings")}
        return {k: saved.get(k) for k in SETTINGS}

    def set_settings(self, values: dict) -> dict:
        for key, value in values.items():
            if key not in SETTINGS:
                raise QuotaExceeded(f"{key}: not a quota setting ({', '.join(SETTINGS)})", field=key)
            _check_limit(key, value)
            self.store.execute("INSERT INTO quota_settings(key, value) VALUES (?,?) ON CONFLICT(key) DO UPDATE SET "
                               "value=excluded.value", (key, value))
        return self.settings()

    def user_limits(self, user_id: int) -> tuple[float | None, int | None]:
        rows = self.store.select("SELECT * FROM user_quotas WHERE user_id=?", (user_id,))
        return (rows[0]["minutes"], rows[0]["models"]) if rows else (None, None)

    def set_user_limits(self, user_id: int, minutes: float | None, models: int | None) -> None:
        _check_limit("minutes", minutes)
        _check_limit("models", models)
        self.store.execute("INSERT INTO user_quotas(user_id, minutes, models) VALUES (?,?,?) ON CONFLICT(user_id) "
                           "DO UPDATE SET minutes=excluded.minutes, models=excluded.models", (user_id, minutes, models))

    def apply_new_user_quota(self, user_id: int) -> None:
        """A new account starts with the new-user quota (when the admin set one)."""
        settings = self.settings()
        if settings["new_user_minutes"] is not None or settings["new_user_models"] is not None:
            models = settings["new_user_models"]
            self.set_user_limits(user_id, settings["new_user_minutes"], None if models is None else int(models))

    def usage(self, user_id: int | None, default_max_s: float, models_root=None) -> Usage:
        """One user's usage (``None``: the whole console's, against the global quota)."""
        jobs = self.store.jobs() if user_id is None else [j for j in self.store.jobs() if j.owner == user_id]
        used = queued = 0.0
        for job in jobs:
            u, q = job_seconds(job, default_max_s)
            used, queued = used + u, queued + q
        models = [name for name, row in self.store.model_records().items() if user_id is None or row["owner"] == user_id]
        if user_id is None:
            settings = self.settings()
            minutes, count = settings["global_minutes"], settings["global_models"]
        else:
            minutes, count = self.user_limits(user_id)
        return Usage(used / 60.0, queued / 60.0, len(models), _storage(models_root, models), minutes,
                     None if count is None else int(count))

    def check_job(self, user_id: int, kind: str, params: dict, default_max_s: float) -> None:
        """Refuse a job that would take ``user_id`` or the console over its compute minutes, or (a new
        model) over the model count; one paragraph naming the quota."""
        need = job_budget_s(kind, params, default_max_s) / 60.0
        for who, usage in (("your", self.usage(user_id, default_max_s)), ("the console's", self.usage(None, default_max_s))):
            if usage.minutes_limit is not None and usage.used_min + usage.queued_min + need > usage.minutes_limit + 1e-9:
                left = max(0.0, usage.minutes_limit - usage.used_min - usage.queued_min)
                raise QuotaExceeded(
                    f"quota: this {kind} job reserves {need:.1f} compute minutes, over {who} quota of "
                    f"{usage.minutes_limit:g} minutes ({usage.used_min:.1f} used, {usage.queued_min:.1f} reserved by "
                    f"queued and running jobs, {left:.1f} left); ask for a shorter max time or fewer trials, wait "
                    "for a running job to end (it returns what it does not use), or ask an admin for more minutes")
            if kind in MODEL_KINDS and usage.models_limit is not None and usage.models + 1 > usage.models_limit:
                raise QuotaExceeded(
                    f"quota: {who} quota allows {usage.models_limit} models and {usage.models} exist; delete a model "
                    "or ask an admin for a larger model count")


def _check_limit(key: str, value) -> None:
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise QuotaExceeded(f"{key}: a number >= 0, or null for no limit; got {value!r}", field=key)


def _storage(root, names: list[str]) -> int:
    """Bytes under the models' folders (0 without a ``root``)."""
    if root is None:
        return 0
    total = 0
    for name in names:
        for folder, _, files in os.walk(os.path.join(root, name)):
            for file in files:
                try:
                    total += os.lstat(os.path.join(folder, file)).st_size
                except OSError:
                    pass
    return total
