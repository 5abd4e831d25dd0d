"""Bad input to ``laplab import`` of DeepRacer models: a missing required file, a checkpoint that does
not match the metadata's network or action space, a truncated .data file or one with a flipped byte
(its tensor's CRC-32C), archives with '..',
absolute paths or links, an archive over the size limit, SAC with a discrete action space, an S3
prefix that does not exist. Each is one paragraph naming the file, and nothing is left behind."""

from __future__ import annotations

import io
import json
import shutil
import tarfile
import zipfile
from pathlib import Path

import pytest

pytest.importorskip("torch", reason="the import writes a laplab (torch) checkpoint")
pytest.importorskip("tensorflow", reason="the console export writes model.pb with tensorflow-cpu")

from laplab.cli import main  # noqa: E402
from laplab.errors import UserError  # noqa: E402
from laplab.export.deepracer_import import import_deepracer_model  # noqa: E402
from laplab.store.layout import models_root  # noqa: E402


@pytest.fixture
def source(console_exports, monkeypatch, tmp_path) -> Path:
    """A copy of the PPO camera + lidar export to spoil, in a $LAPLAB_HOME of the test's own."""
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    folder = tmp_path / "export"
    shutil.copytree(console_exports["ppo-cam-lidar"], folder)
    return folder


def refused(source, *matches: str, **options) -> str:
    """Import ``source``, expect a one-paragraph UserError containing ``matches``, and no model (nor a
    staging folder) left in the models folder."""
    with pytest.raises(UserError) as caught:
        import_deepracer_model(source, "spoilt", **options)
    message = str(caught.value)
    assert "\n" not in message and "Traceback" not in message
    for text in matches:
        assert text in message, message
    root = models_root()
    assert not root.exists() or not list(root.iterdir()), list(root.iterdir())
    return message


@pytest.mark.parametrize("missing", ["reward_function.py", "ip/hyperparameters.json"])
def test_a_missing_required_file_is_named(source, missing):
    (source / missing).unlink()
    refused(source, f"{missing} is missing")


def test_missing_metadata_and_missing_weights(source):
    metadata = (source / "model_metadata.json").read_text()
    (source / "model_metadata.json").unlink()
    (source / "model/model_metadata.json").unlink()
    refused(source, "model_metadata.json is missing")
    (source / "model_metadata.json").write_text(metadata)
    for path in (source / "model").glob("*"):
        path.unlink()
    refused(source, "no model weights")


def edit_metadata(folder: Path, **changes) -> None:
    for path in (folder / "model_metadata.json", folder / "model/model_metadata.json"):
        path.write_text(json.dumps({**json.loads(path.read_text()), **changes}))


def test_a_checkpoint_of_another_network_or_action_space_is_refused(source):
    edit_metadata(source, sensor=["FRONT_FACING_CAMERA"])
    refused(source, "0_Step-0.ckpt.index does not hold the network", "LIDAR")
    edit_metadata(source, sensor=["FRONT_FACING_CAMERA", "LIDAR"],
                  action_space=[{"steering_angle": 0.0, "speed": 1.0}, {"steering_angle": 10.0, "speed": 1.0}])
    refused(source, "policy_fc/kernel' has shape [512, 21], expected [512, 2]")
    edit_metadata(source, neural_network="DEEP_CONVOLUTIONAL_NETWORK_DEEP")
    refused(source, "does not hold the network", "DEEP_CONVOLUTIONAL_NETWORK_DEEP")


def test_sac_with_a_discrete_action_space_is_refused(source):
    edit_metadata(source, training_algorithm="sac")
    refused(source, "model_metadata.json", "'sac' needs a continuous action space")


def test_a_truncated_data_file_is_named(source):
    data = source / "model/0_Step-0.ckpt.data-00000-of-00001"
    data.write_bytes(data.read_bytes()[:100_000])
    refused(source, f"{data}: truncated")


def test_a_missing_data_file_and_a_reward_that_does_not_compile(source):
    (source / "reward_function.py").write_text("def reward_function(params):\n    return (")
    refused(source, "reward_function.py does not compile")
    (source / "reward_function.py").write_text("def reward_function(params):\n    return 1.0\n")
    (source / "model/0_Step-0.ckpt.data-00000-of-00001").unlink()
    refused(source, "0_Step-0.ckpt.data-00000-of-00001: missing")


HEAD_BIAS = "main_level/agent/main/online/network_1/ppo_head_0/policy_fc/bias"


