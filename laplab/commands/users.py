"""``laplab users add | token | list | revoke | disable | enable | remove``: accounts of the console
(``laplab serve``). Changes reach a running console within a second."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    parser = subparsers.add_parser("users", help="console accounts: add a user (prints their token), list users")
    sub = parser.add_subparsers(dest="users_command", metavar="ACTION", required=True)
    add = sub.add_parser("add", help="create a user and print their login token (shown once)")
    add.add_argument("name", help="user name (letters, digits, '-', '_', '.')")
    add.add_argument("--admin", action="store_true", help="the user sees every model")
    add.add_argument("--role", choices=("admin", "facilitator", "racer"), default=None,
                     help="the user's role (default: racer; admin with --admin); facilitators run races")
    add.add_argument("--no-sandbox", action="store_true",
                     help="create a user although this machine has no working bubblewrap sandbox (their reward "
                          "functions would run unconfined: the console must then be started with --no-sandbox)")
    add.set_defaults(func=run_add)
    token = sub.add_parser("token", help="print a new login token for an existing user")
    token.add_argument("name")
    token.set_defaults(func=run_token)
    listing = sub.add_parser("list", help="list users")
    listing.add_argument("--tokens", action="store_true", help="also each user's token ids and labels")
    listing.set_defaults(func=run_list)
    revoke = sub.add_parser("revoke", help="revoke a user's tokens (all, or one by its id) and end their sessions")
    revoke.add_argument("name")
    revoke.add_argument("token_id", nargs="?", default=None, help="the token's id (the part before its dot)")
    revoke.set_defaults(func=run_revoke)
    for action, text in (("disable", "a disabled user can no longer log in or use a token (their models stay)"),
                         ("enable", "let a disabled user in again")):
        command = sub.add_parser(action, help=text)
        command.add_argument("name")
        command.set_defaults(func=run_disable, disabled=action == "disable")
    remove = sub.add_parser("remove", help="remove a user: their tokens and sessions end, their models pass to "
                                           "the admin")
    remove.add_argument("name")
    remove.set_defaults(func=run_remove)


def _store():
    from laplab.jobs.db import JobStore
    return JobStore()


def run_add(args: argparse.Namespace) -> int:
    from laplab.errors import UserError
    from laplab.jobs.db import StoreError
    if args.admin and args.role not in (None, "admin"):
        raise UserError(f"--admin and --role {args.role} contradict each other: give one of them")
    args.admin = args.admin or args.role == "admin"
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
        user, token = store.add_user(args.name, is_admin=args.admin, role=args.role)
    except StoreError as exc:
        raise UserError(str(exc)) from None
    if not user.is_admin:  # every new account starts with the new-user quota, however it was made
        from laplab.jobs.quotas import Quotas
        Quotas(store).apply_new_user_quota(user.id)
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
    for user in _store().user_rows():
        print(f"{user['name']}  ({user['role']}){'  (disabled)' if user['disabled'] else ''}")
        if args.tokens:
            for token in user["tokens"]:
                print(f"    token {token['id']}  {token['label']}")
    return 0


def _change(change) -> None:
    from laplab.errors import UserError
    from laplab.jobs.db import StoreError
    try:
        return change(_store())
    except StoreError as exc:
        raise UserError(str(exc)) from None


def run_revoke(args: argparse.Namespace) -> int:
    count = _change(lambda store: store.revoke_tokens(args.name, args.token_id))
    print(f"revoked {count} token(s) of {args.name} and ended their sessions")
    return 0


def run_disable(args: argparse.Namespace) -> int:
    _change(lambda store: store.set_disabled(args.name, args.disabled))
    print(f"{args.name} {'disabled' if args.disabled else 'enabled'}")
    return 0


def run_remove(args: argparse.Namespace) -> int:
    moved = _change(lambda store: store.remove_user(args.name))
    print(f"removed {args.name}; {moved} model(s) passed to the admin")
    return 0
