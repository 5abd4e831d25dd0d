"""A clone records the model and checkpoint it came from, in laplab.json and in its report."""

from __future__ import annotations


from laplab.analysis.report import build_report
from laplab.store.layout import model_folder
from laplab.train.config import TrainConfig
from laplab.train.jobs import clone_config, create_training


def test_clone_records_its_source(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    source = create_training("source", TrainConfig(track="oval"))
    source.close()
    config, weights = clone_config("source", {})
    assert config.cloned_from == "source (checkpoint 0_Step-0.ckpt)" and "model" in weights
    clone = create_training("clone", config, init_weights=weights)
    clone.close()
    saved = model_folder("clone").read_laplab_config()
    assert saved["cloned_from"] == "source (checkpoint 0_Step-0.ckpt)"
    assert TrainConfig.from_dict(saved).cloned_from == config.cloned_from
    assert model_folder("source").read_laplab_config()["cloned_from"] is None
    page = build_report(model_folder("clone"), tmp_path / "report").read_text()
    assert "cloned from" in page and "source (checkpoint 0_Step-0.ckpt)" in page
