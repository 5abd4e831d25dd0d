"""The resume state's compressed tensors: the same bits back, smaller files, clear errors."""

import io

import pytest
import torch

from laplab.store.atomic import CorruptFileError
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import ModelFolder
from laplab.train.checkpoint_read import read_resume_state
from laplab.train.resume_codec import MIN_PACKED_ELEMENTS, PACKED_KEY, pack_state, unpack_state


def _adam_like(seed: int = 0) -> dict:
    """Moments shaped as Adam leaves them: a quarter exact zeros (inputs that never fire), the rest
    small numbers of similar magnitude."""
    generator = torch.Generator().manual_seed(seed)
    grads = torch.randn(512, 300, generator=generator) * 1e-3
    grads[:, :75] = 0.0
    return {"state": {0: {"step": torch.tensor(12.0), "exp_avg": grads.clone(), "exp_avg_sq": grads ** 2},
                      1: {"step": torch.tensor(12.0), "exp_avg": torch.ones(10), "exp_avg_sq": torch.ones(10)}},
            "param_groups": [{"lr": 3e-4, "betas": (0.9, 0.999), "params": [0, 1]}]}


def _size(state) -> int:
    buffer = io.BytesIO()
    torch.save(state, buffer)
    return buffer.tell()


def _same_bits(a: torch.Tensor, b: torch.Tensor) -> bool:
    return (a.dtype == b.dtype and a.shape == b.shape
            and torch.equal(a.contiguous().reshape(-1).view(torch.uint8), b.contiguous().reshape(-1).view(torch.uint8)))


def test_round_trip_is_exact_and_smaller():
    state = {"optimizer": _adam_like(), "half": torch.randn(MIN_PACKED_ELEMENTS).to(torch.bfloat16),
             "double": torch.randn(300, 300, dtype=torch.float64), "counts": torch.arange(100_000)}
    packed = pack_state(state)
    assert PACKED_KEY in packed["optimizer"]["state"][0]["exp_avg"]
    assert isinstance(packed["optimizer"]["state"][1]["exp_avg"], torch.Tensor)  # small: as it was
    assert isinstance(packed["counts"], torch.Tensor)  # integers: as they were
    assert packed["optimizer"]["param_groups"] == state["optimizer"]["param_groups"]
    buffer = io.BytesIO()
    torch.save(packed, buffer)
    buffer.seek(0)
    restored = unpack_state(torch.load(buffer, weights_only=True))
    for key in ("half", "double", "counts"):
        assert _same_bits(restored[key], state[key])
    for index in (0, 1):
        for key, value in state["optimizer"]["state"][index].items():
            assert _same_bits(restored["optimizer"]["state"][index][key], value)
    moments = {"exp_avg": state["optimizer"]["state"][0]["exp_avg"]}
    assert _size(pack_state(moments)) < 0.85 * _size(moments)


def test_a_state_without_packed_tensors_comes_back_as_it_was():
    state = {"optimizer": {"state": {0: {"exp_avg": torch.ones(3)}}, "param_groups": [{"lr": 1.0}]}}
    restored = unpack_state(state)
    assert restored["optimizer"]["param_groups"] == [{"lr": 1.0}]
    assert _same_bits(restored["optimizer"]["state"][0]["exp_avg"], torch.ones(3))


def test_a_damaged_packed_tensor_is_a_clear_error(tmp_path):
    folder = ModelFolder(tmp_path / "m").create()
    store = CheckpointStore(folder)
    store.save(lambda path: torch.save({"learner": {"model": {"w": torch.ones(2)}}}, path), iteration=1, steps=10,
               resume=lambda path: torch.save({"learner": pack_state({"optimizer": _adam_like()})}, path))
    name, state = read_resume_state(folder)
    assert torch.equal(state["learner"]["optimizer"]["state"][0]["exp_avg"], _adam_like()["state"][0]["exp_avg"])
    damaged = pack_state({"optimizer": _adam_like()})
    entry = damaged["optimizer"]["state"][0]["exp_avg"]
    entry[PACKED_KEY] = entry[PACKED_KEY][: len(entry[PACKED_KEY]) // 2].clone()
    torch.save({"learner": damaged}, store.resume_path(name))
    with pytest.raises(CorruptFileError, match=r"resume state .*1_Step-10\.ckpt\.resume.* is damaged"):
        read_resume_state(folder)
