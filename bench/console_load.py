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
                                    [--no-quiet-phase] [--repeats 1]
       python bench/console_load.py --cpu-per-request --seconds 20 --clients 20 --streams 20
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
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


def iteration_log(model_dir: Path) -> list[tuple[int, float]]:
    """(env steps, wall seconds since the start) at the end of each iteration of a training."""
    path = model_dir / "metrics" / "laplab-iterations.json"
    rows = json.loads(path.read_text())["iterations"] if path.exists() else []
    return [(row["env_steps"], row["elapsed_s"]) for row in rows]


def trainings(models: Path, prefix: str) -> dict:
    """The two trainings ``PREFIX-0`` and ``PREFIX-1`` of a phase, from their iteration logs: env steps per
    wall second at the last iteration (``steps``), the first iteration's wall seconds (its start-up: JIT
    caches, first frames; ``first``) and the logs themselves (``logs``)."""
    logs = [iteration_log(models / f"{prefix}-{i}") for i in range(2)]
    return {"steps": [log[-1][0] / log[-1][1] if log else None for log in logs],
            "first": [log[0][1] if log else None for log in logs], "logs": logs}


def equal_work_ratio(reference: list[list[tuple[int, float]]], other: list[list[tuple[int, float]]]) -> tuple[float, int] | None:
    """How fast ``other``'s trainings did the same work as ``reference``'s: the wall-time ratio at the last
    iteration both reached, averaged over the trainings, and that iteration. The trainings are seeded,
    so the same iteration holds the same episodes (checked: equal env steps); None when they differ."""
    ratios, reached = [], []
    for ref, oth in zip(reference, other):
        k = min(len(ref), len(oth)) - 1
        if k < 0 or ref[k][0] != oth[k][0]:
            return None
        ratios.append(ref[k][1] / oth[k][1])
        reached.append(k + 1)
    return statistics.mean(ratios), min(reached)


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


def start_load(port: int, clients: int, streams: int, think: float, models: list[str]) -> subprocess.Popen:
    """The browsers: ``bench/http_load.py`` in its own process (one event loop, lean HTTP), until stopped."""
    command = [sys.executable, str(Path(__file__).with_name("http_load.py")), "--port", str(port), "--token", TOKEN,
               "--clients", str(clients), "--streams", str(streams), "--think", str(think)]
    for model in models:
        command += ["--model", model]
    return subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def finish_load(load: subprocess.Popen) -> dict:
    """Stop the load generator; its results, with ``clients_cpu`` its CPU seconds."""
    output, _ = load.communicate("", timeout=60)
    result = json.loads(output)
    result["clients_cpu"] = result.pop("cpu")
    return result


