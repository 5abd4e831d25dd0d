"""The README's main job: `laplab run` trains, evaluates 3 trials and writes the report."""

import json

from laplab.cli import main
from laplab.store.layout import model_folder


def test_main_job_trains_evaluates_and_reports(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    assert main(["run", "--name", "quick", "--max-time", "6s"]) == 0
    out = capsys.readouterr().out
    assert "gap to optimal" in out and "report:" in out
    folder = model_folder("quick")
    (stamp,) = folder.list_evaluations()
    summary = json.loads((folder.evaluation_dir(stamp) / "summary.json").read_text())
    assert len(summary["trials"]) == 3
    assert summary["summary"]["optimal_lap_time"] > 0
    assert (folder.root / "report" / "index.html").is_file()


def test_drive_baseline_laps(capsys):
    assert main(["drive", "--laps", "2", "--speed", "1.0"]) == 0
    assert capsys.readouterr().out.count("lap_complete") == 2
