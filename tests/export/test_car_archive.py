"""``laplab export --format car / console`` on trained models: the car's tar.gz read back the way the
car's upload does it (aws-deepracer-systems-pkg model loader + webserver metadata checks), then
converted by OpenVINO with the inputs the car's optimizer derives from the metadata; the console
folder's files; refusals of models the car cannot run."""

from __future__ import annotations

import json
import os
import re
import tarfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch", reason="export loads laplab's torch policy")
pytest.importorskip("tensorflow", reason="model.pb needs tensorflow-cpu: pip install 'laplab[deepracer]'")
pytest.importorskip("openvino", reason="the car's conversion needs openvino: pip install 'laplab[deepracer]'")

from laplab.cli import main  # noqa: E402
from laplab.env.metadata import ModelMetadata  # noqa: E402
from laplab.export.car import CarExportError, export_car  # noqa: E402
from laplab.export.console import export_console  # noqa: E402
from laplab.export.openvino_model import OpenVinoPolicy, car_optimizer_inputs  # noqa: E402
from laplab.export.tensorflow_graph import graph_feed  # noqa: E402
from laplab.export.policy_layers import policy_layers  # noqa: E402
from laplab.store.layout import model_folder  # noqa: E402
from laplab.train.config import TrainConfig  # noqa: E402
from laplab.train.jobs import create_training  # noqa: E402
from laplab.train.policy import load_model_policy  # noqa: E402

TINY_HP = {"num_episodes_between_training": 2, "batch_size": 32, "num_epochs": 3}
# the car's own vocabulary (aws-deepracer-webserver-pkg constants.py)
CAR_SENSOR_KEYS = {"observation", "LIDAR", "SECTOR_LIDAR", "LEFT_CAMERA", "FRONT_FACING_CAMERA", "STEREO_CAMERAS"}
CAR_LIDAR_SECTORS = {"LIDAR": 64, "SECTOR_LIDAR": 8}


def train_tiny(name: str, train: bool = True, **meta) -> None:
    """A model folder; ``train``: one tiny iteration, else the untrained checkpoint 0 alone."""
    config = TrainConfig()
    config = replace(config, hyperparameters={**config.hyper().to_dict(), **TINY_HP},
                     model_metadata={**ModelMetadata().to_dict(), **meta}, max_time_s=60, max_episodes=2,
                     eval_episodes=1)
    trainer = create_training(name, config)
    if train:
        trainer.run()


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    """$LAPLAB_HOME with 'cam' (front camera, discrete PPO, trained for one tiny iteration),
    'cam-lidar-sac' (camera + sector lidar, SAC) and 'state' (laplab's STATE sensor), untrained."""
    with pytest.MonkeyPatch.context() as patch:
        root = tmp_path_factory.mktemp("home")
        patch.setenv("LAPLAB_HOME", str(root))
        train_tiny("cam", sensor=["FRONT_FACING_CAMERA"])
        train_tiny("cam-lidar-sac", False, sensor=["FRONT_FACING_CAMERA", "SECTOR_LIDAR"], training_algorithm="sac",
                   action_space_type="continuous",
                   action_space={"steering_angle": {"low": -30.0, "high": 30.0}, "speed": {"low": 0.5, "high": 3.0}})
        train_tiny("state", False)
        yield root


def car_upload(archive: Path, artifacts: Path) -> tuple[str, Path, dict, list]:
    """What the car does with an uploaded NAME.tar.gz: the model is named after the file up to its
    first dot; the archive's only .pb (searched in every folder) becomes artifacts/NAME/model.pb and
    its top-level model_metadata.json is copied beside it; then the metadata is checked as the
    webserver does, and the optimizer's inputs are derived from it. Returns (name, model.pb, metadata,
    optimizer inputs)."""
    name = archive.name[:archive.name.find(".")].replace(" ", "_")
    temporary = artifacts / f"aws-temp-model-{name}"
    temporary.mkdir(parents=True)
    with tarfile.open(archive, "r:gz") as tar:
        tar.extractall(temporary, filter="data")
    graphs = [Path(root) / f for root, _, files in os.walk(temporary) for f in files if f.endswith(".pb")]
    assert len(graphs) == 1, f"the car ignores an archive with {len(graphs)} .pb files"
    install = artifacts / name
    install.mkdir()
    (install / "model.pb").write_bytes(graphs[0].read_bytes())
    metadata_file = temporary / "model_metadata.json"
    assert metadata_file.is_file(), "the car reads model_metadata.json from the archive's top level"
    (install / "model_metadata.json").write_bytes(metadata_file.read_bytes())
    metadata = json.loads((install / "model_metadata.json").read_text())
    sensors = list(metadata.get("sensor", ["observation"]))
    assert set(sensors) <= CAR_SENSOR_KEYS
    algorithm = metadata.get("training_algorithm", "clipped_ppo")
    assert algorithm in ("clipped_ppo", "sac")
    kind = metadata.get("action_space_type", "discrete")
    assert kind in ("discrete", "continuous")
    space = metadata["action_space"]
    if kind == "discrete":
        assert all("steering_angle" in a and "speed" in a for a in space)
    else:
        assert all(space[k]["high"] > space[k]["low"] for k in ("steering_angle", "speed"))
    # the car reads its own lidar_config keys (num_values, min_angle, ...) when the key is present
    assert "lidar_config" not in metadata or "num_sectors" in metadata["lidar_config"]
    lidar = next((s for s in sensors if s in CAR_LIDAR_SECTORS), None)
    inputs = car_optimizer_inputs(sensors, algorithm, CAR_LIDAR_SECTORS.get(lidar))
    return name, install / "model.pb", metadata, inputs


