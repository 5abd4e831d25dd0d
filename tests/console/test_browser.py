"""The console in real Chromium (Debian's ``chromium`` driven by Playwright): create a model through
the form, Validate reports a broken reward on its line, the reward chart gains points and the live
view moves while it trains, stop, evaluate, leaderboard, download. Screenshots of every page are
kept under the test's output folder (``tmp_path``)."""

from __future__ import annotations

import shutil

import pytest

from tests.console.conftest import signed_in_page

BROKEN = "def reward_function(params):\n    speed = params['speed']\n    return speed * undefined_thing\n"

pytestmark = pytest.mark.skipif(not shutil.which("chromium"), reason="chromium is not installed (apt-get install chromium)")


@pytest.fixture
def page(console, admin_token):
    with signed_in_page(console.url, admin_token, viewport={"width": 1360, "height": 900}) as page:
        yield page


def shot(page, tmp_path, name):
    page.screenshot(path=str(tmp_path / f"{name}.png"), full_page=True)


def test_console_in_chromium(console, page, tmp_path):
    url = console.url
    shot(page, tmp_path, "01-models-empty")
    page.click("text=Create model")
    page.wait_for_selector("[data-track='oval']")
    page.fill("#name", "browser-model")
    page.click("[data-track='oval']")
    page.click("#add-action")
    page.wait_for_function("document.querySelectorAll('#actions tbody tr').length === 22")
    page.fill("#reward", BROKEN)
    page.click("#validate")
    page.wait_for_selector("#validate-result.bad", timeout=90_000)
    assert "line 3" in page.inner_text("#validate-result")
    assert page.inner_text("[data-error-line]") == "3"
    assert "undefined_thing" in page.inner_text("#reward-error")
    shot(page, tmp_path, "02-create-validate-error")
    page.select_option("#examples", "follow_centerline")
    page.click("#validate")
    page.wait_for_selector("#validate-result.ok", timeout=90_000)
    page.fill("#hp-num_episodes_between_training", "2")
    page.fill("#hp-num_epochs", "3")
    page.select_option("#hp-batch_size", "32")
    page.fill("#max-time", "10")
    shot(page, tmp_path, "03-create-filled")
    page.click("#submit")
    page.wait_for_url(f"{url}/models/browser-model", timeout=90_000)

    # the chart gains points and the cars move while it trains
    page.wait_for_function("+document.querySelector('#live').dataset.frames >= 3", timeout=300_000)
    first_car = page.get_attribute("#live", "data-last-car")
    page.wait_for_function("+document.querySelector('#chart').dataset.points >= 1", timeout=300_000)
    page.wait_for_function(f"document.querySelector('#live').dataset.lastCar !== {first_car!r}", timeout=120_000)
    assert page.get_attribute("#status", "data-status") == "training"
    page.wait_for_function("document.querySelector('#stat-phase').textContent.startsWith('iteration ')",
                           timeout=60_000)  # what the job does now: collecting, learning, evaluating
    shot(page, tmp_path, "04-training")
    page.click("#stop")
    page.wait_for_selector("#status[data-status='ready']", timeout=240_000)
    assert page.locator("#iterations tbody tr").count() >= 1

    page.select_option("#eval-trials", "1")
    page.click("#evaluate")
    # Download for the car cannot work for a STATE model: the button is disabled and says why, on it and
    # under the title, before anything asks for TensorFlow
    page.wait_for_function("document.querySelector('#export-car').disabled")
    assert "'STATE' is not supported" in page.get_attribute("#export-car", "title")
    assert "'STATE' is not supported" in page.inner_text("#downloads-blocked")
    page.wait_for_selector("[data-evaluation] .status[data-status='done']", timeout=300_000)
    assert page.locator("[data-evaluation] table tbody tr").count() == 1
    headline = page.locator("[data-evaluation] h3").inner_text()  # one trial: no average of 3 laps to show
    assert "average of 3" not in headline and ("best lap" in headline or "no lap completed" in headline), headline
    assert page.inner_text("#stat-phase") == "–"  # the stopped job's last phase is not shown as "now"
    page.check("#eval-randomize")  # domain randomisation: a STATE model has no camera, refused at once
    page.click("#evaluate")
    page.wait_for_function("document.querySelector('#eval-error').textContent.includes('no camera')")
    assert page.locator("[data-evaluation]").count() == 1
    page.uncheck("#eval-randomize")
    shot(page, tmp_path, "05-model-evaluated")

    with page.expect_download(timeout=180_000) as download:
        page.click("#download-tar")
    target = tmp_path / "browser-model.tar.gz"
    download.value.save_as(target)
    assert target.read_bytes()[:2] == b"\x1f\x8b"

    href = page.get_attribute("#report", "href")  # the Report button: the model's HTML report
    assert href == "/models/browser-model/report/"
    report = page.context.new_page()
    report.goto(f"{url}{href}", timeout=240_000)  # built by `laplab report` in a child process
    report.wait_for_selector("figure img")
    report.wait_for_function("Array.from(document.images).every(i => i.complete)")
    assert report.evaluate("Array.from(document.images).every(i => i.naturalWidth > 0)")  # figures, not broken links
    assert report.locator("figure img").count() >= 3
    shot(report, tmp_path, "07-report")
    report.close()

    shot(page, tmp_path, "06-model-car-download")  # the disabled car download and its reason

    page.click("text=Leaderboard")
    page.wait_for_selector("[data-board='oval'] tbody tr")
    assert "browser-model" in page.inner_text("[data-board='oval']")
    shot(page, tmp_path, "08-leaderboard")

    page.click("text=Your models")
    page.wait_for_selector("tr[data-model='browser-model']")
    shot(page, tmp_path, "09-models")
    page.on("dialog", lambda dialog: dialog.accept())
    page.click("[data-delete='browser-model']")
    page.wait_for_selector("tr[data-model='browser-model']", state="detached")
    print(f"screenshots in {tmp_path}")
