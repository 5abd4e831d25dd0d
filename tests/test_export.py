"""Model export: tar.gz archives (round trip, refusal of unsafe or inconsistent archives) and ONNX
policies (parity with torch for camera, vector and SAC networks), through the library and the CLI."""

from __future__ import annotations

import hashlib
import io
import json
import tarfile
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

pytest.importorskip("onnx")
onnxruntime = pytest.importorskip("onnxruntime")

from laplab.agents.networks import ActionSpec, ActorCritic, observation_to_tensor  # noqa: E402
from laplab.agents.sac_networks import SquashedGaussianActor  # noqa: E402
from laplab.agents.onnx_export import (ONNX_OPSET, graph_feed, graph_inputs, onnx_parity_error,  # noqa: E402
                                       policy_to_onnx, random_observations, torch_policy_output)
from laplab.cli import main  # noqa: E402
from laplab.commands.export import export_model_onnx  # noqa: E402
from laplab.env.metadata import ModelMetadata  # noqa: E402
from laplab.store.archive import MANIFEST, ArchiveError  # noqa: E402
from laplab.train.archive import export_model_archive, import_model_archive  # noqa: E402
from laplab.store.layout import list_models, model_folder, models_root  # noqa: E402
from laplab.train.config import TrainConfig  # noqa: E402
from laplab.train.jobs import create_training  # noqa: E402
from laplab.train.policy import load_model_policy  # noqa: E402

CAMERA_SPACE = gym.spaces.Box(0, 255, (1, 120, 160), np.uint8)
SMALL_HP = {"num_episodes_between_training": 4, "batch_size": 32, "num_epochs": 3}


def train_small(name: str, **meta) -> None:
    config = TrainConfig()
    config = replace(config, hyperparameters={**config.hyper().to_dict(), **SMALL_HP},
                     model_metadata={**ModelMetadata().to_dict(), **meta}, max_time_s=120, max_episodes=8)
    create_training(name, config).run()


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    """$LAPLAB_HOME holding 'trained', a STATE model trained for two iterations."""
    with pytest.MonkeyPatch.context() as patch:
        root = tmp_path_factory.mktemp("home")
        patch.setenv("LAPLAB_HOME", str(root))
        train_small("trained")
        yield root


@pytest.fixture(scope="module")
def archive(home, tmp_path_factory) -> Path:
    return export_model_archive("trained", "best", tmp_path_factory.mktemp("out") / "trained.tar.gz")


def spread_head(network: torch.nn.Module, seed: int = 0) -> None:
    """Random weights that give clearly non-uniform probabilities / means (the default head is ~0)."""
    torch.manual_seed(seed)
    head = network.policy_head if isinstance(network, ActorCritic) else network.mean
    with torch.no_grad():
        head.weight.normal_(0.0, 0.3)
        head.bias.normal_(0.0, 0.3)


def members(path: Path) -> dict[str, bytes]:
    with tarfile.open(path, "r:gz") as tar:
        return {m.name: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}


