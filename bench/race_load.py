"""A class's race under load: N racers submit to one race within a minute while trainings run.

Two phases on one fresh console (``laplab serve`` in a subprocess, a temporary ``$LAPLAB_HOME``):

1. the trainings alone (``--trainings`` console jobs of ``--train-time`` s, seeded);
2. the same trainings again while ``--racers`` racers (accounts signed up through invitation links,
   one tiny untrained model each) submit to one public race, spread over ``--spread`` s, and
   ``--pollers`` clients poll the race board's leaderboard and the races API.

Prints one JSON document: whether every race evaluation finished, whether they started in
submission order (inversions among start times; the job service runs ``--workers`` jobs at once,
the trainings included), the p50 / p99 latency of the board's ``GET /api/races/{id}/leaderboard`` and
of ``GET /api/races``, and the trainings' wall-time ratio for equal work (phase 1 over phase 2:
1.0 = not slowed; DeepRacer's equal-work measure from ``bench/console_load.py``), how long the
evaluations took (queued -> started -> finished, and how many finished while the trainings ran), the
evaluations' CPU priority (``--evaluation-priority``, passed to ``laplab serve``: nice levels below
the trainings, or ``idle``), the host's load average before and after, and the CPU each phase's
trainings ran beside: core-seconds of the trainings, the evaluations, the console (server and these
clients) and the rest of the host (other users: what the equal-work ratio cannot tell from the
evaluations' share). The trainings stop at ``--train-time`` (their own time budget); the evaluations
then go on until all are done.

Usage: python bench/race_load.py [--racers 30] [--trainings 2] [--workers 4] [--train-time 120]
                                 [--spread 60] [--pollers 4] [--laps 1] [--timeout 1800]
                                 [--evaluation-priority NICE|idle]
The issue's figures need a machine with cores for ``--workers`` jobs; on a small one run it small
(``--racers 4 --trainings 1 --workers 2 --train-time 40``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent))
from console_load import (HYPERPARAMETERS, PLAIN_HTTP, equal_work_ratio, free_port, iteration_log,  # noqa: E402
                          percentile, wait_for_server)

TOKEN = "race-bench-admin-token"


def tiny_model(home: Path, key: str, owner: int, seed: int) -> None:
    """An untrained model folder ``key`` owned by ``owner`` (laplab's own create_training)."""
    from laplab.jobs.db import JobStore
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    config = replace(TrainConfig(), hyperparameters={**TrainConfig().hyper().to_dict(), **HYPERPARAMETERS},
                     max_time_s=5.0, seed=seed)
    create_training(key, config)
    store = JobStore(home / "laplab.db")
    try:
        store.claim_model(key, owner)
    finally:
        store.close()


def train_phase(admin: httpx.Client, prefix: str, count: int, seconds: float) -> None:
    for i in range(count):
        admin.post("/api/models", json={"name": f"{prefix}-{i}", "track": "oval", "max_time_s": seconds, "seed": i,
                                        "hyperparameters": HYPERPARAMETERS}).raise_for_status()


def wait_trained(admin: httpx.Client, prefix: str, count: int, timeout_s: float) -> list[str]:
    deadline = time.monotonic() + timeout_s
    while True:
        statuses = [admin.get(f"/api/models/{prefix}-{i}").json()["status"] for i in range(count)]
        if all(s in ("ready", "failed") for s in statuses) or time.monotonic() > deadline:
            return statuses
        time.sleep(1.0)


class CpuSampler(threading.Thread):
    """Twice a second: the CPU seconds so far of each console job (every process whose stdout is the
    job's ``log.txt``: the worker, bubblewrap, ffmpeg), of the server and this script, and the host's
    busy seconds (``/proc/stat``), to split a phase's CPU between trainings, evaluations, the console
    and everything else on the host (Linux only; nothing elsewhere)."""

    def __init__(self, jobs_dir: Path, server_pid: int):
        super().__init__(daemon=True)
        self.jobs_dir, self.server_pid = str(jobs_dir) + os.sep, server_pid
        self.stop, self.samples, self._last = threading.Event(), [], {}  # pid -> (job id, CPU s)

    @staticmethod
    def _cpu(pid) -> float | None:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return None

    def sample(self) -> None:
        for pid in (p for p in os.listdir("/proc") if p.isdigit()):
            try:
                log = os.readlink(f"/proc/{pid}/fd/1")
            except OSError:
                continue
            if log.startswith(self.jobs_dir) and (cpu := self._cpu(pid)) is not None:
                self._last[int(pid)] = (int(log[len(self.jobs_dir):].split(os.sep)[0]), cpu)
        per_job: dict[int, float] = {}
        for job, cpu in self._last.values():
            per_job[job] = per_job.get(job, 0.0) + cpu
        stat = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
        ticks = [int(v) for v in stat[:8]]
        busy = (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")
        console = (self._cpu(self.server_pid) or 0.0) + (self._cpu("self") or 0.0)
        self.samples.append((time.time(), busy, console, per_job))

    def run(self) -> None:
        while not self.stop.is_set():
            self.sample()
            time.sleep(0.5)

    def split(self, start: float, end: float, trainings: set[int]) -> dict | None:
        """Core-seconds from ``start`` to ``end`` (epoch s): the ``trainings`` jobs, the other jobs
        (evaluations), the console (server and this script's clients) and the rest of the host."""
        inside = [s for s in self.samples if start <= s[0] <= end]
        if len(inside) < 2:
            return None
        (t0, busy0, console0, jobs0), (t1, busy1, console1, jobs1) = inside[0], inside[-1]
        grew = {job: cpu - jobs0.get(job, 0.0) for job, cpu in jobs1.items()}
        training = sum(v for job, v in grew.items() if job in trainings)
        evaluation = sum(v for job, v in grew.items() if job not in trainings)
        console = console1 - console0
        return {"wall_s": round(t1 - t0, 1), "training": round(training, 1), "evaluations": round(evaluation, 1),
                "console": round(console, 1), "rest_of_host": round(busy1 - busy0 - training - evaluation - console, 1)}


def poll(url: str, token: str, paths: list[str], stop: threading.Event, timings: dict[str, list[float]]) -> None:
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=30, **PLAIN_HTTP) as client:
        while not stop.is_set():
            for path in paths:
                start = time.perf_counter()
                client.get(path).raise_for_status()
                timings.setdefault(path, []).append(time.perf_counter() - start)
            time.sleep(0.2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--racers", type=int, default=30)
    parser.add_argument("--trainings", type=int, default=2)
    parser.add_argument("--workers", type=int, default=4)
    parser.add_argument("--train-time", type=float, default=120.0)
    parser.add_argument("--spread", type=float, default=60.0)
    parser.add_argument("--pollers", type=int, default=4)
    parser.add_argument("--laps", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=1800.0)
    parser.add_argument("--evaluation-priority", default=None, help="laplab serve's (default: its default, 10)")
    args = parser.parse_args()
    load_before = os.getloadavg()

    home = Path(tempfile.mkdtemp(prefix="laplab-race-load-"))
    os.environ["LAPLAB_HOME"] = str(home)
    port = free_port()
    env = {**os.environ, "LAPLAB_ADMIN_TOKEN": TOKEN}
    priority = [] if args.evaluation_priority is None else ["--evaluation-priority", str(args.evaluation_priority)]
    server = subprocess.Popen([sys.executable, "-m", "laplab.cli", "serve", "--port", str(port),
                               "--workers", str(args.workers), *priority], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    admin = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60, **PLAIN_HTTP)
    try:
        wait_for_server(admin, "/api/health")
        marker = home / "sandbox" / "trusted-numba" / "laplab-warmup-done"
        deadline = time.monotonic() + 900
        while not marker.exists() and time.monotonic() < deadline:  # the server's one-off numba warm-up
            time.sleep(1)
        sampler = CpuSampler(home / "jobs", server.pid)
        sampler.start()
        train_phase(admin, "alone", args.trainings, args.train_time)
        wait_trained(admin, "alone", args.trainings, args.train_time + 900)

        # the class: a facilitator and N racers through invitation links, one tiny model each
        tokens = {}
        for name, role in [("coach", "facilitator")] + [(f"racer{i:02d}", "racer") for i in range(args.racers)]:
            code = admin.post("/api/invites", json={"role": role}).json()["code"]
            httpx.post(f"{url}/api/signup", json={"invite": code, "name": name, "password": f"{name}-password"},
                       **PLAIN_HTTP).raise_for_status()
            tokens[name] = admin.post(f"/api/users/{name}/tokens").json()["token"]
        from laplab.jobs.db import JobStore
        store = JobStore(home / "laplab.db")
        ids = {u.name: u.id for u in store.users()}
        store.close()
        for i in range(args.racers):
            tiny_model(home, f"u{ids[f'racer{i:02d}']}-car", ids[f"racer{i:02d}"], seed=i)
        coach = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {tokens['coach']}"}, timeout=60,
                             **PLAIN_HTTP)
        race = coach.post("/api/races", json={"name": "Load race", "track": "oval", "laps": args.laps,
                                              "ranking": "best_lap", "max_submissions": 3}).json()

        stop, timings = threading.Event(), {}
        board, listing = f"/api/races/{race['id']}/leaderboard", "/api/races"
        pollers = [threading.Thread(target=poll, args=(url, tokens[f"racer{i % args.racers:02d}"], [board, listing],
                                                       stop, timings), daemon=True) for i in range(args.pollers)]
        for thread in pollers:
            thread.start()
        train_phase(admin, "raced", args.trainings, args.train_time)
        submitted: dict[int, float] = {}

        def submit(i: int) -> None:
            time.sleep(args.spread * i / max(1, args.racers))
            with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {tokens[f'racer{i:02d}']}"},
                              timeout=60, **PLAIN_HTTP) as client:
                answer = client.post(f"/api/races/{race['id']}/submissions", json={"model": "car"})
                answer.raise_for_status()
                submitted[answer.json()["job"]] = time.time()

        submitters = [threading.Thread(target=submit, args=(i,)) for i in range(args.racers)]
        started = time.monotonic()
        for thread in submitters:
            thread.start()
        for thread in submitters:
            thread.join()
        deadline = time.monotonic() + args.timeout
        while time.monotonic() < deadline:
            subs = coach.get(f"/api/races/{race['id']}/submissions").json()
            if len(subs) == args.racers and all(s["state"] in ("done", "failed") for s in subs):
                break
            time.sleep(2.0)
        race_wall = time.monotonic() - started
        statuses = wait_trained(admin, "raced", args.trainings, args.train_time + 900)
        stop.set()
        for thread in pollers:
            thread.join(60)

        store = JobStore(home / "laplab.db")
        jobs = [store.job(job_id) for job_id in sorted(submitted)]
        trained = [j for j in store.jobs(kind=("train",)) if j.model.startswith("raced-")]
        alone = [j for j in store.jobs(kind=("train",)) if j.model.startswith("alone-")]
        store.close()
        training_end = max((j.finished for j in trained if j.finished), default=None)
        first_log = (home / "jobs" / str(jobs[0].id) / "log.txt").read_text().splitlines() if jobs else []
        ran = [j.finished - j.started for j in jobs if j.started and j.finished]
        waited = [j.started - j.created for j in jobs if j.started]
        starts = [j.started for j in jobs]
        inversions = sum(1 for a in range(len(starts)) for b in range(a + 1, len(starts))
                         if starts[a] is not None and starts[b] is not None and starts[b] < starts[a])
        ratio = equal_work_ratio([iteration_log(home / "models" / f"alone-{i}") for i in range(args.trainings)],
                                 [iteration_log(home / "models" / f"raced-{i}") for i in range(args.trainings)])
        subs = coach.get(f"/api/races/{race['id']}/submissions").json()
        report = {
            "racers": args.racers, "trainings": args.trainings, "workers": args.workers, "laps": args.laps,
            "evaluations_done": sum(s["state"] == "done" for s in subs), "evaluations_failed":
                [s["reason"] for s in subs if s["state"] == "failed"],
            "ranked": len(coach.get(board).json()["entries"]), "start_order_inversions": inversions,
            "race_wall_s": round(race_wall, 1), "training_status": statuses,
            "evaluation_priority": args.evaluation_priority or "serve's default",
            "evaluation_cpu": first_log[0].split("(CPU: ", 1)[-1][:-1] if first_log else None,
            "evaluation_run_s": {"mean": round(sum(ran) / len(ran), 1), "max": round(max(ran), 1)} if ran else None,
            "evaluation_queue_s": {"mean": round(sum(waited) / len(waited), 1), "max": round(max(waited), 1)}
                                  if waited else None,
            "evaluations_done_while_training": None if training_end is None else
                sum(1 for j in jobs if j.finished and j.finished <= training_end),
            "training_equal_work_ratio": None if ratio is None else round(ratio[0], 3),
            "training_slowdown_pct": None if ratio is None else round(100 * (1 / ratio[0] - 1), 1),
            "latency_ms": {path: {"n": len(v), "p50": round(1000 * percentile(v, 50), 1),
                                  "p99": round(1000 * percentile(v, 99), 1)} for path, v in timings.items()},
            "core_seconds_while_training": {  # CPU split over each phase's trainings (first start to last end)
                phase: sampler.split(min(j.started for j in group), max(j.finished for j in group), {j.id for j in group})
                if group and all(j.started and j.finished for j in group) else None
                for phase, group in (("alone", alone), ("raced", trained))},
            "cpus": os.cpu_count(), "load_average_before": [round(v, 2) for v in load_before],
            "load_average_after": [round(v, 2) for v in os.getloadavg()],
        }
        print(json.dumps(report, indent=1))
    finally:
        if "sampler" in locals():
            sampler.stop.set()
        admin.close()
        server.terminate()
        server.wait(60)


if __name__ == "__main__":
    main()
