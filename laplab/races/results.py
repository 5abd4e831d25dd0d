"""A race's results, read from its submissions' evaluate jobs: each submission's laps (time,
off-tracks, resets), its score under the race's ranking and why it did not rank; the board; the CSV;
the top-down replay of a submission's laps.

An ended job's result never changes, so its laps are read once and kept (:class:`ResultCache`): a
board polled every second by a projector and thirty phones costs a few SQLite reads.
"""

from __future__ import annotations

import csv
import io
import threading
from pathlib import Path

from laplab.jobs.db import Job, JobStore
from laplab.races.rescore import rescore
from laplab.races.rules import RaceSettings, rank
from laplab.races.store import Race, Submission

JOB_STATES = {"queued": "queued", "running": "running", "stopping": "running", "done": "done",
              "failed": "failed", "interrupted": "failed"}


class ResultCache:
    """Laps of ended evaluate jobs by job id (read from the model's evaluation summary once)."""

    def __init__(self):
        self._done: dict[int, dict] = {}
        self._lock = threading.Lock()

    def evaluation(self, job: Job, models_root: Path) -> dict:
        """``{"trials": [...], "stamp": ..., "video": bool, "sensors": [...] or None}`` of a done job
        (empty trials otherwise)."""
        with self._lock:
            hit = self._done.get(job.id)
        if hit is not None:
            return hit
        found = {"trials": [], "stamp": None, "video": False, "sensors": None}
        stamp = (job.result or {}).get("stamp") if job.status == "done" else None
        if stamp:
            from laplab.evaluate.trials import EvaluationError, read_evaluation_summary
            from laplab.store.layout import ModelFolder
            folder = ModelFolder(models_root / job.model)
            try:
                document = read_evaluation_summary(folder, stamp) or {}
                videos = list(folder.evaluation_dir(stamp).glob("*.mp4")) + list(folder.evaluation_dir(stamp).glob("*.gif"))
            except (EvaluationError, OSError, ValueError):
                document, videos = {}, []
            found = {"trials": document.get("trials", []), "stamp": stamp, "video": bool(videos),
                     "sensors": document.get("sensors")}
        if job.status not in ("queued", "running", "stopping"):
            with self._lock:
                self._done[job.id] = found
        return found


def laps_of(trials: list[dict]) -> list[dict]:
    """The laps a board shows: number, time (s, None unless completed), off-tracks, resets, how it ended."""
    return [{"lap": i + 1, "time": t.get("lap_time") if t.get("status") == "lap_complete" else None,
             "off_track": int(t.get("off_track_count", 0)), "resets": int(t.get("reset_count", 0)),
             "crashes": int(t.get("crash_count", 0)), "status": t.get("status"),
             "completion": t.get("completion")} for i, t in enumerate(trials)]


def submission_rows(race: Race, submissions: list[Submission], store: JobStore, cache: ResultCache,
                    models_root: Path) -> list[dict]:
    """One row per submission: state, laps, score and ``reason`` (why it does not rank, when it does not)."""
    jobs = {j.id: j for j in store.jobs(kind=("evaluate",))} if submissions else {}
    current = race_params(race.settings) if submissions else {}
    rows = []
    for sub in submissions:
        job = jobs.get(sub.job_id)
        row = {"id": sub.id, "user_id": sub.user_id, "model": sub.model, "job": sub.job_id, "created": sub.created,
               "state": "failed", "laps": [], "score": None, "reason": None, "video": False, "rules_note": None}
        if job is None:
            row["reason"] = "its evaluation job was removed (the model was deleted)"
        else:
            row["state"] = JOB_STATES.get(job.status, "failed")
            found = cache.evaluation(job, models_root)
            row["laps"], row["video"] = laps_of(found["trials"]), found["video"]
            if row["state"] == "done":  # under the race's rules now, from the laps it drove (laplab.races.rescore)
                now = rescore(race.settings, current, job.params, found["trials"], found.get("sensors"))
                row["laps"], row["score"], row["reason"] = laps_of(now.trials), now.score.value, now.score.reason
                row["rules_note"] = "; ".join(now.notes) or None
            elif row["state"] == "failed":
                row["reason"] = f"its evaluation failed: {job.error or 'no reason recorded'}"
            else:
                row["reason"] = f"its evaluation is {row['state']}"
        rows.append(row)
    return rows


