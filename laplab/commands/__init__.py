"""Implementations of the ``laplab`` subcommands (each module: ``register(subparsers)``)."""
