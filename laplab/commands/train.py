"""``laplab train`` and ``laplab clone``: training jobs with a live progress display."""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path

from rich.console import Console

from laplab.agents.hyperparameters import PRECISIONS


def _add_job_options(parser: argparse.ArgumentParser, defaults: bool) -> None:
    none = None
    parser.add_argument("--track", action="append", default=none,
                        help="track name or .npy path (default: classic_2018); NAME@reversed drives it the other "
                             "way; repeat it for a multi-track job (rollout worker i drives track i mod count)")
    parser.add_argument("--reward", default=none, help="reward_function.py (default: laplab's lap_pace example)")
    parser.add_argument("--model-metadata", default=none, help="model_metadata.json (action space, sensors, network)")
    parser.add_argument("--hyperparameters", default=none,
                        help="hyperparameters.json, or the JSON itself, e.g. '{\"num_epochs\": 5}' (other keys keep "
                             "their defaults)")
    from laplab.train.request import TrainRequest
    default = TrainRequest()  # the defaults of every door (laplab.train.request)
    parser.add_argument("--max-time", default=none,
                        help="stop after this long (e.g. 90s, 20m, 1h; default " +
                             (f"{default.max_time_s / 60:g}m)" if defaults else "the source's)"))
    parser.add_argument("--max-episodes", type=int, default=none, help="stop after this many training episodes")
    parser.add_argument("--seed", type=int, default=none,
                        help=f"random seed (default {default.seed})" if defaults else "random seed")
    parser.add_argument("--physics", default=none, metavar="V",
                        help="DeepRacer's car to train with: 4, 5 or 6 (model_metadata.json's version decides by "
                             "default; no version: 6, DeepRacer on AWS's) or classic (laplab's car before them)")
    from laplab.commands.store_option import add_store_option
    add_store_option(parser)


def _add_scale_options(parser: argparse.ArgumentParser) -> None:
    """Rollout workers on Ray and the learner's device (docs/scaleout.md)."""
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="rollout workers (Ray actors) sharing each iteration's episodes (default 1: "
                             "in-process, no Ray; a resumed job may change it)")
    parser.add_argument("--ray-address", default=None, metavar="ADDR",
                        help="join the Ray cluster at ADDR (`ray start --head` prints it) instead of a local Ray")
    parser.add_argument("--device", default="cpu", help="the learner's torch device: cpu (default) or cuda")


def add_limit_options(parser: argparse.ArgumentParser, reward: bool = True) -> None:
    """The job sandbox's options (see laplab.jobs.supervisor.JobLimits and docs/reliability.md)."""
    parser.add_argument("--memory-limit", default="75%", metavar="SIZE",
                        help="memory the job may use, e.g. 4G, 50%% (of this machine's), none (default 75%%)")
    parser.add_argument("--cpu-limit", default=None, metavar="DURATION",
                        help="CPU time the job may use in all (e.g. 2h; default unlimited)")
    if reward:
        parser.add_argument("--reward-timeout", type=float, default=None, metavar="S",
                            help="CPU seconds one step's reward-function calls may take (default 5)")
    parser.set_defaults(job_limits=job_limits_from_args)


def job_limits_from_args(args: argparse.Namespace):
    from laplab.errors import UserError
    from laplab.jobs.supervisor import JobLimits, parse_memory_limit
    from laplab.train.config import parse_duration
    try:
        memory = parse_memory_limit(args.memory_limit)
        cpu = parse_duration(args.cpu_limit) if args.cpu_limit else None
    except ValueError as exc:
        raise UserError(str(exc)) from None
    timeout = getattr(args, "reward_timeout", None)
    if timeout is not None and not timeout > 0:
        raise UserError(f"--reward-timeout must be a positive number of seconds, got {timeout:g}")
    return JobLimits(memory_bytes=memory, cpu_seconds=cpu, **({"reward_timeout_s": timeout} if timeout else {}))


def register(subparsers) -> None:
    train = subparsers.add_parser("train", help="train a model (PPO or SAC) with a reward function")
    train.add_argument("--name", help="name of the new model (letters, digits, hyphens)")
    train.add_argument("--resume", metavar="NAME", help="continue an interrupted job from its last checkpoint")
    _add_job_options(train, defaults=True)
    train.add_argument("--domain-randomization", action="store_true",
                       help="randomise camera frames in training (lighting, colours, noise, jitter) for the car")
    train.add_argument("--precision", choices=PRECISIONS, default="auto",
                       help="network arithmetic in training (auto: bfloat16 for camera networks on CPUs "
                            "with native bfloat16, else float32)")
    _add_scale_options(train)
    train.add_argument("--quiet", action="store_true", help="print only the summary")
    from laplab.commands.race_options import add_race_options
    add_race_options(train)
    train.add_argument("--trust-reward", action="store_true",
                       help="run the reward function of an imported model (--resume); recorded, asked once")
    add_limit_options(train)
    train.set_defaults(func=run_train)
    clone = subparsers.add_parser("clone", help="start a new model from another model's weights")
    clone.add_argument("source", help="the model to start from (its best checkpoint)")
    clone.add_argument("name", help="name of the new model")
    _add_job_options(clone, defaults=False)
    _add_scale_options(clone)
    clone.add_argument("--quiet", action="store_true")
    clone.add_argument("--trust-reward", action="store_true",
                       help="run the source's reward function when it came from an imported archive; recorded")
    add_limit_options(clone)
    clone.set_defaults(func=run_clone)


