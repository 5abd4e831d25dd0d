import json
import math

import pytest

from laplab.store.atomic import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    atomic_write_with,
    read_json,
)


def test_round_trips_and_creates_parent_folders(tmp_path):
    target = tmp_path / "a" / "b" / "file.bin"
    atomic_write_bytes(target, b"\x00\x01")
    assert target.read_bytes() == b"\x00\x01"
    atomic_write_text(target, "héllo\n")
    assert target.read_text(encoding="utf-8") == "héllo\n"
    atomic_write_json(target, {"x": [1, 2.5, None]})
    assert json.loads(target.read_text()) == {"x": [1, 2.5, None]}
    assert read_json(target) == {"x": [1, 2.5, None]}


def test_failed_writer_keeps_old_content_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "state.json"
    atomic_write_json(target, {"version": 1})

    def broken_writer(path):
        path.write_text('{"version": 2')  # half written, then the writer dies
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError, match="disk on fire"):
        atomic_write_with(target, broken_writer)
    assert read_json(target) == {"version": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]


def test_callable_writer_gets_a_path_in_the_same_folder(tmp_path):
    seen = []
    atomic_write_with(tmp_path / "ckpt", lambda p: (seen.append(p), p.write_bytes(b"abc")))
    assert seen[0].parent == tmp_path and seen[0].name != "ckpt"
    assert (tmp_path / "ckpt").read_bytes() == b"abc"
    assert not seen[0].exists()


def test_refuses_nan_and_non_bytes_with_the_path_in_the_message(tmp_path):
    with pytest.raises(ValueError, match="bad.json"):
        atomic_write_json(tmp_path / "bad.json", {"x": math.nan})
    with pytest.raises(TypeError, match="f.bin"):
        atomic_write_bytes(tmp_path / "f.bin", "text")
    assert list(tmp_path.iterdir()) == []


def test_read_json_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.json"):
        read_json(tmp_path / "missing.json")
    (tmp_path / "broken.json").write_text("{nope")
    with pytest.raises(ValueError, match="broken.json.*line 1"):
        read_json(tmp_path / "broken.json")
