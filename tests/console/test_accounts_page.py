"""The admin's Accounts page in real Chromium: add a user (the token is shown once), disable them,
revoke their tokens, remove them; another user has no such page."""

from __future__ import annotations

from tests.console.conftest import signed_in_page


def test_the_admin_manages_accounts_in_the_browser(tmp_path, serve_console, admin_token):
    with serve_console(tmp_path / "home", workers=1, seed_numba=False) as console, \
            signed_in_page(console.url, admin_token) as page:
        page.click("text=Accounts")
        page.wait_for_selector("tr[data-user='admin']")
        page.fill("#new-user", "frank")
        page.click("#add-user button[type=submit]")
        page.wait_for_selector("tr[data-user='frank']")
        token = page.inner_text("#new-token").rsplit(" ", 1)[-1]
        frank = console.client(token)
        assert frank.get("/api/me").json()["name"] == "frank"
        assert frank.get("/users").status_code == 403
        page.click("tr[data-user='frank'] >> text=Disable")
        page.wait_for_selector("tr[data-user='frank'] >> text=disabled")
        assert frank.get("/api/me").status_code == 401
        page.click("tr[data-user='frank'] >> text=Enable")
        page.wait_for_selector("tr[data-user='frank'] >> text=active")
        assert frank.get("/api/me").status_code == 200
        page.click("tr[data-user='frank'] >> text=Revoke all tokens")
        page.wait_for_function("!document.querySelector(\"tr[data-user='frank']\").innerText.includes('login')")
        assert frank.get("/api/me").status_code == 401
        page.on("dialog", lambda dialog: dialog.accept())
        page.click("tr[data-user='frank'] >> text=Remove")
        page.wait_for_selector("tr[data-user='frank']", state="detached")
        page.screenshot(path=str(tmp_path / "accounts.png"), full_page=True)