def write_archive(path: Path, files: dict[str, bytes], fix_manifest: bool = True, extra=()) -> Path:
    """An archive of ``files``; ``fix_manifest`` rewrites the manifest's sizes and checksums so a
    modified archive passes the integrity checks and reaches the model validation."""
    if fix_manifest:
        manifest = json.loads(files[MANIFEST])
        manifest["files"] = {name: {"sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}
                             for name, data in files.items() if name != MANIFEST}
        files = {**files, MANIFEST: json.dumps(manifest).encode()}
    with tarfile.open(path, "w:gz") as tar:
        for name, data in files.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
        for info in extra:
            tar.addfile(info)
    return path


def leftovers() -> list[str]:
    return sorted(p.name for p in models_root().iterdir() if p.name.startswith("."))


# -- tar.gz --------------------------------------------------------------------------------------

def test_archive_holds_the_model_folder_subset(home, archive):
    files = members(archive)
    folder = model_folder("trained")
    best = json.loads(folder.deepracer_checkpoints.read_text())["best_checkpoint"]["name"]
    assert set(files) == {MANIFEST, "model/model_metadata.json", f"model/{best}", "model/deepracer_checkpoints.json",
                          "ip/hyperparameters.json", "reward_function.py", "laplab.json",
                          "metrics/TrainingMetrics.json", "metrics/laplab-iterations.json"}
    assert files[f"model/{best}"] == (folder.model_dir / best).read_bytes()
    assert files["reward_function.py"] == folder.reward_function.read_bytes()
    records = json.loads(files["model/deepracer_checkpoints.json"])
    assert records["best_checkpoint"]["name"] == records["last_checkpoint"]["name"] == best
    manifest = json.loads(files[MANIFEST])
    assert manifest["name"] == "trained" and manifest["checkpoint"] == best
    assert all(hashlib.sha256(files[n]).hexdigest() == e["sha256"] for n, e in manifest["files"].items())


def test_import_round_trip_gives_identical_actions(home, archive):
    imported = import_model_archive(archive, "copy")
    assert imported.name == "copy" and "copy" in list_models() and leftovers() == []
    original, copy = load_model_policy("trained"), load_model_policy("copy")
    assert copy.checkpoint == original.checkpoint
    observations = random_observations(original.observation_space, 64, seed=3)
    assert np.array_equal(original.act(observations), copy.act(observations))
    for a, b in zip(original.network.parameters(), copy.network.parameters()):
        assert torch.equal(a, b)
    with pytest.raises(ArchiveError, match="already exists"):
        import_model_archive(archive, "copy")
    with pytest.raises(ArchiveError, match="already exists"):
        import_model_archive(archive)  # the exported name, 'trained', is taken too
    assert leftovers() == []


def test_export_of_another_checkpoint_and_bad_names(home, tmp_path):
    last = model_folder("trained").model_dir
    names = sorted(p.name for p in last.glob("*.ckpt"))
    path = export_model_archive("trained", names[0], tmp_path / "first.tar.gz")
    assert f"model/{names[0]}" in members(path)
    assert import_model_archive(path, "first").checkpoint == names[0]
    with pytest.raises(FileNotFoundError, match="not found"):
        export_model_archive("trained", "9_Step-9.ckpt", tmp_path / "x.tar.gz")
    with pytest.raises(FileNotFoundError, match="no model named"):
        export_model_archive("absent", "best", tmp_path / "x.tar.gz")
    assert not (tmp_path / "x.tar.gz").exists()
    assert export_model_archive("trained", "best", tmp_path) == tmp_path / "trained.tar.gz"  # a folder


def _symlink(name: str, target: str) -> tarfile.TarInfo:
    info = tarfile.TarInfo(name)
    info.type, info.linkname = tarfile.SYMTYPE, target
    return info


@pytest.mark.parametrize("case,message", [
    ("absolute", "absolute path or '..'"),
    ("dotdot", "absolute path or '..'"),
    ("symlink", "link or a special file"),
    ("unexpected", "unexpected member"),
    ("tampered", "sha256"),
    ("no_manifest", "no laplab-export.json"),
    ("missing_member", r"lacks \['laplab.json'\]"),
])
def test_unsafe_or_damaged_archives_are_refused(home, archive, tmp_path, case, message):
    files = members(archive)
    bad = tmp_path / f"{case}.tar.gz"
    if case == "absolute":
        write_archive(bad, {**files, "/etc/laplab.json": b"{}"}, fix_manifest=False)
    elif case == "dotdot":
        write_archive(bad, {**files, "model/../../evil.json": b"{}"}, fix_manifest=False)
    elif case == "symlink":
        write_archive(bad, files, fix_manifest=False, extra=[_symlink("reward_function2.py", "/etc/passwd")])
    elif case == "unexpected":
        write_archive(bad, {**files, "run_me.sh": b"rm -rf ~"}, fix_manifest=False)
    elif case == "tampered":
        source = files["reward_function.py"]
        write_archive(bad, {**files, "reward_function.py": source.replace(b"1", b"2", 1)}, fix_manifest=False)
    elif case == "no_manifest":
        write_archive(bad, {k: v for k, v in files.items() if k != MANIFEST}, fix_manifest=False)
    else:
        write_archive(bad, {k: v for k, v in files.items() if k != "laplab.json"}, fix_manifest=False)
    with pytest.raises(ArchiveError, match=message):
        import_model_archive(bad, f"bad-{case.replace('_', '-')}")
    assert f"bad-{case.replace('_', '-')}" not in list_models() and leftovers() == []
    assert not (home / "evil.json").exists() and not (home.parent / "evil.json").exists()


@pytest.mark.parametrize("member,change,message", [
    ("model/model_metadata.json", lambda d: {**d, "neural_network": "ALEXNET"}, "neural_network"),
    ("model/model_metadata.json", lambda d: {**d, "action_space": [{"steering_angle": 0, "speed": 1}]},
     "differs from the one recorded in laplab.json"),
    ("ip/hyperparameters.json", lambda d: {**d, "batch_size": 7}, "batch_size"),
    ("laplab.json", lambda d: {**d, "track": "no-such-track"}, "track 'no-such-track'"),
    ("laplab.json", lambda d: {**d, "turbo": True}, "unknown key 'turbo'"),
    ("reward_function.py", b"def reward_function(params)\n    return 1.0\n", "does not compile"),
    ("checkpoint", b"not a checkpoint", "does not load"),
    ("checkpoint", "pickle", "does not load.*Weights only load failed"),
    ("checkpoint", "shapes", "does not load.*size mismatch"),
])
def test_inconsistent_models_are_refused(home, archive, tmp_path, member, change, message):
    files = members(archive)
    if member == "checkpoint":
        member = next(n for n in files if n.endswith(".ckpt"))
        if change == "pickle":  # an unpickle that would run code: refused by weights_only loading
            buffer = io.BytesIO()
            torch.save({"learner": {"x": tarfile.TarInfo("boom")}}, buffer)
            change = buffer.getvalue()
        elif change == "shapes":  # a safe checkpoint of another network
            state = torch.load(io.BytesIO(files[member]), weights_only=True)
            weights = state["learner"]["model"]
            first = next(iter(weights))
            weights[first] = torch.zeros(weights[first].shape[0] + 1, *weights[first].shape[1:])
            buffer = io.BytesIO()
            torch.save(state, buffer)
            change = buffer.getvalue()
    if callable(change):
        files[member] = json.dumps(change(json.loads(files[member]))).encode()
    else:
        files[member] = change
    bad = write_archive(tmp_path / "bad.tar.gz", files)
    with pytest.raises(ArchiveError, match=message):
        import_model_archive(bad, "inconsistent")
    assert "inconsistent" not in list_models() and leftovers() == []


def test_not_an_archive(home, tmp_path):
    path = tmp_path / "junk.tar.gz"
    path.write_bytes(b"\x00" * 100)
    with pytest.raises(ArchiveError, match="not a gzip-compressed tar"):
        import_model_archive(path)


def test_cli_export_and_import(home, tmp_path, capsys):
    out = tmp_path / "cli.tar.gz"
    assert main(["export", "trained", "--out", str(out)]) == 0
    assert main(["import", str(out), "--name", "from-cli"]) == 0
    assert "from-cli" in list_models()
    assert main(["import", str(out), "--name", "from-cli"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["import", str(out), "--name", "bad_name"]) == 2
    assert main(["export", "absent", "--out", str(tmp_path / "a.tar.gz")]) == 2
    assert main(["export", "trained", "--format", "onnx", "--out", str(tmp_path / "onnx")]) == 0
    assert {p.name for p in (tmp_path / "onnx").iterdir()} == {"model.onnx", "model_metadata.json"}


# -- ONNX ----------------------------------------------------------------------------------------

def _session(graph: bytes):
    return onnxruntime.InferenceSession(graph, providers=["CPUExecutionProvider"])


@pytest.mark.parametrize("actions", [ActionSpec(True, 5), ActionSpec(False, 2)])
def test_camera_network_graph_matches_torch(actions):
    torch.manual_seed(1)
    network = ActorCritic(CAMERA_SPACE, actions)
    spread_head(network)
    graph = policy_to_onnx(network, CAMERA_SPACE, ["FRONT_FACING_CAMERA"])
    session = _session(graph)
    (inp,), (out,) = session.get_inputs(), session.get_outputs()
    assert inp.name == "FRONT_FACING_CAMERA" and inp.shape[1:] == [120, 160, 1] and inp.type == "tensor(float)"
    assert out.name == ("probabilities" if actions.discrete else "action") and out.shape[1] == actions.size
    frames = random_observations(CAMERA_SPACE, 6, seed=2)  # (6, 1, 120, 160) uint8
    nhwc = frames.transpose(0, 2, 3, 1).astype(np.float32)  # DeepRacer's layout, grey levels 0-255
    got = session.run(None, {"FRONT_FACING_CAMERA": nhwc})[0]
    expected = torch_policy_output(network, torch.as_tensor(frames))
    assert np.abs(got - expected).max() < 1e-5
    assert np.ptp(expected) > 0.05  # the comparison is not between near-constant outputs
    if actions.discrete:
        assert np.allclose(got.sum(axis=1), 1.0, atol=1e-6)
    else:
        assert np.all(np.abs(got) <= 1.0)


def test_graph_is_opset_17_with_the_metadata_embedded():
    import onnx
    network = ActorCritic(CAMERA_SPACE, 3)
    model = onnx.load_from_string(policy_to_onnx(network, CAMERA_SPACE, ["FRONT_FACING_CAMERA"], '{"x": 1}'))
    assert max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx")) >= ONNX_OPSET
    props = {p.key: p.value for p in model.metadata_props}
    assert props["model_metadata"] == '{"x": 1}' and props["input_layout"] == "FRONT_FACING_CAMERA:NHWC"


def test_stereo_camera_with_lidar_and_sac_graphs_match_torch():
    stereo_lidar = gym.spaces.Dict({"STEREO_CAMERAS": gym.spaces.Box(0, 255, (2, 120, 160), np.uint8),
                                    "LIDAR": gym.spaces.Box(0.0, 1.0, (64,), np.float32)})
    sensors = ["STEREO_CAMERAS", "LIDAR"]
    network = ActorCritic(stereo_lidar, 4)
    spread_head(network)
    assert onnx_parity_error(policy_to_onnx(network, stereo_lidar, sensors), network, stereo_lidar, sensors) < 1e-5
    assert [g.shape for g in graph_inputs(stereo_lidar, sensors)] == [(120, 160, 2), (64,)]
    vectors = gym.spaces.Dict({"STATE": gym.spaces.Box(-np.inf, np.inf, (10,), np.float32),
                               "SECTOR_LIDAR": gym.spaces.Box(0.0, 1.0, (8,), np.float32)})
    actor = SquashedGaussianActor(vectors, 2, "MLP")
    spread_head(actor)
    graph = policy_to_onnx(actor, vectors, ["STATE", "SECTOR_LIDAR"])
    observations = random_observations(vectors, 32, seed=5)
    got = _session(graph).run(None, graph_feed(graph_inputs(vectors, ["STATE", "SECTOR_LIDAR"]), observations))[0]
    expected = torch_policy_output(actor, observation_to_tensor(observations, "cpu"))
    assert np.abs(got - expected).max() < 1e-5 and np.ptp(expected) > 0.05


def test_trained_state_model_export_matches_its_policy(home, tmp_path):
    result = export_model_onnx("trained", "best", tmp_path / "car")
    assert result.parity_error is not None and result.parity_error < 1e-5
    assert json.loads(result.metadata_path.read_text()) == model_folder("trained").read_model_metadata()
    policy = load_model_policy("trained")
    session = _session(result.onnx_path.read_bytes())
    assert [i.name for i in session.get_inputs()] == ["STATE"]
    observations = random_observations(policy.observation_space, 200, seed=7)
    probabilities = session.run(None, {"STATE": observations})[0]
    expected = torch_policy_output(policy.network, observation_to_tensor(observations, "cpu"))
    assert np.abs(probabilities - expected).max() < 1e-5
    assert np.array_equal(probabilities.argmax(axis=1), policy.act(observations))


def test_graph_inputs_refuse_mismatched_sensors():
    with pytest.raises(ValueError, match="exactly one sensor"):
        graph_inputs(CAMERA_SPACE, ["FRONT_FACING_CAMERA", "LIDAR"])
    with pytest.raises(ValueError, match="not among the model's sensors"):
        graph_inputs(gym.spaces.Dict({"LIDAR": gym.spaces.Box(0, 1, (64,))}), ["STATE"])
