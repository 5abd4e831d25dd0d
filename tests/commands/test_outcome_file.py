"""A command's outcome as JSON in $LAPLAB_RESULT_FILE: what the console reads instead of printed text."""

from __future__ import annotations

import json

from laplab.cli import main


def test_a_user_error_is_written_with_its_message(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    monkeypatch.setenv("LAPLAB_RESULT_FILE", str(tmp_path / "outcome.json"))
    assert main(["report", "no-such-model"]) == 2
    outcome = json.loads((tmp_path / "outcome.json").read_text())
    assert outcome["ok"] is False and outcome["command"] == "report" and "no-such-model" in outcome["error"]


def test_a_report_names_its_page(tmp_path, monkeypatch):
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    monkeypatch.setenv("LAPLAB_RESULT_FILE", str(tmp_path / "outcome.json"))
    create_training("reported", TrainConfig(track="oval")).close()
    assert main(["report", "reported", "--out", str(tmp_path / "page")]) == 0
    outcome = json.loads((tmp_path / "outcome.json").read_text())
    assert outcome["ok"] is True and outcome["page"] == str(tmp_path / "page" / "index.html")


def test_an_evaluation_setting_out_of_range_names_its_option(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    monkeypatch.setenv("LAPLAB_RESULT_FILE", str(tmp_path / "outcome.json"))
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    create_training("judged", TrainConfig(track="oval")).close()
    assert main(["evaluate", "judged", "--trials", "9"]) == 2
    outcome = json.loads((tmp_path / "outcome.json").read_text())
    assert outcome["field"] == "--trials" and "trials must be an integer from 1 to 5" in outcome["error"]
