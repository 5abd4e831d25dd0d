"""``laplab export --format console`` against DeepRacer on AWS's import rules, one test per rule
(aws-solutions/deepracer-on-aws: docs/import/README.md and the import workflow's ImportHelper, which
reads training_params.yaml, model_metadata.json, reward_function.py and ip/hyperparameters.json at
the folder's root, and the checkpoint .coach_checkpoint names under model/)."""

from __future__ import annotations

import json
import re

import pytest

pytest.importorskip("torch", reason="the export reads laplab's torch checkpoint")
pytest.importorskip("tensorflow", reason="the console export writes model.pb with tensorflow-cpu")

from deepracer_models import MODELS  # noqa: E402

CAMERAS, LIDARS = {"FRONT_FACING_CAMERA", "STEREO_CAMERAS"}, {"LIDAR", "SECTOR_LIDAR"}  # DeepRacer on AWS's sensors
NAMES = list(MODELS)


@pytest.mark.parametrize("name", NAMES)
def test_rule_model_metadata_at_the_root(console_exports, name):
    metadata = json.loads((console_exports[name] / "model_metadata.json").read_text())
    assert metadata["training_algorithm"] in ("clipped_ppo", "sac")
    assert set(metadata["sensor"]) <= CAMERAS | LIDARS and set(metadata["sensor"]) & CAMERAS
    space = metadata["action_space"]
    if isinstance(space, list):
        assert all({"speed", "steering_angle"} <= set(action) for action in space)
    else:
        assert {"low", "high"} <= set(space["speed"]) and {"low", "high"} <= set(space["steering_angle"])


@pytest.mark.parametrize("name", NAMES)
def test_rule_reward_function_at_the_root(console_exports, name):
    source = (console_exports[name] / "reward_function.py").read_text()
    namespace: dict = {}
    exec(compile(source, "reward_function.py", "exec"), namespace)  # laplab's own example reward
    assert callable(namespace["reward_function"])


@pytest.mark.parametrize("name", NAMES)
def test_rule_hyperparameters_in_ip(console_exports, name):
    hyper = json.loads((console_exports[name] / "ip/hyperparameters.json").read_text())
    assert {"batch_size", "lr", "num_epochs", "discount_factor", "loss_type"} <= set(hyper)


@pytest.mark.parametrize("name", NAMES)
def test_rule_training_params_yaml_at_the_root(console_exports, name):
    yaml = pytest.importorskip("yaml")
    params = yaml.safe_load((console_exports[name] / "training_params.yaml").read_text())
    assert params["WORLD_NAME"] and params["RACE_TYPE"] == "TIME_TRIAL" and params["BODY_SHELL_TYPE"]


@pytest.mark.parametrize("name", NAMES)
def test_rule_coach_checkpoint_names_the_ckpt_files(console_exports, name):
    model = console_exports[name] / "model"
    key = (model / ".coach_checkpoint").read_text().strip()
    assert re.fullmatch(r"[0-9]+_Step-[0-9]+\.ckpt", key)
    for suffix in (".index", ".data-00000-of-00001", ".meta"):
        assert (model / f"{key}{suffix}").stat().st_size > 0
    assert json.loads((model / "deepracer_checkpoints.json").read_text())["best_checkpoint"]["name"] == key


@pytest.mark.parametrize("name", NAMES)
def test_rule_under_one_gigabyte(console_exports, name):
    size = sum(p.stat().st_size for p in console_exports[name].rglob("*") if p.is_file())
    assert size < 1 << 30


@pytest.mark.parametrize("name", NAMES)
def test_rule_sac_only_with_a_continuous_action_space(console_exports, name):
    metadata = json.loads((console_exports[name] / "model_metadata.json").read_text())
    if metadata["training_algorithm"] == "sac":
        assert metadata["action_space_type"] == "continuous" and isinstance(metadata["action_space"], dict)
