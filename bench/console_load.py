"""The console under load: 50 concurrent API clients and 20 open event streams against a server
running 2 trainings.

Prints the p50 / p99 latency of ``GET /api/models``, the delivery latency of ``iteration`` events
(the worker's write time to the moment a stream client reads the event), and the trainings' env
steps per second against the same two trainings run by ``laplab train`` without the server.

Everything runs on this machine (server, jobs and clients share its cores), on 127.0.0.1, with a
fresh temporary ``$LAPLAB_HOME``, bounded by ``--seconds`` per phase.

Three phases of ``--seconds``: the two trainings by ``laplab train`` (with the thread setting the
console gives its jobs), the same two as console jobs with no clients (the server's own cost), and
as console jobs under the load. Clients and server share this machine's cores with the trainings,
so the bench also prints the share of the machine's CPU each took.

Usage: python bench/console_load.py [--seconds 90] [--clients 50] [--streams 20] [--think 0.2] [--no-baseline]
                                    [--no-quiet-phase]
       python bench/console_load.py --cpu-per-request --seconds 20 --clients 20 --streams 20
"""

from __future__ import annotations

import argparse
import json
import os
import random
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

TOKEN = "bench-admin-token"
# The bench speaks plain HTTP on loopback. httpx builds a TLS context (the CA bundle, 60-200 ms holding
# the GIL on this host) for every client unless told not to verify; 70 clients doing that at once
# stalled every client's first request by 1-2 s in session 5's runs.
PLAIN_HTTP = {"verify": False}
HYPERPARAMETERS = {"num_episodes_between_training": 4, "num_epochs": 3, "batch_size": 32}


def wait_for_server(client: httpx.Client, path: str, timeout_s: float = 60.0) -> None:
    """Poll ``path`` until the server answers 200 (it is starting up); exit after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            if client.get(path).status_code == 200:
                return
        except httpx.TransportError:
            pass
        if time.monotonic() > deadline:
            raise SystemExit("the server did not start")
        time.sleep(0.2)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def steps_per_second(model_dir: Path) -> float | None:
    """Env steps per wall second of a training, from laplab's iteration log."""
    path = model_dir / "metrics" / "laplab-iterations.json"
    if not path.exists():
        return None
    rows = json.loads(path.read_text())["iterations"]
    return rows[-1]["env_steps"] / rows[-1]["elapsed_s"] if rows else None