def race_params(settings: RaceSettings) -> dict:
    """The evaluate job's params of a submission made now (the race's track in its direction)."""
    from laplab.races.catalogue import track_key
    return settings.evaluation_params(track_key(settings.track, settings.direction))


def stale_submissions(race: Race, submissions: list[Submission], store: JobStore) -> int:
    """How many of ``submissions`` drove another course than the race's now (track, direction, car,
    race type: :func:`laplab.races.rescore.course_change`): they no longer rank, nor count toward
    ``max_submissions``, so racers can submit again after such an edit."""
    if not submissions:
        return 0
    from laplab.races.rescore import course_change
    current = race_params(race.settings)
    wanted = {sub.job_id for sub in submissions}
    return sum(1 for job in store.jobs(kind=("evaluate",))
               if job.id in wanted and course_change(current, job.params) is not None)


def rescoring(before: list[dict], after: list[dict]) -> dict:
    """What an edit of a race's rules did to its submissions: the rows of :func:`submission_rows`
    ``before`` and ``after`` the edit (by submission id) give ``ranked`` / ``unranked`` counts now
    and ``changed``: each submission whose score, reason or board rank moved, before and after."""
    ranks_before = {r["id"]: r["rank"] for r in board(before)}
    ranks_after = {r["id"]: r["rank"] for r in board(after)}
    old = {r["id"]: r for r in before}
    changed = []
    for row in after:
        was = old.get(row["id"], {})
        if (was.get("score"), was.get("reason"), ranks_before.get(row["id"])) != (
                row["score"], row["reason"], ranks_after.get(row["id"])):
            changed.append({"id": row["id"], "user_id": row["user_id"], "alias": row.get("alias"),
                            "score_before": was.get("score"), "score": row["score"],
                            "rank_before": ranks_before.get(row["id"]), "rank": ranks_after.get(row["id"]),
                            "reason": row["reason"], "rules_note": row["rules_note"]})
    done = [r for r in after if r["state"] == "done"]
    return {"submissions": len(after), "ranked": sum(r["score"] is not None for r in done),
            "unranked": sum(r["score"] is None for r in done), "changed": changed}


def board(rows: list[dict]) -> list[dict]:
    """The ranked rows (each racer's best, ties by submission time)."""
    return rank([{**r, "user": r["user_id"]} for r in rows])


def csv_text(settings: RaceSettings, ranked: list[dict], names: dict[int, str]) -> str:
    """The board as CSV: rank, racer, score and each lap's time, off-tracks and resets."""
    out = io.StringIO()
    writer = csv.writer(out)
    header = ["rank", "racer", "user", "score_s", "ranking", "submitted_utc"]
    for lap in range(1, settings.laps + 1):
        header += [f"lap{lap}_s", f"lap{lap}_off_track", f"lap{lap}_resets"]
    writer.writerow(header)
    from datetime import datetime, timezone
    for row in ranked:
        line = [row["rank"], row.get("alias", ""), names.get(row["user_id"], ""), f"{row['score']:.3f}",
                settings.ranking, datetime.fromtimestamp(row["created"], timezone.utc).isoformat(timespec="seconds")]
        for lap in range(settings.laps):
            got = row["laps"][lap] if lap < len(row["laps"]) else {}
            line += ["" if got.get("time") is None else f"{got['time']:.3f}", got.get("off_track", ""),
                     got.get("resets", "")]
        writer.writerow(line)
    return out.getvalue()


def replay(job: Job, stamp: str, models_root: Path, points_per_lap: int = 300) -> list[list[list[float]]]:
    """The car's path of each lap of an evaluation, top-down: ``[lap][point] = [x, y]`` (m), at most
    ``points_per_lap`` points each (from the evaluation's simtrace)."""
    from laplab.store.layout import ModelFolder
    path = ModelFolder(models_root / job.model).evaluation_simtrace(stamp)
    if not Path(path).is_file():
        return []
    laps: dict[int, list[list[float]]] = {}
    with open(path, newline="") as handle:
        for record in csv.DictReader(handle):
            try:
                laps.setdefault(int(float(record["episode"])), []).append([round(float(record["X"]), 3),
                                                                          round(float(record["Y"]), 3)])
            except (KeyError, ValueError):
                continue
    out = []
    for index in sorted(laps):
        points = laps[index]
        step = max(1, len(points) // points_per_lap)
        out.append(points[::step])
    return out
