"""``laplab serve``: the console in a browser, on the job service (FastAPI + uvicorn)."""

from __future__ import annotations

import argparse
import ipaddress
import math


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "serve", help="start the console (web pages and JSON API) with its job service",
        description="Serve DeepRacer's console for laplab: create, train, evaluate, clone, import and download "
                    "models in a browser, with accounts and a shared leaderboard. Jobs run as confined child "
                    "processes, at most --workers at a time. See docs/console.md.")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8080, help="port (default 8080)")
    parser.add_argument("--workers", type=int, default=None, help="jobs run at once (default: one per two cores)")
    parser.add_argument("--job-wall-margin", type=float, default=600.0, metavar="SECONDS",
                        help="wall-clock seconds a job may run past its own budget (a training's max time, an "
                             "evaluation's trials x max trial time) before the server ends it (default 600)")
    parser.add_argument("--max-job-time", default="24h", metavar="DURATION",
                        help="the longest training a user may ask for (e.g. 90m, 24h; default 24h, as DeepRacer "
                             "on AWS's 1440 minutes): a longer max time is refused")
    parser.add_argument("--evaluation-priority", default=None, metavar="NICE|idle",
                        help="how far evaluation jobs (evaluations, race submissions, head-to-model races) run below "
                             "trainings on the CPU: a niceness 0..19 (default 10; 0: the same priority) or 'idle' "
                             "(Linux SCHED_IDLE). Trainings keep their speed while a class races; on a busy machine "
                             "evaluations take longer (docs/console.md, 'CPU priority')")
    parser.add_argument("--max-upload", default="1G", metavar="SIZE",
                        help="the largest archive `Import` accepts (default 1G); other requests take at most 1 MiB")
    parser.add_argument("--ray-address", default=None, metavar="ADDR",
                        help="run the rollout workers of training jobs on the Ray cluster at ADDR; sandboxed jobs "
                             "join through Ray Client, ray://HEAD:10001. Those jobs keep the network (no other "
                             "access) and the cluster's Ray token, and reward functions then run in the cluster's "
                             "worker processes, as the cluster's user on its nodes: keep the console's secrets off "
                             "those nodes (docs/console.md, 'Jobs on a Ray cluster')")
    parser.add_argument("--rollout-workers", type=int, default=None, metavar="N",
                        help="with --ray-address: rollout workers per training job, as deepracer-for-cloud's "
                             "DR_WORKERS (default 2; a request's `workers` may ask for fewer)")
    parser.add_argument("--no-sandbox", action="store_true",
                        help="run jobs without bubblewrap and still let users other than the admin in: every "
                             "user's reward function then runs as the server's user and can read the database, the "
                             "secret key and other users' models (a banner on every page says so). Without this "
                             "flag a console whose sandbox is missing serves only its admin")
    parser.add_argument("--no-accounts", action="store_true",
                        help="everyone is the admin, no login (only with a loopback --host)")
    parser.set_defaults(func=run)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def run(args: argparse.Namespace) -> int:
    from laplab.errors import UserError
    try:
        import uvicorn

        from laplab.console.app import create_app
    except ImportError as exc:
        raise UserError(f"the console needs its extra: pip install -e \".[console]\" ({exc})") from None
    if args.no_accounts and not is_loopback(args.host):
        raise UserError(f"--host {args.host} serves other machines: it works only with accounts on "
                        "(drop --no-accounts); everyone on the network could otherwise run code as you.")
    if args.workers is not None and args.workers < 1:
        raise UserError(f"--workers must be >= 1, got {args.workers}")
    if not 0 < args.port < 65536:
        raise UserError(f"--port must be within 1..65535, got {args.port}")
    if not (args.job_wall_margin > 0 and math.isfinite(args.job_wall_margin)):
        raise UserError(f"--job-wall-margin must be a positive number of seconds, got {args.job_wall_margin}")
    from laplab.jobs.confinement import JobLimits
    from laplab.jobs.supervisor import parse_memory_limit
    from laplab.train.config import ConfigError, parse_duration
    try:
        max_time = parse_duration(args.max_job_time)
        max_upload = parse_memory_limit(args.max_upload)
    except (ConfigError, ValueError) as exc:
        raise UserError(f"--max-job-time / --max-upload: {exc}") from None
    from laplab.jobs.priority import DEFAULT_EVALUATION_PRIORITY, parse_priority
    evaluation_priority = parse_priority(DEFAULT_EVALUATION_PRIORITY if args.evaluation_priority is None
                                         else args.evaluation_priority, "--evaluation-priority")
    cluster, warnings = _cluster(args)
    limits = JobLimits.console(wall_margin_s=args.job_wall_margin, max_time_s=max_time,
                               evaluation_priority=evaluation_priority)
    app = create_app(args.workers, open_access=args.no_accounts, limits=limits, cluster=cluster,
                     sandbox=False if args.no_sandbox else None, allow_unsandboxed=args.no_sandbox,
                     max_upload_bytes=max_upload or (1 << 40))
    store, service = app.state.store, app.state.service
    admin = store.admin()
    token = app.state.first_token
    if token is None and not args.no_accounts:
        token = store.add_token(admin.id, "serve-link", lifetime_s=24 * 3600.0)
    shown = "127.0.0.1" if args.host in ("0.0.0.0", "::") else args.host
    url = f"http://{shown}:{args.port}/"
    from laplab.console.safety import NO_SANDBOX_BANNER, NO_SANDBOX_REFUSAL
    print(f"laplab console: {service.workers} job worker(s), jobs "
          f"{'sandboxed with bubblewrap' if app.state.sandbox else 'NOT sandboxed: limits and a clean environment only'}")
    if not app.state.sandbox:
        print(f"warning: {NO_SANDBOX_BANNER if args.no_sandbox else NO_SANDBOX_REFUSAL}", flush=True)
    print("evaluation jobs run " + ("at the trainings' CPU priority" if evaluation_priority == 0 else
                                    "with SCHED_IDLE (CPU time the trainings leave)" if evaluation_priority == "idle"
                                    else f"{evaluation_priority} nice levels below the trainings"), flush=True)
    if cluster is not None:
        print(f"training jobs run {cluster.workers} rollout worker(s) each on the Ray cluster at {cluster.address} "
              "(their jobs keep the network)")
    for warning in warnings:
        print(f"warning: {warning}", flush=True)
    for job in service.interrupted_at_start:
        print(f"  job {job.id} ({job.kind} {job.model}) was interrupted by the last shutdown: resume it from its page")
    if args.no_accounts:
        print(f"open {url} (no accounts: loopback only)", flush=True)
    else:
        print(f"open {url}login?token={token}", flush=True)
        if app.state.first_token:
            print(f"the admin's token (shown once; `laplab users add NAME` adds users): {token}", flush=True)
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning")
    return 0


def _cluster(args: argparse.Namespace):
    """The Ray cluster of ``--ray-address`` (checked: reachable, joinable from a sandboxed job) and
    its warnings, or (None, []) without one."""
    from laplab.errors import UserError
    if args.ray_address is None:
        if args.rollout_workers is not None:
            raise UserError("--rollout-workers needs --ray-address: without a cluster each job collects in its own process")
        return None, []
    from laplab.cluster.console import DEFAULT_ROLLOUT_WORKERS, RayCluster, check_console_cluster
    from laplab.jobs.confinement import bubblewrap_works
    workers = DEFAULT_ROLLOUT_WORKERS if args.rollout_workers is None else args.rollout_workers
    warnings = check_console_cluster(args.ray_address, workers, bubblewrap_works())
    return RayCluster.at(args.ray_address, workers), warnings
