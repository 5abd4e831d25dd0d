"""``laplab import`` of DeepRacer's layouts: ``laplab export --format console`` then import gives the
same model (every policy and value weight, the outputs on the same frames to 1e-5, metadata,
hyperparameters, physics version), from a folder, a .tar.gz, a .zip and a bare model.pb; the
imported model's reward is untrusted, it clones once trusted; a real console checkpoint's variable
names and shapes are the ones laplab expects."""

from __future__ import annotations

import json
import shutil
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch", reason="the import writes a laplab (torch) checkpoint")
pytest.importorskip("tensorflow", reason="the console export writes model.pb with tensorflow-cpu")

import torch  # noqa: E402
from deepracer_models import MODELS  # noqa: E402
from export_networks import varied_observations  # noqa: E402

from laplab.cli import main  # noqa: E402
from laplab.export.deepracer_import import import_deepracer_model  # noqa: E402
from laplab.export.policy_layers import reference_output  # noqa: E402
from laplab.store.layout import model_folder  # noqa: E402
from laplab.train.errors import JobError  # noqa: E402
from laplab.train.policy import load_model_policy  # noqa: E402

REAL = Path(__file__).resolve().parents[3] / "shared/real-deepracer/console-2023-reInvent2019_wide_ccw"


@pytest.fixture
def home(console_exports, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(console_exports["home"]))
    return console_exports


def assert_same_model(original: str, imported: str, value_network: bool = True) -> None:
    a, b = load_model_policy(original), load_model_policy(imported)
    assert a.metadata == b.metadata
    assert a.config.hyper() == b.config.hyper() or not value_network  # a model.pb has no hyperparameters
    assert a.config.car == b.config.car == "deepracer-v5"
    sa, sb = a.network.state_dict(), b.network.state_dict()
    compared = [k for k in sa if value_network or not k.startswith(("value_trunk", "value_head"))]
    assert compared and sa.keys() == sb.keys()
    different = [k for k in compared if not torch.equal(sa[k], sb[k])]
    assert not different
    frames = varied_observations(a.observation_space, 32, seed=5)
    expected, got = reference_output(a.network, frames), reference_output(b.network, frames)
    assert np.ptp(expected, axis=0).max() > 1e-2  # outputs differ between frames: the check means something
    assert np.abs(expected - got).max() <= 1e-5


@pytest.mark.parametrize("name", list(MODELS))
def test_console_export_imports_back_as_the_same_model(home, name):
    imported = import_deepracer_model(home[name], f"{name}-back")
    assert imported.trainable and imported.checkpoint == "0_Step-0.ckpt"
    assert_same_model(name, f"{name}-back")
    record = json.loads((imported.folder.root / "laplab-import.json").read_text())
    assert record["reward_trusted"] is False and record["trainable"] is True
    assert imported.folder.reward_function.read_text() == (home[name] / "reward_function.py").read_text()


def test_tar_gz_and_zip_of_the_folder_wrapped_in_a_folder(home, tmp_path):
    folder = home["ppo-cam-lidar"]
    with tarfile.open(tmp_path / "m.tar.gz", "w:gz") as tar:
        tar.add(folder, arcname="my-model")
    with zipfile.ZipFile(tmp_path / "m.zip", "w") as archive:
        for path in sorted(folder.rglob("*")):
            archive.write(path, path.relative_to(folder).as_posix())
    assert main(["import", str(tmp_path / "m.tar.gz"), "--name", "from-tar"]) == 0
    assert import_deepracer_model(tmp_path / "m.zip", "from-zip").trainable
    for name in ("from-tar", "from-zip"):
        assert_same_model("ppo-cam-lidar", name)


def test_best_checkpoint_is_the_one_deepracer_checkpoints_json_names(home, tmp_path):
    folder = tmp_path / "two"
    shutil.copytree(home["ppo-deep-cam"], folder)
    for path in list((folder / "model").glob("0_Step-0.ckpt.*")):  # an older checkpoint beside it
        shutil.copy(path, folder / "model" / path.name.replace("0_Step-0", "7_Step-900"))
    (folder / "model/.coach_checkpoint").write_text("7_Step-900.ckpt")
    hyper = json.loads((folder / "ip/hyperparameters.json").read_text())
    (folder / "ip/hyperparameters.json").write_text(json.dumps({**hyper, "a_newer_key": 1}))
    imported = import_deepracer_model(folder, "best-of-two")
    assert (imported.source_checkpoint, imported.checkpoint) == ("0_Step-0.ckpt", "0_Step-0.ckpt")
    assert imported.notes == ("ip/hyperparameters.json: a_newer_key ignored (laplab does not use them)",)
    (folder / "model/deepracer_checkpoints.json").unlink()
    assert import_deepracer_model(folder, "coach-of-two").checkpoint == "7_Step-900.ckpt"


def test_imported_model_clones_once_its_reward_is_trusted(home):
    from laplab.train.jobs import clone_config
    from laplab.train.trainer import build_learner
    import_deepracer_model(home["sac-cam-sector"], "sac-to-clone")
    with pytest.raises(JobError, match="--trust-reward"):
        clone_config("sac-to-clone", {})
    config, weights = clone_config("sac-to-clone", {}, trust_reward=True)
    learner = build_learner(config, 0)
    learner.load_weights(weights)  # continues training from the imported weights
    assert config.cloned_from.startswith("sac-to-clone")