@pytest.mark.parametrize("model", ["cam", "cam-lidar-sac"])
def test_car_archive_loads_on_the_car_and_drives_like_laplab(home, tmp_path, model):
    path, graph = export_car(model, "best", tmp_path)
    assert path == tmp_path / f"{model}.tar.gz" and graph.parity_error <= 1e-5
    with tarfile.open(path, "r:gz") as tar:
        assert sorted(m.name for m in tar.getmembers()) == ["agent/model.pb", "model_metadata.json"]
        assert all(m.isfile() for m in tar.getmembers())
    name, pb, metadata, inputs = car_upload(path, tmp_path / "artifacts")
    assert name == model
    assert metadata == {k: v for k, v in model_folder(model).read_model_metadata().items() if k != "lidar_config"}
    openvino = OpenVinoPolicy(pb, inputs)
    policy = load_model_policy(model)
    layers = policy_layers(policy.network, policy.observation_space, list(policy.metadata.sensors))
    from laplab.agents.onnx_export import random_observations
    observations = random_observations(policy.observation_space, 20, seed=4)
    outputs = openvino.run_batch(graph_feed(layers, observations))
    actions = policy.act(observations)
    if metadata["action_space_type"] == "discrete":
        assert np.array_equal(outputs.argmax(axis=1), actions)
    else:  # the car's navigation node clips the output to [-1, 1] before scaling it
        assert np.abs(np.clip(outputs, -1.0, 1.0) - actions).max() <= 1e-4


@pytest.fixture(scope="module")
def console(home, tmp_path_factory):
    """``laplab export cam --format console`` into a fresh folder."""
    return export_console("cam", "best", tmp_path_factory.mktemp("export") / "console")


def test_console_folder_has_the_dr_upload_model_layout(console):
    folder = console.folder
    checkpoint = console.graph.checkpoint
    iteration = checkpoint.split("_")[0]
    files = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())
    assert files == sorted(["model/model_metadata.json", f"model/model_{iteration}.pb", "model/deepracer_checkpoints.json",
                            "model/.coach_checkpoint", f"model/{checkpoint}.index",
                            f"model/{checkpoint}.data-00000-of-00001", f"model/{checkpoint}.meta", "model/checkpoint",
                            "model_metadata.json", "reward_function.py", "ip/hyperparameters.json",
                            "metrics/TrainingMetrics.json", "training_params.yaml"])
    source = model_folder("cam")
    assert (folder / "model/model_metadata.json").read_bytes() == (folder / "model_metadata.json").read_bytes()
    assert json.loads((folder / "model_metadata.json").read_text()) == source.read_model_metadata()
    assert (folder / "reward_function.py").read_bytes() == source.reward_function.read_bytes()
    assert (folder / "ip/hyperparameters.json").read_bytes() == source.hyperparameters.read_bytes()
    yaml = pytest.importorskip("yaml")
    params = yaml.safe_load((folder / "training_params.yaml").read_text())
    assert params["WORLD_NAME"] == TrainConfig().track and params["RACE_TYPE"] == "TIME_TRIAL"
    assert params["MODEL_METADATA_FILE_S3_KEY"] == "cam/model/model_metadata.json"
    with pytest.raises(CarExportError, match="not an empty folder"):
        export_console("cam", "best", folder)


