"""A class's race in real Chromium: the admin invites a facilitator and racers through links; the
facilitator signs up and creates a private race; the racers sign up, join by its code and submit
their models; the live board ranks them (top three highlighted, the newest laps replayed); a racer
over quota is refused; a racer cannot open another racer's models or submission files. Screenshots
go to the test's folder (``LAPLAB_SCREENSHOTS=docs`` writes docs/races-*.png)."""

from __future__ import annotations

import os
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

playwright_api = pytest.importorskip("playwright.sync_api")
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
        "--disable-sync", "--disable-dev-shm-usage"]

TINY = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}
pytestmark = pytest.mark.skipif(not shutil.which("chromium"), reason="chromium is not installed (apt-get install chromium)")


def seeded_model(console, user_name: str, model: str, seed: int) -> None:
    """A tiny untrained model of ``user_name`` (its initial weights from ``seed``)."""
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    store = console.app.state.store
    user = store.user_by_name(user_name)
    config = replace(TrainConfig(), hyperparameters={**TrainConfig().hyper().to_dict(), **TINY},
                     max_time_s=5.0, seed=seed)
    create_training(f"u{user.id}-{model}", config)
    store.claim_model(f"u{user.id}-{model}", user.id)
    console.app.state.service.models_changed()


def sign_up_in_browser(browser, url: str, link: str, name: str, alias: str, country: str):
    page = browser.new_context(viewport={"width": 1360, "height": 900}).new_page()
    page.set_default_timeout(30_000)
    page.goto(link)
    page.fill("#name", name)
    page.fill("#password", f"{name}-password")
    page.fill("#alias", alias)
    page.fill("#country", country)
    page.click("#signup-form button[type=submit]")
    page.wait_for_url(f"{url}/races")
    return page


def test_a_class_race_in_chromium(tmp_path, serve_console, admin_token):
    shots = Path(os.environ.get("LAPLAB_SCREENSHOTS") or tmp_path)
    shots.mkdir(parents=True, exist_ok=True)
    shoot = lambda page, name: page.screenshot(path=str(shots / f"races-{name}.png"))  # noqa: E731
    with serve_console(tmp_path / "home", workers=2) as console, playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True, timeout=60_000)
        try:
            url = console.url
            admin = browser.new_context(viewport={"width": 1360, "height": 900}).new_page()
            admin.set_default_timeout(30_000)
            admin.goto(f"{url}/login")
            admin.fill("#token", admin_token)
            admin.click("button[type=submit]")
            admin.wait_for_url(f"{url}/")
            admin.click("text=Invitations")
            links = {}
            for name, role in (("fay", "facilitator"), ("rita", "racer"), ("ravi", "racer"), ("rosa", "racer")):
                admin.select_option("#invite-role", role)
                admin.click("#create-invite")
                admin.wait_for_function(f"document.querySelectorAll('#invites tbody tr').length === {len(links) + 1}")
                links[name] = admin.input_value("#invite-link-text")
            shoot(admin, "invites")

            fay = sign_up_in_browser(browser, url, links["fay"], "fay", "Ms Fay", "GB")
            assert fay.inner_text("#role-tag") == "facilitator"
            fay.click("#new-race")
            fay.wait_for_selector("#track option[value='oval']", state="attached")
            fay.fill("#name", "Period 3 Grand Prix")
            fay.fill("#description", "Best lap on the oval; two laps per submission.")
            fay.select_option("#track", "oval")
            fay.select_option("#ranking", "best_lap")
            fay.fill("#laps", "2")
            fay.fill("#max_submissions", "3")
            fay.check("#private")
            shoot(fay, "create")
            fay.click("#save-race")
            fay.wait_for_selector("#race-code:not(:empty)")
            code = fay.inner_text("#race-code")
            race_id = int(fay.url.rstrip("/").rsplit("/", 1)[-1])

            racers = {}
            for seed, (name, alias, country) in enumerate((("rita", "Rita Racer", "DE"), ("ravi", "Ravi K", "IN"),
                                                            ("rosa", "Rosa Speed", "ES")), start=1):
                page = sign_up_in_browser(browser, url, links[name], name, alias, country)
                seeded_model(console, name, f"{name}-model", seed)
                page.fill("#join-code", code)
                page.click("#join-form button[type=submit]")
                page.wait_for_url(f"{url}/races/{race_id}")
                page.wait_for_selector(f"#model option[value='{name}-model']", state="attached")
                page.click("#submit-model")
                page.wait_for_selector("#submit-result.ok")
                racers[name] = page
            shoot(racers["rita"], "race")

            board = browser.new_context(viewport={"width": 1600, "height": 900}).new_page()
            board.context.add_cookies(fay.context.cookies())
            board.goto(f"{url}/races/{race_id}/board")
            board.wait_for_function("+document.querySelector('#board-rows').dataset.count === 3", timeout=600_000)
            board.wait_for_selector(".board-row.top1")
            board.wait_for_function("+document.querySelector('#replay').dataset.frames > 60", timeout=60_000)
            # the board shows a new result within 2 s of its evaluation's end (it polls every second)
            jobs = [console.app.state.store.job(s["job"]) for s in console.admin.get(f"/api/races/{race_id}/submissions").json()]
            shown_at = float(board.get_attribute("#board-rows", "data-changed-at")) / 1000.0
            assert shown_at - max(j.finished for j in jobs) < 2.0
            ranks = board.eval_on_selector_all(".board-row", "rows => rows.map(r => r.dataset.rank)")
            assert ranks == ["1", "2", "3"]
            shoot(board, "board")

            # over quota: refused on the page with the rule, nothing queued
            console.admin.put("/api/users/ravi/quota", json={"minutes": 0.5})
            ravi = racers["ravi"]
            ravi.reload()
            ravi.wait_for_selector("#model option[value='ravi-model']", state="attached")
            ravi.click("#submit-model")
            ravi.wait_for_selector("#submit-result.field-error")
            assert "quota" in ravi.inner_text("#submit-result")
            ravi.wait_for_function("document.querySelectorAll('#subs tbody tr').length === 1")
            shoot(ravi, "quota")

            # a racer cannot open another racer's models or submission files
            rita = racers["rita"]
            subs = console.admin.get(f"/api/races/{race_id}/submissions").json()
            ravi_sub = next(s for s in subs if s["alias"] == "Ravi K")
            assert rita.request.get(f"{url}/api/races/{race_id}/submissions/{ravi_sub['id']}/video").status == 404
            assert rita.request.get(f"{url}/api/models/ravi-model").status == 404
            assert rita.request.get(f"{url}/models/ravi-model").status == 404
            assert ravi.request.get(f"{url}/api/races/{race_id}/submissions/{ravi_sub['id']}/video").status == 200
        finally:
            browser.close()
