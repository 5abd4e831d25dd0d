"""``laplab users add NAME`` / ``laplab users list``: accounts of the console (``laplab serve``)."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    parser = subparsers.add_parser("users", help="console accounts: add a user (prints their token), list users")
    sub = parser.add_subparsers(dest="users_command", metavar="ACTION", required=True)
    add = sub.add_parser("add", help="create a user and print their login token (shown once)")
    add.add_argument("name", help="user name (letters, digits, '-', '_', '.')")
    add.add_argument("--admin", action="store_true", help="the user sees every model")
    add.add_argument("--no-sandbox", action="store_true",
                     help="create a user although this machine has no working bubblewrap sandbox (their reward "
                          "functions would run unconfined: the console must then be started with --no-sandbox)")
    add.set_defaults(func=run_add)
    token = sub.add_parser("token", help="print a new login token for an existing user")
    token.add_argument("name")
    token.set_defaults(func=run_token)
    listing = sub.add_parser("list", help="list users")
    listing.set_defaults(func=run_list)


def _store():
    from laplab.jobs.db import JobStore
    return JobStore()


def run_add(args: argparse.Namespace) -> int:
    from laplab.errors import UserError
    from laplab.jobs.db import StoreError
    if not args.admin and not args.no_sandbox:
        from laplab.console.safety import NO_SANDBOX_REFUSAL
        from laplab.jobs.confinement import bubblewrap_works
        if not bubblewrap_works():
            raise UserError(f"user {args.name!r} not created. {NO_SANDBOX_REFUSAL}".replace(
                "only the admin may log in", "only the admin may log in (`laplab users add --no-sandbox` creates "
                "the user anyway)"))
    store = _store()
    if store.admin() is None and not args.admin:
        from laplab.console.app import ensure_admin
        first = ensure_admin(store)
        print(f"created the admin first; its token (shown once): {first}")
    try:
        user, token = store.add_user(args.name, is_admin=args.admin)
    except StoreError as exc:
        raise UserError(str(exc)) from None
    print(f"user {user.name} created; login token (shown once, stored only hashed):\n{token}")
    return 0


def run_token(args: argparse.Namespace) -> int:
    from laplab.errors import UserError
    store = _store()
    user = store.user_by_name(args.name)
    if user is None:
        raise UserError(f"no user named {args.name!r} (laplab users list)")
    print(store.add_token(user.id, "cli"))
    return 0


def run_list(args: argparse.Namespace) -> int:
    for user in _store().users():
        print(f"{user.name}{'  (admin)' if user.is_admin else ''}")
    return 0