def train_request(args: argparse.Namespace, name: str | None = None):
    """The :class:`~laplab.train.request.TrainRequest` the options ask for (files read and checked);
    an error's ``field`` is the option's name (``--max-time``), its message the request's."""
    from laplab.agents.hyperparameters import load_hyperparameters, parse_hyperparameters
    from laplab.env.metadata import load_model_metadata
    from laplab.errors import UserError
    from laplab.train.config import parse_duration
    from laplab.train.request import TrainRequest, as_cli_error
    from laplab.commands.race_options import race_type_from_args
    try:
        values = {"name": name, "tracks": tuple(args.track or ()), "max_episodes": args.max_episodes,
                  "seed": args.seed, "physics": getattr(args, "physics", None), "workers": args.workers,
                  "reward_path": str(Path(args.reward).resolve()) if args.reward else None}
        if args.max_time:
            try:
                values["max_time_s"] = parse_duration(args.max_time)
            except UserError as exc:
                raise type(exc)(str(exc), field="max_time_s") from None
        if args.model_metadata:
            values["model_metadata"] = load_model_metadata(args.model_metadata).to_dict()
        if args.hyperparameters and args.hyperparameters.lstrip().startswith(("{", "[", '"')):  # JSON, not a file
            values["hyperparameters"] = parse_hyperparameters(args.hyperparameters, "--hyperparameters").to_dict()
        elif args.hyperparameters:
            values["hyperparameters"] = load_hyperparameters(args.hyperparameters).to_dict()
        if hasattr(args, "race_type"):
            race = race_type_from_args(args)
            values["race_type"] = race.to_dict() if race is not None else None
        if hasattr(args, "precision"):
            values["precision"] = args.precision
            values["domain_randomization"] = bool(args.domain_randomization)
        request = TrainRequest.from_mapping(values)
        if request.domain_randomization:
            request.to_config()  # refused for a model without a camera before anything is written
        return request
    except UserError as exc:
        raise as_cli_error(exc) from None


def _overrides(args: argparse.Namespace) -> dict:
    """A clone's (or a resume's) changes to its source's config: what the options name, None elsewhere."""
    request = train_request(args)
    values = request.config_values()
    out = {key: values.get(key) for key in ("track", "tracks", "reward_path", "max_episodes", "model_metadata",
                                            "hyperparameters", "vehicle")}
    out["tracks"] = values.get("tracks", () if args.track else None)
    out["seed"] = args.seed
    out["max_time_s"] = request.max_time_s if args.max_time else None
    return {k: v for k, v in out.items() if v is not None}


class _Flag:
    """A flag a signal handler may set at any moment, even while it is being set or read (a
    threading.Event takes a lock: a second signal arriving inside ``set()`` deadlocked on it)."""

    def __init__(self):
        self._set = False

    def set(self) -> None:
        self._set = True

    def is_set(self) -> bool:
        return self._set


class _StopFlag:
    """SIGINT / SIGTERM set a flag the trainer polls; a second one (either) interrupts at once."""

    def __init__(self):
        self.event = _Flag()
        self._previous = {}
        self._depth = 0  # entered again by run_trainer: the handlers are installed once

    def __enter__(self):
        self._depth += 1
        if self._depth == 1 and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame):
        if self.event.is_set():  # asked twice: stop now (the model keeps its last checkpoint)
            raise KeyboardInterrupt
        self.event.set()

    def __exit__(self, *exc):
        self._depth -= 1
        if self._depth == 0:
            for sig, handler in self._previous.items():
                signal.signal(sig, handler)
            self._previous = {}


def watch_limits(reward_timeout: float | None = None):
    """The job's limits on reward calls (:class:`laplab.reward.watchdog.WatchdogLimits`): ``--reward-timeout``
    or the supervisor's, for the job's own process and its rollout workers alike."""
    from laplab.jobs.supervisor import job_limits
    from laplab.reward.watchdog import WatchdogLimits
    limits = job_limits()
    return WatchdogLimits(reward_timeout or limits.reward_timeout_s, limits.reward_wait_timeout_s)


