"""``laplab`` command line: one entry point, subcommands registered by ``laplab.commands`` modules.

Each module in :data:`COMMAND_MODULES` exposes ``register(subparsers)``, which adds its parser and
sets ``func`` (``args -> exit code``). User errors (bad files, bad values) are printed as one paragraph
and exit with status 2; the commands themselves decide other exit codes.
"""

from __future__ import annotations

import argparse
import importlib
import sys

COMMAND_MODULES = (
    "laplab.commands.run",
    "laplab.commands.drive",
    "laplab.commands.tracks",
    "laplab.commands.reward",
    "laplab.commands.train",
    "laplab.commands.evaluate",
    "laplab.commands.leaderboard",
    "laplab.commands.raceline",
    "laplab.commands.report",
    "laplab.commands.export",
    "laplab.commands.render",
    "laplab.commands.serve",
    "laplab.commands.users",
)


class UserError(Exception):
    """An error caused by the user's input; printed without a traceback."""


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
    from laplab.store.layout import ModelNameError
    from laplab.track.geometry import TrackError
    from laplab.train.config import ConfigError
    from laplab.train.errors import JobError
    return (UserError, TrackError, MetadataError, ActionSpaceError, RewardFunctionError, FileNotFoundError,
            HyperparameterError, ModelNameError, ConfigError, JobError)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except user_error_types() as exc:
        print(f"laplab {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