def overwrite(source: Path, name: str, at: int, new: bytes, checksum: bool) -> Path:
    """Write ``new`` into variable ``name``'s bytes at ``at`` in the .data file; ``checksum``: update the
    index's CRC-32C to match (a checkpoint TensorFlow wrote with those weights), else leave it."""
    from laplab.export.checkpoint_bundle import read_index
    from laplab.export.crc32c import crc32c, masked
    index = source / "model/0_Step-0.ckpt.index"
    entry = read_index(index)[1][name]
    data = source / "model/0_Step-0.ckpt.data-00000-of-00001"
    raw = bytearray(data.read_bytes())
    raw[entry.offset + at:entry.offset + at + len(new)] = new
    data.write_bytes(bytes(raw))
    if checksum:  # the entry's field 6 (fixed32): tag 0x35, then the masked CRC, little-endian
        old_field = b"\x35" + entry.crc32c.to_bytes(4, "little")
        table = index.read_bytes()
        assert table.count(old_field) == 1
        tensor = bytes(raw[entry.offset:entry.offset + entry.size])
        index.write_bytes(table.replace(old_field, b"\x35" + masked(crc32c(tensor)).to_bytes(4, "little")))
    return data


def test_nan_weights_are_refused(source):
    overwrite(source, HEAD_BIAS, 0, b"\x00\x00\xc0\x7f", checksum=True)  # float32 NaN
    refused(source, f"'{HEAD_BIAS}' holds NaN")


def test_a_flipped_byte_fails_the_tensors_checksum(source):
    from laplab.export.checkpoint_bundle import read_index
    name = "main_level/agent/main/online/network_1/FRONT_FACING_CAMERA/Conv2d_0/kernel"
    entry = read_index(source / "model/0_Step-0.ckpt.index")[1][name]
    raw = (source / "model/0_Step-0.ckpt.data-00000-of-00001").read_bytes()
    at = entry.size // 2
    data = overwrite(source, name, at, bytes([raw[entry.offset + at] ^ 0x04]), checksum=False)
    message = refused(source, f"{data}: variable '{name}'", "does not match its checksum in 0_Step-0.ckpt.index")
    assert "Copy the checkpoint again" in message


def test_a_checkpoint_named_but_absent(source):
    (source / "model/.coach_checkpoint").write_text("9_Step-1.ckpt")
    (source / "model/deepracer_checkpoints.json").unlink()
    refused(source, "model/.coach_checkpoint names checkpoint '9_Step-1.ckpt'")


def tar_with(path: Path, folder: Path, extra: tarfile.TarInfo, data: bytes = b"") -> Path:
    with tarfile.open(path, "w:gz") as tar:
        tar.add(folder, arcname=".")
        tar.addfile(extra, io.BytesIO(data) if extra.isfile() else None)
    return path


@pytest.mark.parametrize("member", ["../escape.py", "/etc/laplab-owned", "model/../../x"])
def test_tar_members_outside_the_folder_are_refused(source, tmp_path, member):
    info = tarfile.TarInfo(member)
    info.size = 3
    refused(tar_with(tmp_path / "bad.tar.gz", source, info, b"bad"), "has an absolute path or '..'")
    assert not (tmp_path / "escape.py").exists()


@pytest.mark.parametrize("kind", [tarfile.SYMTYPE, tarfile.LNKTYPE])
def test_tar_links_are_refused(source, tmp_path, kind):
    info = tarfile.TarInfo("model/link")
    info.type, info.linkname = kind, "reward_function.py"
    refused(tar_with(tmp_path / "link.tar.gz", source, info), "'model/link' is a link")


def test_zip_with_dot_dot_is_refused(source, tmp_path):
    with zipfile.ZipFile(tmp_path / "bad.zip", "w") as archive:
        archive.writestr("model_metadata.json", "{}")
        archive.writestr("../../escape.py", "x")
    refused(tmp_path / "bad.zip", "'../../escape.py' has an absolute path or '..'")


def test_zip_symlink_is_refused(source, tmp_path):
    import stat
    link = zipfile.ZipInfo("model/link")
    link.external_attr = (stat.S_IFLNK | 0o777) << 16
    with zipfile.ZipFile(tmp_path / "link.zip", "w") as archive:
        archive.writestr("model_metadata.json", (source / "model_metadata.json").read_text())
        archive.writestr(link, "/etc/passwd")
    refused(tmp_path / "link.zip", "'model/link' is a link")


def test_an_archive_over_the_size_limit_is_refused(source, tmp_path):
    with tarfile.open(tmp_path / "big.tar.gz", "w:gz") as tar:
        tar.add(source, arcname=".")
    refused(tmp_path / "big.tar.gz", "over the import limit of 1 MB", max_bytes=1_000_000)


def test_a_damaged_archive_and_the_cli_paragraph(source, tmp_path, capsys):
    (tmp_path / "cut.zip").write_bytes(b"PK\x03\x04 not really")
    refused(tmp_path / "cut.zip", "not a readable zip archive")
    assert main(["import", str(source / "nothing-here"), "--name", "x"]) != 0
    assert "no such file or folder" in capsys.readouterr().err
