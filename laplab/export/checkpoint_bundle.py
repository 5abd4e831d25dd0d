"""TensorFlow's checkpoint files read with numpy alone (no TensorFlow): what ``laplab import`` needs to
take an rl_coach checkpoint (``<N>_Step-<steps>.ckpt.index`` + ``.data-00000-of-00001``).

A checkpoint is a "tensor bundle":

- ``.index`` is a LevelDB-style sorted table: data blocks of prefix-compressed ``key -> value``
  entries (each block followed by a 1-byte compression type and a 4-byte CRC), an index block
  naming the data blocks, and a 48-byte footer (two block handles, padding, the magic number
  ``0xdb4775248b80fb57``). The empty key holds the ``BundleHeaderProto``; every other key is a
  variable name whose value is a ``BundleEntryProto`` (dtype, shape, shard, offset, size, crc32c);
- ``.data-<shard>-of-<shards>`` are the tensors' raw little-endian bytes at those offsets.

Each tensor read is checked against its entry's masked CRC-32C (:mod:`laplab.export.crc32c`), so a
damaged ``.data`` file (a flipped byte, a copy cut short and padded) is refused, naming the tensor.
Errors are :class:`BundleError` naming the file and what is wrong (a truncated or damaged ``.data``
file, an index that is not a table, a dtype laplab does not read).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from laplab.errors import UserError
from laplab.export.crc32c import crc32c, masked

TABLE_MAGIC = 0xDB4775248B80FB57
FOOTER_SIZE = 48
BLOCK_TRAILER_SIZE = 5  # compression type (1 byte) + masked crc32c (4 bytes)
DTYPES = {1: np.float32, 2: np.float64, 3: np.int32, 9: np.int64, 10: np.bool_}  # tensorflow DataType enum


class BundleError(UserError, ValueError):
    """A TensorFlow checkpoint that cannot be read; the message names the file."""


@dataclass(frozen=True)
class BundleEntry:
    """One variable of a checkpoint: dtype (numpy), shape, and where its bytes are (shard, offset, size)."""

    name: str
    dtype: type
    shape: tuple[int, ...]
    shard: int
    offset: int
    size: int
    crc32c: int | None = None  # masked CRC-32C of the bytes (None: the index gives none)


def _varint(data: bytes, position: int, where: str) -> tuple[int, int]:
    value, shift = 0, 0
    while True:
        if position >= len(data) or shift > 63:
            raise BundleError(f"{where}: a number runs past the end of its record; the file is damaged.")
        byte = data[position]
        value |= (byte & 0x7F) << shift
        position += 1
        shift += 7
        if not byte & 0x80:
            return value, position


def _fields(data: bytes, where: str):
    """(field number, wire type, value) of a protocol buffer message (value: int or bytes)."""
    position = 0
    while position < len(data):
        key, position = _varint(data, position, where)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, position = _varint(data, position, where)
        elif wire == 2:
            length, position = _varint(data, position, where)
            value, position = data[position:position + length], position + length
        elif wire == 5:
            value, position = int.from_bytes(data[position:position + 4], "little"), position + 4
        elif wire == 1:
            value, position = int.from_bytes(data[position:position + 8], "little"), position + 8
        else:
            raise BundleError(f"{where}: unreadable record (wire type {wire}); the file is damaged.")
        if position > len(data):
            raise BundleError(f"{where}: a record runs past its end; the file is damaged.")
        yield number, wire, value


def _block(data: bytes, handle: bytes, where: str) -> list[tuple[bytes, bytes]]:
    """The ``(key, value)`` entries of the block that ``handle`` (offset, size varints) points at."""
    offset, position = _varint(handle, 0, where)
    size, _ = _varint(handle, position, where)
    if offset + size + BLOCK_TRAILER_SIZE > len(data) or size < 4:
        raise BundleError(f"{where}: a block lies outside the file ({len(data)} bytes); the index is truncated.")
    if data[offset + size] != 0:
        raise BundleError(f"{where}: a compressed block (type {data[offset + size]}); TensorFlow writes checkpoint "
                          "indexes uncompressed, so this is not one laplab can read.")
    block = data[offset:offset + size]
    restarts = struct.unpack_from("<I", block, size - 4)[0]
    end = size - 4 - 4 * restarts
    entries, key, position = [], b"", 0
    while position < end:
        shared, position = _varint(block, position, where)
        unshared, position = _varint(block, position, where)
        length, position = _varint(block, position, where)
        key = key[:shared] + block[position:position + unshared]
        position += unshared
        entries.append((key, block[position:position + length]))
        position += length
    return entries


def tensor_shape(message: bytes, where: str) -> list[int]:
    """The sizes of a TensorShapeProto (its ``dim`` fields' ``size``), outermost first."""
    return [next((v for n, _, v in _fields(dim, where) if n == 1), 0)
            for number, _, dim in _fields(message, where) if number == 2]


def _entry(name: str, value: bytes, where: str) -> BundleEntry:
    dtype, shape, shard, offset, size, slices, checksum = 0, [], 0, 0, 0, False, None
    for number, _, field in _fields(value, where):
        if number == 1:
            dtype = field
        elif number == 2:
            shape = tensor_shape(field, where)
        elif number == 3:
            shard = field
        elif number == 4:
            offset = field
        elif number == 5:
            size = field
        elif number == 6:
            checksum = field
        elif number == 7:
            slices = True
    if slices:
        raise BundleError(f"{where}: variable {name!r} is saved in slices (a partitioned variable); laplab reads "
                          "whole tensors only.")
    if dtype not in DTYPES:
        raise BundleError(f"{where}: variable {name!r} has TensorFlow dtype {dtype}, which laplab does not read.")
    return BundleEntry(name, DTYPES[dtype], tuple(shape), shard, offset, size, checksum)


def read_index(index_path: str | Path) -> tuple[int, dict[str, BundleEntry]]:
    """``(number of shards, {variable name: entry})`` of a checkpoint's ``.index`` file."""
    path = Path(index_path)
    data = path.read_bytes()
    where = str(path)
    if len(data) < FOOTER_SIZE or struct.unpack_from("<Q", data, len(data) - 8)[0] != TABLE_MAGIC:
        raise BundleError(f"{where}: not a TensorFlow checkpoint index (no table footer); the file is truncated "
                          "or is something else.")
    footer = data[-FOOTER_SIZE:]
    _, position = _varint(footer, 0, where)  # metaindex handle: offset
    _, position = _varint(footer, position, where)  # metaindex handle: size
    index_handle = footer[position:]
    shards, entries = 1, {}
    for _, handle in _block(data, index_handle, where):
        for key, value in _block(data, handle, where):
            if key == b"":
                shards = next((v for n, _, v in _fields(value, where) if n == 1), 1) or 1
                continue
            name = key.decode("utf-8", "replace")
            entries[name] = _entry(name, value, where)
    return shards, entries


def data_paths(prefix: str | Path, shards: int) -> list[Path]:
    return [Path(f"{prefix}.data-{shard:05d}-of-{shards:05d}") for shard in range(shards)]


def read_checkpoint(prefix: str | Path, names: set[str] | None = None) -> dict[str, np.ndarray]:
    """``{variable name: array}`` of the checkpoint ``prefix`` (``.../30_Step-163797.ckpt``);
    ``names``: only those variables (default all). A ``.data`` file shorter than its index says is
    refused, naming the file and the variable that runs past its end."""
    shards, entries = read_index(f"{prefix}.index")
    paths = data_paths(prefix, shards)
    wanted = [entry for name, entry in entries.items() if names is None or name in names]
    arrays: dict[str, np.ndarray] = {}
    for shard, path in enumerate(paths):
        in_shard = [entry for entry in wanted if entry.shard == shard]
        if not in_shard:
            continue
        if not path.is_file():
            raise BundleError(f"{path}: missing; the checkpoint's index names it as shard {shard} of {shards}.")
        size = path.stat().st_size
        with open(path, "rb") as handle:
            for entry in sorted(in_shard, key=lambda e: e.offset):
                expected = int(np.prod(entry.shape, dtype=np.int64)) * np.dtype(entry.dtype).itemsize
                if entry.size != expected:
                    raise BundleError(f"{prefix}.index: variable {entry.name!r} has {entry.size} bytes for shape "
                                      f"{list(entry.shape)} ({expected} expected); the index is damaged.")
                if entry.offset + entry.size > size:
                    raise BundleError(f"{path}: truncated ({size} bytes): variable {entry.name!r} lies at bytes "
                                      f"{entry.offset}-{entry.offset + entry.size}. Copy the checkpoint again.")
                handle.seek(entry.offset)
                raw = handle.read(entry.size)
                if entry.crc32c is not None and masked(crc32c(raw)) != entry.crc32c:
                    raise BundleError(f"{path}: variable {entry.name!r} (bytes {entry.offset}-"
                                      f"{entry.offset + entry.size}) does not match its checksum in "
                                      f"{Path(f'{prefix}.index').name}: the file is damaged (a changed byte, or a copy "
                                      "cut short and padded). Copy the checkpoint again from where it was trained.")
                arrays[entry.name] = np.frombuffer(raw, dtype=np.dtype(entry.dtype).newbyteorder("<")) \
                    .astype(entry.dtype).reshape(entry.shape)
    return arrays