def run_trainer(trainer, console: Console, quiet: bool, reward_timeout: float | None = None,
                stop: _StopFlag | None = None, location: str | None = None) -> int:
    """Run ``trainer`` with the progress display, Ctrl-C handling, the reward watchdog and reports
    to the job's supervisor (when there is one), then close it (its rollout workers, if it was given
    any, stop; the model folder's lock is released). ``stop``: a flag entered before the trainer was
    built (a Ctrl-C during set-up then stops the job at its first check); ``location``: where the
    summary says the model is (an object store's URL; None: the model folder)."""
    from laplab.jobs.supervisor import report
    from laplab.reward.watchdog import RewardWatchdog
    from laplab.train.progress import ProgressPrinter
    with trainer:  # the job is over when this ends: workers stopped, the folder free for the next job
        name = trainer.folder.name
        report(folder=str(trainer.folder.root), model=name, what="training job",
               resume=f"laplab train --resume {name}", reward_path=trainer.reward_fn.path,
               **({"iteration": trainer.iteration} if trainer.iteration else {}))
        printer = ProgressPrinter(console, trainer, quiet, location=location)
        with (stop or _StopFlag()) as stop, RewardWatchdog(watch_limits(reward_timeout)):
            result = trainer.run(callbacks=(printer, lambda r: report(iteration=r.iteration)),
                                 should_stop=stop.event.is_set)
    printer.summary(result)
    return 1 if result.error else 0


def _workers(args: argparse.Namespace, console: Console):
    """How the job's rollout workers start (:class:`laplab.cluster.launch.RayWorkers`): on Ray for
    several workers or a cluster address, else none (the in-process path: Ray is not even imported).
    Their start and restarts are printed, restarts also logged in the model folder."""
    from laplab.cluster.launch import RayWorkers
    watch = watch_limits(args.reward_timeout)
    return RayWorkers(args.ray_address, notify=lambda message: console.print(f"[yellow]{message}[/yellow]"),
                      announce=console.print, reward_timeout_s=watch.timeout_s,
                      reward_wait_timeout_s=watch.wait_timeout_s)


def _scale(args: argparse.Namespace) -> tuple[int | None, str]:
    """(--workers, the learner's device), the cluster reachable, before any folder is written (the
    request checks --workers' range)."""
    from laplab.cluster.launch import resolve_device
    if args.ray_address:
        from laplab.cluster.collector import check_reachable
        check_reachable(args.ray_address)
    return args.workers, resolve_device(args.device)


def run_train(args: argparse.Namespace) -> int:
    from laplab.errors import UserError
    from laplab.train.jobs import create_training, resume_training

    from laplab.commands.store_option import store_session

    console = Console(highlight=False, soft_wrap=True)
    if args.resume and args.name:
        raise UserError("give either --name (a new model) or --resume NAME, not both")
    if not args.resume and not args.name:
        raise UserError("name the new model with --name NAME (or continue one with --resume NAME)")
    if args.resume:
        kept = (("--reward", args.reward, "reward function"), ("--track", args.track, "tracks"),
                ("--hyperparameters", args.hyperparameters, "hyperparameters"),
                ("--model-metadata", args.model_metadata, "model_metadata.json"),
                ("--physics", args.physics, "car (its physics)"),
                ("--race-type", args.race_type, "race type"))
        for option, value, what in kept:
            if value:  # refused, not checked and then ignored
                raise UserError(f"a resumed job keeps its {what} (laplab.json records it); to train with another, "
                                f"`laplab clone {args.resume} NEW {option} ...` (a clone keeps the action space "
                                "and the sensors).", field=option)
        from laplab.train.request import TrainRequest
        max_time = _overrides(args).get("max_time_s", TrainRequest().max_time_s)
    else:
        request = train_request(args, args.name)
    workers, device = _scale(args)
    with _StopFlag() as stop, store_session(args, "train") as store:  # Ctrl-C while setting up: a clean stop
        location = store.remote.url(args.resume or args.name) if store else None  # what the summary names
        if args.resume:
            listeners = store.resume_job(args.resume) if store else ()
            trainer = resume_training(args.resume, max_time, args.max_episodes,
                                      trust_reward=args.trust_reward, workers=workers, device=device,
                                      listeners=listeners, launcher=_workers(args, console))
            console.print(f"resuming {args.resume} at iteration {trainer.iteration} ({trainer.episodes} episodes)")
        else:
            listeners = store.create_job(args.name) if store else ()
            trainer = create_training(args.name, request.to_config(), listeners=listeners, device=device,
                                      launcher=_workers(args, console))
        return run_trainer(trainer, console, args.quiet, args.reward_timeout, stop, location)


def run_clone(args: argparse.Namespace) -> int:
    from laplab.train.jobs import clone_config, create_training

    from laplab.commands.store_option import store_session, without_traces

    console = Console(highlight=False, soft_wrap=True)
    workers, device = _scale(args)
    with _StopFlag() as stop, store_session(args, "clone") as store:  # Ctrl-C while setting up: a clean stop
        if store:
            store.pull(args.source, ("best",), without_traces)
        config, weights = clone_config(args.source, {**_overrides(args), "workers": workers},
                                       trust_reward=args.trust_reward)
        listeners = store.create_job(args.name) if store else ()
        location = store.remote.url(args.name) if store else None  # what the summary names
        trainer = create_training(args.name, config, init_weights=weights, listeners=listeners, device=device,
                                  launcher=_workers(args, console))
        console.print(f"cloned {args.source} -> {args.name}")
        return run_trainer(trainer, console, args.quiet, args.reward_timeout, stop, location)
