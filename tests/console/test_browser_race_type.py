"""The Create form's race type in real Chromium: object avoidance with 2 boxes is what the new model's
laplab.json records and its page shows; the domain randomisation checkbox is for camera sensors only."""

from __future__ import annotations

import shutil

import pytest

from tests.console.test_browser import page, shot  # noqa: F401 (the page fixture)

pytestmark = pytest.mark.skipif(not shutil.which("chromium"), reason="chromium is not installed (apt-get install chromium)")


def test_create_form_race_type(console, page, tmp_path):  # noqa: F811
    page.click("text=Create model")
    page.wait_for_selector("[data-track='oval']")
    page.fill("#name", "browser-oa")
    assert page.is_disabled("#domain-randomization")  # laplab's default sensor, STATE, has no camera
    page.select_option("#sensor", "FRONT_FACING_CAMERA")
    page.check("#domain-randomization")
    page.select_option("#sensor", "STATE")  # unticked again: a STATE model would be refused
    assert page.is_disabled("#domain-randomization") and not page.is_checked("#domain-randomization")
    assert page.is_hidden("#race-objects")
    page.check("input[name='race'][value='object_avoidance']")
    assert page.is_visible("#race-objects") and page.is_hidden("#race-bots")
    page.fill("#race-objects-count", "2")
    page.fill("#hp-num_episodes_between_training", "2")
    page.fill("#hp-num_epochs", "3")
    page.select_option("#hp-batch_size", "32")
    page.fill("#max-time", "0.1")
    shot(page, tmp_path, "create-race-type")
    page.click("#validate")  # the form submits a validated reward function
    page.wait_for_selector("#validate-result.ok", timeout=90_000)
    page.click("#submit")
    page.wait_for_url(f"{console.url}/models/browser-oa", timeout=90_000)
    page.wait_for_function("document.querySelector('#config').textContent.includes('object avoidance')",
                           timeout=120_000)
    assert "object avoidance: 2 boxes" in page.inner_text("#config")
    detail = console.admin.get("/api/models/browser-oa").json()
    assert detail["config"]["race_type"]["kind"] == "object_avoidance" and detail["config"]["race_type"]["objects"] == 2
    assert detail["config"]["domain_randomization"] is False and "Domain randomisation\noff" in page.inner_text("#config")
