"""``laplab`` command line: one entry point, subcommands registered by ``laplab.commands`` modules.

Each module in :data:`COMMAND_MODULES` exposes ``register(subparsers)``, which adds its parser and
sets ``func`` (``args -> exit code``). User errors (bad files, bad values) are printed as one paragraph
and exit with status 2; the commands themselves decide other exit codes.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# Commands raise laplab.errors.UserError; the name stays importable from here for compatibility.
from laplab.errors import UserError

COMMAND_MODULES = (
    "laplab.commands.run",
    "laplab.commands.drive",
    "laplab.commands.tracks",
    "laplab.commands.reward",
    "laplab.commands.train",
    "laplab.commands.evaluate",
    "laplab.commands.leaderboard",
    "laplab.commands.race",
    "laplab.commands.raceline",
    "laplab.commands.report",
    "laplab.commands.export",
    "laplab.commands.render",
    "laplab.commands.serve",
    "laplab.commands.users",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="laplab", description="A local, open and fast DeepRacer.")
    parser.add_argument("--version", action="version", version=f"laplab {_version()}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # a command not present in this build
                continue
            raise
        module.register(subparsers)
    return parser


def _version() -> str:
    from laplab import __version__
    return __version__


def user_error_types() -> tuple[type[BaseException], ...]:
    """Exceptions that describe bad user input (each carries a complete message)."""
    from laplab.env.action_space import ActionSpaceError
    from laplab.env.metadata import MetadataError
    from laplab.reward.errors import RewardFunctionError
    from laplab.agents.hyperparameters import HyperparameterError
    from laplab.store.atomic import CorruptFileError
    from laplab.store.layout import ModelNameError
    from laplab.track.geometry import TrackError
    from laplab.train.config import ConfigError
    from laplab.train.errors import JobError
    return (UserError, TrackError, MetadataError, ActionSpaceError, RewardFunctionError, FileNotFoundError,
            HyperparameterError, ModelNameError, ConfigError, JobError, CorruptFileError)


def main(argv: list[str] | None = None) -> int:
    """Run one command. Commands that run a job (``train``, ``clone``, ``evaluate``, ``run``) set
    ``job_limits`` and run in a child process under :mod:`laplab.jobs.supervisor` when started from
    the command line (``argv`` None); ``LAPLAB_SUPERVISOR=0`` runs them in this process."""
    from laplab.jobs import supervisor
    exec_job = supervisor.enter_job_from_environment()  # a job started by run_supervised(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    limits = getattr(args, "job_limits", None)
    if limits is not None and argv is None and supervisor.supervision_enabled():
        try:
            job_limits = limits(args)
        except user_error_types() as exc:
            print(f"laplab {args.command}: error: {exc}", file=sys.stderr)
            return 2
        return supervisor.run_supervised(lambda: _dispatch(args), job_limits, what=f"laplab {args.command}").exit_code
    code = _dispatch(args)
    if exec_job:
        supervisor.report(exit=code)
    return code


def _dispatch(args: argparse.Namespace) -> int:
    from laplab.jobs import sandbox, supervisor
    try:
        return int(args.func(args) or 0)
    except user_error_types() as exc:
        print(f"laplab {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        limit = supervisor.job_limits().memory_bytes if supervisor.in_job() else None
        message = ("the job ran out of memory" + (f" (its limit is {limit / 2**30:.1f} GiB: --memory-limit)"
                                                   if limit else "") + "; the model folder keeps every "
                   "checkpoint saved before that.")
        supervisor.job_failed(message)
        print(f"laplab {args.command}: error: {message}", file=sys.stderr)
        return 1
    finally:
        summary = sandbox.reward_output_summary()
        if summary:
            print(f"laplab: {summary}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