def first_iteration_s(model_dir: Path) -> float | None:
    """Wall seconds of a training's first iteration (its start-up: JIT caches, first frames), from its log."""
    path = model_dir / "metrics" / "laplab-iterations.json"
    rows = json.loads(path.read_text())["iterations"] if path.exists() else []
    return rows[0]["elapsed_s"] if rows else None


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q / 100 * (len(ordered) - 1))))] if ordered else float("nan")


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds a process has used so far (Linux; None elsewhere)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def baseline(home: Path, seconds: float) -> tuple[list[float | None], list[float | None]]:
    """Two `laplab train` processes at once, no server, with the thread setting the console gives its jobs:
    their env steps/s and their first iterations' wall seconds."""
    env = {**os.environ, "LAPLAB_HOME": str(home), "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    home.mkdir(parents=True, exist_ok=True)
    hp = home / "hp.json"
    hp.write_text(json.dumps(HYPERPARAMETERS))
    processes = [subprocess.Popen([sys.executable, "-m", "laplab.cli", "train", "--name", f"base-{i}", "--track", "oval",
                                   "--max-time", f"{seconds}s", "--hyperparameters", str(hp), "--quiet"],
                                  env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for i in range(2)]
    for p in processes:
        p.wait(seconds + 600)
    return [steps_per_second(home / "models" / f"base-{i}") for i in range(2)], \
        [first_iteration_s(home / "models" / f"base-{i}") for i in range(2)]


def with_server(home: Path, seconds: float, clients: int, streams: int, think: float) -> dict:
    port = free_port()
    env = {**os.environ, "LAPLAB_HOME": str(home), "LAPLAB_ADMIN_TOKEN": TOKEN}
    server = subprocess.Popen([sys.executable, "-m", "laplab.cli", "serve", "--port", str(port), "--workers", "2"],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    headers = {"Authorization": f"Bearer {TOKEN}"}
    admin = httpx.Client(base_url=url, headers=headers, timeout=30, **PLAIN_HTTP)
    try:
        wait_for_server(admin, "/api/health")
        marker = home / "sandbox" / "trusted-numba" / "laplab-warmup-done"
        warm_deadline = time.monotonic() + 600
        while not marker.exists() and time.monotonic() < warm_deadline:  # the server's one-off numba warm-up
            time.sleep(1)
        for i in range(2):
            answer = admin.post("/api/models", json={"name": f"served-{i}", "track": "oval", "max_time_s": seconds,
                                                     "hyperparameters": HYPERPARAMETERS})
            answer.raise_for_status()
        stop = threading.Event()
        latencies: list[float] = []
        slow: list[tuple[float, float]] = []  # (s since the load started, latency s) of requests over 100 ms
        deliveries: list[float] = []
        errors = [0]

        def api_client():
            stop.wait(random.uniform(0, think))  # pages opened at different moments, not in lock-step
            with httpx.Client(base_url=url, headers=headers, timeout=30, **PLAIN_HTTP) as client:
                while not stop.is_set():
                    t0 = time.perf_counter()
                    try:
                        ok = client.get("/api/models").status_code == 200
                    except httpx.HTTPError:
                        ok = False
                    if ok:
                        latencies.append(time.perf_counter() - t0)
                        if latencies[-1] > 0.1:
                            slow.append((t0 - load_started, latencies[-1]))
                    else:
                        errors[0] += 1
                    stop.wait(think)

        def stream_client(model: str):
            with httpx.Client(base_url=url, headers=headers, timeout=httpx.Timeout(30, read=None), **PLAIN_HTTP) as client:
                try:
                    with client.stream("GET", f"/api/models/{model}/events") as response:
                        kind = None
                        for line in response.iter_lines():
                            if stop.is_set():
                                return
                            if line.startswith("event: "):
                                kind = line[7:]
                            elif line.startswith("data: ") and kind == "iteration":
                                deliveries.append(time.time() - json.loads(line[6:])["t"])
                except httpx.HTTPError:
                    errors[0] += 1

        threads = [threading.Thread(target=api_client, daemon=True) for _ in range(clients)]
        threads += [threading.Thread(target=stream_client, args=(f"served-{i % 2}",), daemon=True) for i in range(streams)]
        cpu_start, clients_start, wall_start = cpu_seconds(server.pid), time.process_time(), time.monotonic()
        load_started = time.perf_counter()
        for t in threads:
            t.start()
        end = time.monotonic() + seconds + 600
        while time.monotonic() < end:
            statuses = [admin.get(f"/api/models/served-{i}").json()["status"] for i in range(2)]
            if all(s in ("ready", "failed") for s in statuses):
                break
            time.sleep(1)
        stop.set()
        cpu_end, clients_cpu = cpu_seconds(server.pid), time.process_time() - clients_start
        wall = time.monotonic() - wall_start
        for t in threads:
            t.join(5)
        cpu = None if cpu_start is None or cpu_end is None else cpu_end - cpu_start
        return {"latencies": latencies, "deliveries": deliveries, "errors": errors[0], "statuses": statuses, "cpu": cpu,
                "clients_cpu": clients_cpu, "wall": wall, "slow": slow, "steps": [steps_per_second(home / "models" / f"served-{i}") for i in range(2)],
                "first": [first_iteration_s(home / "models" / f"served-{i}") for i in range(2)]}
    finally:
        admin.close()
        server.terminate()
        server.wait(60)


def cpu_per_request(home: Path, seconds: float, clients: int, streams: int) -> None:
    """The server's CPU time per ``GET /api/models`` with one idle model, ``streams`` open event
    streams on it and ``clients`` threads asking with no think time (no trainings: the figure the
    machine's other load disturbs least)."""
    from dataclasses import replace
    os.environ["LAPLAB_HOME"] = str(home)
    from laplab.jobs.warmup import READY_MARKER, trusted_cache
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    create_training("idle", replace(TrainConfig(), max_time_s=5.0))
    trusted_cache(home).mkdir(parents=True)
    (trusted_cache(home) / READY_MARKER).write_text("no jobs run here\n")  # no warm-up in the server
    port = free_port()
    server = subprocess.Popen([sys.executable, "-m", "laplab.cli", "serve", "--port", str(port)],
                              env={**os.environ, "LAPLAB_ADMIN_TOKEN": TOKEN}, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    url, headers = f"http://127.0.0.1:{port}", {"Authorization": f"Bearer {TOKEN}"}
    stop, latencies = threading.Event(), []
    try:
        with httpx.Client(base_url=url, headers=headers, **PLAIN_HTTP) as admin:
            wait_for_server(admin, "/api/models")

        def stream_client():
            with httpx.Client(base_url=url, headers=headers, timeout=httpx.Timeout(30, read=None), **PLAIN_HTTP) as client:
                with client.stream("GET", "/api/models/idle/events") as response:
                    for _ in response.iter_lines():
                        if stop.is_set():
                            return

        def api_client():
            with httpx.Client(base_url=url, headers=headers, timeout=30, **PLAIN_HTTP) as client:
                while not stop.is_set():
                    t0 = time.perf_counter()
                    if client.get("/api/models").status_code == 200:
                        latencies.append(time.perf_counter() - t0)

        for _ in range(streams):
            threading.Thread(target=stream_client, daemon=True).start()
        time.sleep(2)
        idle_start = cpu_seconds(server.pid)
        time.sleep(5)
        idle = (cpu_seconds(server.pid) - idle_start) / 5
        cpu_start = cpu_seconds(server.pid)
        for _ in range(clients):
            threading.Thread(target=api_client, daemon=True).start()
        time.sleep(seconds)
        stop.set()
        cpu = cpu_seconds(server.pid) - cpu_start
    finally:
        server.terminate()
        server.wait(60)
    n = len(latencies)
    print(f"idle server with {streams} open streams: {1000 * idle:.0f} ms of CPU per second")
    print(f"{n} GET /api/models from {clients} clients in {seconds:g} s ({n / seconds:.0f}/s): server CPU "
          f"{1000 * cpu / max(n, 1):.2f} ms per request; p50 {1000 * percentile(latencies, 50):.1f} ms, "
          f"p99 {1000 * percentile(latencies, 99):.1f} ms; load average {os.getloadavg()[0]:.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=90.0, help="training time of each phase (default 90)")
    parser.add_argument("--clients", type=int, default=50)
    parser.add_argument("--streams", type=int, default=20)
    parser.add_argument("--think", type=float, default=0.2,
                        help="s each API client waits between requests (the console's Models page polls every 3 s)")
    parser.add_argument("--no-baseline", action="store_true", help="skip the trainings without the server")
    parser.add_argument("--no-quiet-phase", action="store_true",
                        help="skip the trainings run by the server with no clients (the server's own cost)")
    parser.add_argument("--cpu-per-request", action="store_true",
                        help="only the server's CPU per request: an idle model, --streams streams, --clients clients "
                             "with no think time for --seconds")
    args = parser.parse_args()
    if args.cpu_per_request:
        with tempfile.TemporaryDirectory(prefix="laplab-bench-") as folder:
            cpu_per_request(Path(folder), args.seconds, args.clients, args.streams)
        return
    with tempfile.TemporaryDirectory(prefix="laplab-bench-") as folder:
        root = Path(folder)
        base, base_first = ([None, None], [None, None]) if args.no_baseline else baseline(root / "baseline", args.seconds)
        quiet = None if args.no_quiet_phase else with_server(root / "quiet", args.seconds, 0, 0, args.think)
        served = with_server(root / "served", args.seconds, args.clients, args.streams, args.think)
    lat, dl = served["latencies"], served["deliveries"]
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end")
    print(f"GET /api/models: {len(lat)} requests from {args.clients} clients (think {args.think:g} s): "
          f"p50 {1000 * percentile(lat, 50):.1f} ms, p99 {1000 * percentile(lat, 99):.1f} ms, errors {served['errors']}")
    if served["slow"]:
        when = ", ".join(f"{1000 * lat_s:.0f} ms at {t:.1f} s" for t, lat_s in sorted(served["slow"])[:12])
        print(f"  {len(served['slow'])} requests over 100 ms, the first: {when}")
    if served["cpu"] is not None and lat:
        print(f"server CPU during the load: {served['cpu']:.1f} s, {1000 * served['cpu'] / len(lat):.2f} ms per "
              f"GET /api/models answered (streams, scheduler and the other requests included); the client "
              f"threads' CPU (this process, same machine): {served['clients_cpu']:.1f} s")
    print(f"iteration events over {args.streams} streams: {len(dl)} delivered, p50 {1000 * percentile(dl, 50):.0f} ms, "
          f"p99 {1000 * percentile(dl, 99):.0f} ms, max {1000 * max(dl, default=float('nan')):.0f} ms")
    fmt = lambda xs: ", ".join("-" if x is None else f"{x:.1f}" for x in xs)  # noqa: E731
    mean = lambda xs: statistics.mean([x for x in xs if x is not None] or [float("nan")])  # noqa: E731
    print(f"env steps/s of 2 trainings: without the server {fmt(base)} (mean {mean(base):.1f}); "
          f"with the server and the load {fmt(served['steps'])} (mean {mean(served['steps']):.1f}); "
          f"ratio {mean(served['steps']) / mean(base):.2f}; final statuses {served['statuses']}")
    if quiet is not None:
        print(f"  as console jobs, no clients: {fmt(quiet['steps'])} (mean {mean(quiet['steps']):.1f}), ratio to "
              f"without the server {mean(quiet['steps']) / mean(base):.2f}; the load's clients then take the "
              f"ratio to {mean(served['steps']) / mean(quiet['steps']):.2f} of that")
    print(f"  first iteration (s): without the server {fmt(base_first)}; with the load {fmt(served['first'])}"
          + ("" if quiet is None else f"; no clients {fmt(quiet['first'])}"))
    if served["cpu"] is not None:
        print(f"  the server's share of the machine under the load: {served['cpu'] / (served['wall'] * os.cpu_count()):.1%}"
              f" of its CPU ({served['cpu']:.1f} s in {served['wall']:.0f} s on {os.cpu_count()} cores); the clients' "
              f"{served['clients_cpu'] / (served['wall'] * os.cpu_count()):.1%}")


if __name__ == "__main__":
    main()
