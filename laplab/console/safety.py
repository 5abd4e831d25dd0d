"""Safe by default: a console whose jobs are not sandboxed serves only its admin.

Without bubblewrap a job runs another user's reward function as the server's own user: it can read
the secret key, the database, every model folder and the server's environment, and reach the
network. So unless the operator says so explicitly (``laplab serve --no-sandbox``), a console
without the sandbox refuses to log in or create any user but the admin; with ``--no-sandbox`` every
page carries a banner saying that jobs are not confined.
"""

from __future__ import annotations

from fastapi import HTTPException

NO_SANDBOX_REFUSAL = (
    "This console runs without its sandbox (bubblewrap is missing or cannot build its namespaces here), so "
    "a user's reward function would run as the server's own user, able to read the server's secret key, its "
    "database, other users' reward functions and models and the server's environment, and to reach the "
    "network: only the admin may log in. The operator fixes it with `sudo apt-get install bubblewrap` and a "
    "restart of `laplab serve` (or accepts the risk, for users who are all trusted, with `laplab serve "
    "--no-sandbox`).")

NO_SANDBOX_BANNER = ("Jobs on this console are NOT sandboxed (laplab serve --no-sandbox): every user's reward "
                     "function runs as the server's user and can read the other users' models and the "
                     "server's secrets.")


def unconfined(state) -> bool:
    """Whether this app's jobs run without bubblewrap."""
    return not getattr(state, "sandbox", True)


def may_admit(state, is_admin: bool) -> bool:
    """Whether a user may log in / be created: always the admin; others only with the sandbox or
    when the operator allowed an unconfined console (``--no-sandbox``)."""
    return is_admin or not unconfined(state) or bool(getattr(state, "allow_unsandboxed", False))


def refuse_unless_admitted(state, is_admin: bool) -> None:
    """403 with :data:`NO_SANDBOX_REFUSAL` for a non-admin on a console without its sandbox."""
    if not may_admit(state, is_admin):
        raise HTTPException(403, {"message": NO_SANDBOX_REFUSAL})


NO_SANDBOX_ADMIN_BANNER = ("Jobs on this console are not sandboxed (bubblewrap is missing): only the admin can "
                           "log in. Install it (`sudo apt-get install bubblewrap`) and restart `laplab serve`.")


def banner(state) -> str | None:
    """The banner of every page (None with the sandbox)."""
    if not unconfined(state):
        return None
    return NO_SANDBOX_BANNER if getattr(state, "allow_unsandboxed", False) else NO_SANDBOX_ADMIN_BANNER


def banner_html(state) -> str:
    """The banner as a block of HTML (empty without one), for pages not built from base.html."""
    text = banner(state)
    if text is None:
        return ""
    return ('<div class="unsandboxed-banner" role="alert" style="background:#d13212;color:#fff;padding:8px 24px;'
            f'font:600 14px system-ui,sans-serif">{text}</div>')
