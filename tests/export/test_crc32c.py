"""laplab's numpy CRC-32C: the standard check value, a byte-at-a-time reference on every chunking the
lanes make (sizes around the chunk and word boundaries), and TensorFlow's own checksums of a
checkpoint it wrote (``BundleEntryProto.crc32c``, masked)."""

from __future__ import annotations

import numpy as np
import pytest

from laplab.export.crc32c import TABLE, crc32c, masked


def byte_at_a_time(data: bytes) -> int:
    register = 0xFFFFFFFF
    for byte in data:
        register = int(TABLE[(register ^ byte) & 0xFF]) ^ (register >> 8)
    return register ^ 0xFFFFFFFF


def test_the_standard_check_value():
    assert crc32c(b"123456789") == 0xE3069283  # CRC-32C's check value (RFC 3720, iSCSI)
    assert crc32c(b"") == 0


@pytest.mark.parametrize("size", [1, 3, 4, 5, 255, 511, 512, 513, 1023, 1024, 1025, 4099, 70_001, 262_147])
def test_matches_a_byte_at_a_time_crc(size):
    data = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes()
    assert crc32c(data) == byte_at_a_time(data)


def test_matches_tensorflows_checksums(tmp_path):
    tf = pytest.importorskip("tensorflow")
    from laplab.export.checkpoint_bundle import read_index

    graph = tf.Graph()
    with graph.as_default():
        shapes = {"a": [3], "b": [17, 5], "c": [64, 1001]}
        for name, shape in shapes.items():
            tf.compat.v1.get_variable(name, shape, initializer=tf.compat.v1.random_normal_initializer())
        saver = tf.compat.v1.train.Saver()
        with tf.compat.v1.Session(graph=graph) as session:
            session.run(tf.compat.v1.global_variables_initializer())
            saver.save(session, str(tmp_path / "x.ckpt"), write_meta_graph=False, write_state=False)
    _, entries = read_index(tmp_path / "x.ckpt.index")
    data = (tmp_path / "x.ckpt.data-00000-of-00001").read_bytes()
    for name in shapes:
        entry = entries[name]
        assert entry.crc32c is not None
        assert masked(crc32c(data[entry.offset:entry.offset + entry.size])) == entry.crc32c
