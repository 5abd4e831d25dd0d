"""Damaged files give one clear paragraph naming the file (never a traceback), export verifies its
checkpoint, an imported reward function needs trust before it runs, and store/ imports nothing above it."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from laplab.cli import main
from laplab.store.layout import model_folder
from laplab.store.checkpoints import CheckpointStore
from laplab.train.jobs import create_training

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def trained(laplab_home, tiny_config):
    trainer = create_training("m", tiny_config(max_episodes=2))
    trainer.run()
    trainer.close()
    return model_folder("m")


def one_paragraph(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return " ".join(err.split())


def test_truncated_checkpoint_at_evaluate_and_export(trained, capsys, tmp_path):
    path = CheckpointStore(trained).resolve("best")
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 3])
    assert main(["evaluate", "m", "--trials", "1"]) == 2
    text = one_paragraph(capsys)
    assert "is damaged" in text and path.name in text
    out = tmp_path / "m.tar.gz"
    assert main(["export", "m", "--out", str(out)]) == 2
    text = one_paragraph(capsys)
    assert "is damaged" in text and path.name in text and "Nothing was written" in text
    assert not out.exists()


def test_torn_checkpoint_index(trained, capsys):
    trained.deepracer_checkpoints.write_text('{"best_checkpoint": {"name": "1_St')
    assert main(["evaluate", "m", "--trials", "1"]) == 2
    text = one_paragraph(capsys)
    assert "deepracer_checkpoints.json" in text and "damaged" in text and "_Step-" in text
    assert main(["train", "--resume", "m", "--max-episodes", "4", "--quiet"]) == 2
    assert "deepracer_checkpoints.json" in one_paragraph(capsys)


def test_truncated_archive_at_import(trained, capsys, tmp_path):
    archive = tmp_path / "m.tar.gz"
    assert main(["export", "m", "--out", str(archive)]) == 0
    data = archive.read_bytes()
    for cut in (len(data) // 2, len(data) * 9 // 10, 100):  # (a cut in the gzip trailer loses no member)
        broken = tmp_path / f"cut{cut}.tar.gz"
        broken.write_bytes(data[:cut])
        assert main(["import", str(broken), "--name", f"cut{cut}"]) == 2
        text = one_paragraph(capsys)
        assert str(broken) in text and ("damaged" in text or "truncated" in text or "not a gzip" in text), text
        assert not model_folder(f"cut{cut}").exists()


def test_metadata_file_without_action_space_is_an_error(tmp_path, capsys):
    meta = tmp_path / "model_metadata.json"
    meta.write_text(json.dumps({"sensor": ["STATE"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"}))
    assert main(["train", "--name", "nometa", "--model-metadata", str(meta), "--max-episodes", "2"]) == 2
    text = one_paragraph(capsys)
    assert str(meta) in text and "action_space" in text
    assert not model_folder("nometa").exists()


def test_hyperparameters_given_as_json_on_the_command_line(laplab_home, capsys):
    for given, expected in (('{"num_epochs": 3', "--hyperparameters: not valid JSON at line 1, column 17"),
                            ('{"num_epochs": 30}', "'num_epochs' has the invalid value 30"),
                            ('{"num_epoch": 3}', "Did you mean 'num_epochs'?")):
        assert main(["train", "--name", "inline", "--hyperparameters", given, "--max-episodes", "2"]) == 2
        assert expected in one_paragraph(capsys)
        assert not model_folder("inline").exists()
    tiny = {"num_episodes_between_training": 2, "batch_size": 32, "num_epochs": 3}
    assert main(["train", "--name", "inline", "--hyperparameters", json.dumps(tiny), "--max-episodes", "2",
                 "--quiet"]) == 0
    written = json.loads(model_folder("inline").hyperparameters.read_text())
    assert {key: written[key] for key in tiny} == tiny and written["lr"] == 0.0003  # the rest: defaults


def test_imported_reward_function_needs_trust(trained, capsys, tmp_path):
    archive = tmp_path / "m.tar.gz"
    assert main(["export", "m", "--out", str(archive)]) == 0
    capsys.readouterr()
    assert main(["import", str(archive), "--name", "imp"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "reward function" in out and "Python code" in out and "--trust-reward" in out
    assert main(["train", "--resume", "imp", "--max-episodes", "4", "--quiet"]) == 2
    text = one_paragraph(capsys)
    assert "imported" in text and "--trust-reward" in text
    assert main(["clone", "imp", "c1", "--max-episodes", "2", "--quiet"]) == 2
    assert "--trust-reward" in one_paragraph(capsys) and not model_folder("c1").exists()
    own = tmp_path / "own.py"
    own.write_text("def reward_function(params):\n    return 1.0\n")
    assert main(["clone", "imp", "c2", "--reward", str(own), "--max-episodes", "2", "--quiet"]) == 0
    assert main(["train", "--resume", "imp", "--max-episodes", "4", "--quiet", "--trust-reward"]) == 0
    assert main(["train", "--resume", "imp", "--max-episodes", "6", "--quiet"]) == 0  # trusted once, recorded


def test_store_imports_nothing_above_it():
    allowed = ("laplab.store", "laplab", "laplab.errors", "laplab.settings")  # standard library only, any layer
    for path in (REPO / "laplab" / "store").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module] if isinstance(node, ast.ImportFrom) and node.module else [])
            for name in names:
                if name.startswith("laplab"):
                    assert name in allowed or name.startswith("laplab.store."), f"{path.name} imports {name}"