def frozen_rl_coach_graph(folder: Path, layers, out: Path) -> None:
    """A car's model.pb as DeepRacer freezes it: the checkpoint's variables made constants of the same
    names (convert_variables_to_constants), the policy output kept."""
    import tensorflow as tf

    from laplab.export.tensorflow_checkpoint import restore_checkpoint
    graph = restore_checkpoint(folder / "model", layers)
    frozen = tf.compat.v1.graph_util.convert_variables_to_constants(
        graph.session, graph.graph.as_graph_def(), [graph.output.op.name])
    out.write_bytes(frozen.SerializeToString())


@pytest.mark.parametrize("name", list(MODELS))
def test_laplabs_car_model_pb_imports_back_as_the_same_policy(home, name, tmp_path):
    """The car's model.pb of a laplab model (the console export's model_0.pb is the same file) imports
    with the policy weight for weight: its constants carry rl_coach's names, as DeepRacer's do. A
    model.pb has neither value network nor exploration noise (the freeze drops them)."""
    car = tmp_path / "car"
    car.mkdir()
    shutil.copy(home[name] / "model" / "model_0.pb", car / "model.pb")
    shutil.copy(home[name] / "model_metadata.json", car / "model_metadata.json")
    assert not import_deepracer_model(car / "model.pb", f"{name}-pb").trainable
    a, b = load_model_policy(name), load_model_policy(f"{name}-pb")
    sa, sb = a.network.state_dict(), b.network.state_dict()
    compared = [k for k in sa if not k.startswith(("value_trunk", "value_head")) and "log_std" not in k]
    assert compared and not [k for k in compared if not torch.equal(sa[k], sb[k])]
    frames = varied_observations(a.observation_space, 32, seed=5)
    expected = reference_output(a.network, frames)
    assert np.ptp(expected, axis=0).max() > 1e-2
    assert np.abs(reference_output(b.network, frames) - expected).max() <= 1e-5


def test_bare_model_pb_evaluates_but_refuses_clone_and_resume(home, tmp_path):
    from laplab.export.policy_layers import policy_layers
    from laplab.train.jobs import clone_config, resume_training
    source = load_model_policy("ppo-cam-lidar")
    layers = policy_layers(source.network, source.observation_space, list(source.metadata.sensors))
    car = tmp_path / "car"
    car.mkdir()
    frozen_rl_coach_graph(home["ppo-cam-lidar"], layers, car / "model.pb")
    shutil.copy(home["ppo-cam-lidar"] / "model_metadata.json", car / "model_metadata.json")
    assert main(["import", str(car / "model.pb"), "--name", "from-pb"]) == 0
    assert_same_model("ppo-cam-lidar", "from-pb", value_network=False)
    with pytest.raises(JobError, match="frozen graph"):
        clone_config("from-pb", {}, trust_reward=True)
    with pytest.raises(JobError, match="frozen graph"):
        resume_training("from-pb", trust_reward=True)
    with tarfile.open(tmp_path / "car-model.tar.gz", "w:gz") as tar:  # the car's archive layout
        tar.add(car / "model.pb", arcname="agent/model.pb")
        tar.add(car / "model_metadata.json", arcname="model_metadata.json")
    assert not import_deepracer_model(tmp_path / "car-model.tar.gz").trainable
    assert_same_model("ppo-cam-lidar", "car-model", value_network=False)


def test_an_imported_model_exports_to_the_console_again(home, tmp_path):
    from laplab.export.console import export_console
    import_deepracer_model(home["sac-cam-sector"], "sac-once")
    again = export_console("sac-once", out=tmp_path / "again").folder
    import_deepracer_model(again, "sac-twice")
    assert_same_model("sac-cam-sector", "sac-twice")


@pytest.mark.skipif(not REAL.is_dir(), reason="needs ../shared/real-deepracer")
def test_a_real_console_checkpoint_has_the_variables_laplab_expects():
    from laplab.env.metadata import metadata_from_dict
    from laplab.export.checkpoint_bundle import read_index
    from laplab.export.deepracer_import import _templates
    from laplab.export.rl_coach_weights import expected_variables, mismatches
    from laplab.train.config import TrainConfig
    from laplab.train.trainer import build_learner
    metadata = metadata_from_dict(json.loads((REAL / "model/model_metadata.json").read_text()), "real")
    config = TrainConfig(model_metadata=metadata, hyperparameters=json.loads((REAL / "ip/hyperparameters.json")
                                                                             .read_text()))
    _, _, policy, value = _templates(build_learner(config, 0, precision="float32"), config)
    for index in sorted((REAL / "model").glob("*.ckpt.index")):
        _, entries = read_index(index)
        found = {name: entry.shape for name, entry in entries.items()}
        assert mismatches(found, expected_variables(policy, value)) == []
        assert set(found) == set(expected_variables(policy, value))  # nothing more either


def test_python_api_import_model(home, tmp_path):
    from laplab.api import import_model
    from laplab.errors import UserError
    assert import_model(home["ppo-deep-cam"], "via-api") == "via-api"
    assert model_folder("via-api").exists()
    with pytest.raises(UserError, match="no such file or folder"):
        import_model(tmp_path / "missing", "never")


def test_import_needs_no_tensorflow(home):
    """The checkpoint is read with numpy: ``laplab import`` runs where TensorFlow cannot be imported."""
    import os
    import subprocess
    import sys
    code = ("import sys; sys.modules['tensorflow'] = None; from laplab.cli import main; "
            f"raise SystemExit(main(['import', {str(home['ppo-stereo-continuous'])!r}, '--name', 'no-tf']))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ))
    assert done.returncode == 0, done.stderr[-2000:]
    assert_same_model("ppo-stereo-continuous", "no-tf")