def baseline(home: Path, seconds: float) -> dict:
    """Two `laplab train` processes at once, no server, with the thread setting the console gives its jobs:
    their env steps/s, their first iterations' wall seconds and their iteration logs."""
    env = {**os.environ, "LAPLAB_HOME": str(home), "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    home.mkdir(parents=True, exist_ok=True)
    hp = home / "hp.json"
    hp.write_text(json.dumps(HYPERPARAMETERS))
    processes = [subprocess.Popen([sys.executable, "-m", "laplab.cli", "train", "--name", f"base-{i}", "--track", "oval",
                                   "--max-time", f"{seconds}s", "--hyperparameters", str(hp), "--quiet"],
                                  env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for i in range(2)]
    for p in processes:
        p.wait(seconds + 600)
    return trainings(home / "models", "base")


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
        load = start_load(port, clients, streams, think, [f"served-{i}" for i in range(2)])
        cpu_start, wall_start = cpu_seconds(server.pid), time.monotonic()
        end = time.monotonic() + seconds + 600
        while time.monotonic() < end:
            statuses = [admin.get(f"/api/models/served-{i}").json()["status"] for i in range(2)]
            if all(s in ("ready", "failed") for s in statuses):
                break
            time.sleep(1)
        cpu_end, wall = cpu_seconds(server.pid), time.monotonic() - wall_start
        result = finish_load(load)
        cpu = None if cpu_start is None or cpu_end is None else cpu_end - cpu_start
        return {**result, "statuses": statuses, "cpu": cpu, "wall": wall, **trainings(home / "models", "served")}
    finally:
        admin.close()
        server.terminate()
        server.wait(60)


def cpu_per_request(home: Path, seconds: float, clients: int, streams: int) -> None:
    """The server's CPU time per ``GET /api/models`` with one idle model, ``streams`` open event
    streams on it and ``clients`` clients asking with no think time (no trainings: the figure the
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
    try:
        with httpx.Client(base_url=url, headers=headers, **PLAIN_HTTP) as admin:
            wait_for_server(admin, "/api/models")
        stream_load = start_load(port, 0, streams, 0, ["idle"])
        time.sleep(2)
        idle_start = cpu_seconds(server.pid)
        time.sleep(5)
        idle = (cpu_seconds(server.pid) - idle_start) / 5
        cpu_start = cpu_seconds(server.pid)
        api_load = start_load(port, clients, 0, 0, ["idle"])
        time.sleep(seconds)
        cpu = cpu_seconds(server.pid) - cpu_start
        latencies = finish_load(api_load)["latencies"]
        finish_load(stream_load)
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
    parser.add_argument("--repeats", type=int, default=1,
                        help="rounds of the three phases, each printed, with the medians of their ratios")
    parser.add_argument("--cpu-per-request", action="store_true",
                        help="only the server's CPU per request: an idle model, --streams streams, --clients clients "
                             "with no think time for --seconds")
    args = parser.parse_args()
    if args.cpu_per_request:
        with tempfile.TemporaryDirectory(prefix="laplab-bench-") as folder:
            cpu_per_request(Path(folder), args.seconds, args.clients, args.streams)
        return
    ratios = []
    for repeat in range(args.repeats):
        with tempfile.TemporaryDirectory(prefix="laplab-bench-") as folder:
            root = Path(folder)
            base = {"steps": [None, None], "first": [None, None], "logs": [[], []]} if args.no_baseline \
                else baseline(root / "baseline", args.seconds)
            quiet = None if args.no_quiet_phase else with_server(root / "quiet", args.seconds, 0, 0, args.think)
            served = with_server(root / "served", args.seconds, args.clients, args.streams, args.think)
        if args.repeats > 1:
            print(f"round {repeat + 1} of {args.repeats}")
        ratios.append(report(args, base, quiet, served))
    if args.repeats > 1 and ratios[0]:
        medians = [statistics.median(r[i] for r in ratios) for i in range(len(ratios[0]))]
        print(f"median of {args.repeats} rounds, the same work under the load: {medians[0]:.2f}x as fast as without "
              f"the server" + ("" if len(medians) < 2 else f", {medians[1]:.2f}x as fast as console jobs with no clients"))


def report(args: argparse.Namespace, base: dict, quiet: dict | None, served: dict) -> list[float]:
    """Print one round's figures; return its trainings' equal-work speed ratios (under the load against
    without the server, and against the console with no clients when that phase ran)."""
    mean = lambda xs: statistics.mean([x for x in xs if x is not None] or [float("nan")])  # noqa: E731
    fmt = lambda xs: ", ".join("-" if x is None else f"{x:.1f}" for x in xs)  # noqa: E731
    lat, dl = served["latencies"], served["deliveries"]
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end")
    print(f"GET /api/models: {len(lat)} requests from {args.clients} clients (think {args.think:g} s): "
          f"p50 {1000 * percentile(lat, 50):.1f} ms, p99 {1000 * percentile(lat, 99):.1f} ms, errors {served['errors']}")
    if served["slow"]:
        when = ", ".join(f"{1000 * lat_s:.0f} ms at {t:.1f} s" for t, lat_s in sorted(served["slow"])[:12])
        print(f"  {len(served['slow'])} requests over 100 ms, the first: {when}")
    if served["cpu"] is not None and lat:
        print(f"server CPU during the load: {served['cpu']:.1f} s, {1000 * served['cpu'] / len(lat):.2f} ms per "
              f"GET /api/models answered (streams, scheduler and the other requests included); the load "
              f"generator's CPU (bench/http_load.py, same machine): {served['clients_cpu']:.1f} s")
    print(f"iteration events over {args.streams} streams: {len(dl)} delivered, p50 {1000 * percentile(dl, 50):.0f} ms, "
          f"p99 {1000 * percentile(dl, 99):.0f} ms, max {1000 * max(dl, default=float('nan')):.0f} ms")
    steps = lambda phase: f"{fmt(phase['steps'])} (mean {mean(phase['steps']):.1f})"  # noqa: E731
    print(f"env steps/s of 2 trainings (a training's env steps / wall s at its last iteration): without the server "
          f"{steps(base)}; as console jobs with no clients {'-' if quiet is None else steps(quiet)}; with the server "
          f"and the load {steps(served)}; final statuses {served['statuses']}")
    ratios = []
    for name, reference in (("without the server", base), ("as console jobs with no clients", quiet)):
        if reference is None or not any(reference["logs"]):
            continue
        same = equal_work_ratio(reference["logs"], served["logs"])
        if same is not None:
            ratios.append(same[0])
            print(f"  the same work (the first {same[1]} iterations, seeded) under the load ran {same[0]:.2f}x as fast as "
                  f"{name}")
        else:
            ratios.append(float("nan"))
            print(f"  {name}: not the same iterations (env steps differ), no equal-work ratio")
    print(f"  first iteration (s): without the server {fmt(base['first'])}; with the load {fmt(served['first'])}"
          + ("" if quiet is None else f"; no clients {fmt(quiet['first'])}"))
    if served["cpu"] is not None:
        print(f"  the server's share of the machine under the load: {served['cpu'] / (served['wall'] * os.cpu_count()):.1%}"
              f" of its CPU ({served['cpu']:.1f} s in {served['wall']:.0f} s on {os.cpu_count()} cores); the clients' "
              f"{served['clients_cpu'] / (served['wall'] * os.cpu_count()):.1%}")
    return ratios


if __name__ == "__main__":
    main()