def test_console_checkpoint_is_found_and_restored_as_deepracer_tooling_does(console):
    """The checkpoint is named alike by rl_coach's .coach_checkpoint, deepracer_checkpoints.json and
    TensorFlow's state file; dr-upload-model and the simapp pick exactly its files; TensorFlow
    restores it into rl_coach's networks, which act as laplab's torch policy and value."""
    tf = pytest.importorskip("tensorflow")
    import torch

    from laplab.agents.networks import observation_to_tensor
    from laplab.agents.onnx_export import random_observations
    from laplab.export.policy_layers import reference_output, value_layers
    from laplab.export.tensorflow_checkpoint import restore_checkpoint

    model = console.folder / "model"
    # rl_coach's CheckpointStateFile / CheckpointFilenameParser: the name and number of the checkpoint
    coach = re.match(r"\A(([0-9]+)[^0-9])?.*?\.ckpt(-([0-9]+))?", (model / ".coach_checkpoint").read_text()[:256])
    name, number = coach.group(0), int(coach.group(2))
    assert name == console.graph.checkpoint and (model / ".coach_checkpoint").read_text() == name
    # deepracer_checkpoints.json (the simapp reads the number before "_Step")
    records = json.loads((model / "deepracer_checkpoints.json").read_text())
    assert records["best_checkpoint"]["name"] == records["last_checkpoint"]["name"] == name
    assert int(records["last_checkpoint"]["name"].split("_Step")[0]) == number
    assert isinstance(records["last_checkpoint"]["time_stamp"], float)
    # TensorFlow's state file ("checkpoint", the simapp's old coach checkpoint: its quoted name)
    assert re.findall(r'"(.*?)"', (model / "checkpoint").read_text().splitlines()[0]) == [name]
    assert tf.train.latest_checkpoint(str(model)) == str(model / name)
    # dr-upload-model copies "<N>*" and model_<N>.pb; the simapp downloads the files starting with the name, .pb aside
    uploaded = sorted(p.name for p in model.iterdir() if p.name.startswith(str(number)) or p.name == f"model_{number}.pb")
    assert uploaded == sorted([f"{name}.data-00000-of-00001", f"{name}.index", f"{name}.meta", f"model_{number}.pb"])
    assert any(re.fullmatch(rf"{number}_Step-[0-9]{{1,7}}\.ckpt\.index", p) for p in uploaded)
    variables = [variable for variable, _ in tf.train.list_variables(str(model))]
    assert variables and all(v.startswith("main_level/agent/main/online/network_") for v in variables)
    # restored into rl_coach's networks: laplab's torch policy and value
    policy = load_model_policy("cam")
    graph = restore_checkpoint(model, console.graph.layers, console.graph.value_layers)
    observations = random_observations(policy.observation_space, 20, seed=9)
    feed = graph_feed(console.graph.layers, observations)
    assert np.abs(graph.run(feed) - reference_output(policy.network, observations)).max() <= 1e-5
    with torch.no_grad():
        value = policy.network.value(observation_to_tensor(observations, "cpu")).numpy()
    assert np.abs(graph.run_value(feed) - value).max() <= 1e-5
    sensors = list(policy.metadata.sensors)
    assert np.array_equal(value_layers(policy.network, policy.observation_space, sensors).head.kernel,
                          console.graph.value_layers.head.kernel)
    assert console.checkpoint_error <= 1e-5
    assert console.limitations == ()  # a front-camera PPO model: the simapp restores all of it


def test_models_the_car_cannot_run_are_refused(home, tmp_path, capsys):
    with pytest.raises(CarExportError, match="sensor 'STATE' is not supported by the DeepRacer car"):
        export_car("state", "best", tmp_path)
    assert main(["export", "state", "--format", "car", "--out", str(tmp_path)]) == 2
    assert "STATE is laplab's own simulator-only sensor" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_cli_writes_the_car_archive_and_the_console_folder(home, tmp_path, capsys):
    assert main(["export", "cam", "--format", "car", "--out", str(tmp_path / "cam.tar.gz")]) == 0
    assert "agent/model.pb" in capsys.readouterr().out and (tmp_path / "cam.tar.gz").is_file()
    assert main(["export", "cam", "--format", "console", "--out", str(tmp_path / "c")]) == 0
    assert (tmp_path / "c" / "model_metadata.json").is_file()
    assert main(["export", "absent", "--format", "car", "--out", str(tmp_path)]) == 2


def test_console_layout_goes_to_an_s3_prefix(home, console, monkeypatch):
    """--format console --out s3://BUCKET/PREFIX: the same files as the local layout, under the prefix,
    on a real S3-compatible server (moto's, on 127.0.0.1)."""
    moto_server = pytest.importorskip("moto.server")
    boto3 = pytest.importorskip("boto3")
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    try:
        host, port = server.get_host_and_port()
        for name, value in (("AWS_ENDPOINT_URL", f"http://{host}:{port}"), ("AWS_ACCESS_KEY_ID", "testing"),
                            ("AWS_SECRET_ACCESS_KEY", "testing"), ("AWS_DEFAULT_REGION", "us-east-1")):
            monkeypatch.setenv(name, value)
        client = boto3.client("s3", endpoint_url=f"http://{host}:{port}")
        client.create_bucket(Bucket="console-import")
        assert main(["export", "cam", "--format", "console", "--out", "s3://console-import/upload/cam"]) == 0
        keys = {item["Key"] for item in client.list_objects_v2(Bucket="console-import")["Contents"]}
        local = {p.relative_to(console.folder).as_posix() for p in console.folder.rglob("*") if p.is_file()}
        assert keys == {f"upload/cam/{rel}" for rel in local}
        assert main(["export", "cam", "--format", "car", "--out", "s3://console-import/car.tar.gz"]) == 2
    finally:
        server.stop()
