"""CRC-32C (Castagnoli), as TensorFlow checksums a checkpoint's tensors, in numpy alone.

TensorFlow's ``BundleEntryProto.crc32c`` is the *masked* CRC-32C of a tensor's bytes in the
``.data`` file (:func:`masked`: rotated right by 15 bits plus ``0xa282ead8``, LevelDB's mask).

A byte-at-a-time table loop in Python runs at ~5 MB/s; here the data is cut into ``K`` chunks of
``L`` bytes whose CRC registers advance together (``L / 4`` vectorised steps over ``K`` lanes, four
bytes a step with four tables: "slicing by 4"), and the chunks' registers are then merged pairwise
in a tree. This works because, without its initial and final inversion, the CRC register is linear
over GF(2): the register after ``A || B`` is ``shift_|B|(register after A) ^ register of B from
zero``, where ``shift_n`` (the register run through ``n`` zero bytes) is a 32x32 bit matrix, applied
here with four 256-entry tables and squared to double ``n`` at each level of the tree.
"""

from __future__ import annotations

import numpy as np

POLYNOMIAL = 0x82F63B78  # Castagnoli's, bit-reflected
MASK_DELTA = 0xA282EAD8
MAX_LANES = 1 << 16  # chunks processed side by side
MIN_CHUNK = 256  # bytes per chunk at least (fewer lanes for small tensors)


def _byte_table() -> np.ndarray:
    """(256,) uint32: the register after one byte ``b`` from register 0 (the classic CRC table)."""
    values = np.arange(256, dtype=np.uint32)
    for _ in range(8):
        values = np.where(values & 1, (values >> 1) ^ np.uint32(POLYNOMIAL), values >> 1).astype(np.uint32)
    return values


TABLE = _byte_table()
BIT_VALUES = (np.uint32(1) << np.arange(32, dtype=np.uint32))


def _zero_byte_columns() -> np.ndarray:
    """(32,) uint32: the register of each single set bit after one zero byte (the matrix's columns)."""
    return (TABLE[BIT_VALUES & 0xFF] ^ (BIT_VALUES >> 8)).astype(np.uint32)


def _apply(columns: np.ndarray, registers: np.ndarray) -> np.ndarray:
    """The linear map with ``columns`` (32,) applied to ``registers`` (any shape) uint32."""
    tables = _byte_tables(columns)
    return (tables[0][registers & 0xFF] ^ tables[1][(registers >> 8) & 0xFF]
            ^ tables[2][(registers >> 16) & 0xFF] ^ tables[3][registers >> 24]).astype(np.uint32)


def _byte_tables(columns: np.ndarray) -> list[np.ndarray]:
    """Four (256,) tables: the map's image of each value of byte 0..3 of a register."""
    bits = ((np.arange(256, dtype=np.uint32)[:, None] >> np.arange(8, dtype=np.uint32)) & 1).astype(bool)
    tables = []
    for byte in range(4):
        images = np.where(bits, columns[8 * byte:8 * byte + 8][None, :], np.uint32(0))
        tables.append(np.bitwise_xor.reduce(images, axis=1).astype(np.uint32))
    return tables


def _compose(outer: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """Columns of ``outer`` after ``inner``."""
    return _apply(outer, inner)


def _shift_columns(length: int) -> np.ndarray:
    """Columns of the map running a register through ``length`` zero bytes (by squaring)."""
    result = BIT_VALUES.copy()  # identity
    power = _zero_byte_columns()
    while length:
        if length & 1:
            result = _compose(power, result)
        power = _compose(power, power)
        length >>= 1
    return result


def _slicing_tables() -> np.ndarray:
    """(4, 256) int64: ``[k][b]`` the register after byte ``b`` then ``k`` zero bytes, from register 0
    (four bytes per step: "slicing by 4")."""
    tables = [TABLE.astype(np.int64)]
    for _ in range(3):
        last = tables[-1]
        tables.append((last >> 8) ^ tables[0][last & 0xFF])
    return np.stack(tables)


SLICES = _slicing_tables()


def _register(data: np.ndarray) -> int:
    """The CRC register after ``data`` (uint8, 1-D) from register 0, no inversions."""
    size = data.size
    if size == 0:
        return 0
    lanes = 1
    while lanes < MAX_LANES and lanes * 2 * MIN_CHUNK <= size:
        lanes *= 2
    chunk = -(-size // (4 * lanes)) * 4  # bytes per lane, whole 4-byte words
    padded = np.zeros(lanes * chunk, np.uint8)  # zeros in front leave a register of 0 unchanged
    padded[lanes * chunk - size:] = data
    words = np.ascontiguousarray(padded.view("<u4").reshape(lanes, chunk // 4).T)  # (words, lanes)
    registers = np.zeros(lanes, np.int64)  # int64 lanes: numpy gathers with them ~3x faster than uint32
    t0, t1, t2, t3 = SLICES
    for word in words:
        value = registers ^ word
        registers = (np.take(t3, value & 0xFF) ^ np.take(t2, (value >> 8) & 0xFF)
                     ^ np.take(t1, (value >> 16) & 0xFF) ^ np.take(t0, value >> 24))
    registers = registers.astype(np.uint32)
    shift = _shift_columns(chunk)
    while registers.size > 1:  # merge neighbours: shift the left one past the right one's bytes
        registers = _apply(shift, registers[0::2]) ^ registers[1::2]
        shift = _compose(shift, shift)
    return int(registers[0])


def crc32c(data: bytes | bytearray | memoryview | np.ndarray) -> int:
    """CRC-32C of ``data`` (initial register and final value inverted, as everyone computes it)."""
    array = np.frombuffer(data, np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1).view(np.uint8)
    start = int(_apply(_shift_columns(array.size), np.array([0xFFFFFFFF], np.uint32))[0])
    return (start ^ _register(array)) ^ 0xFFFFFFFF


def masked(crc: int) -> int:
    """TensorFlow's (LevelDB's) masked CRC: rotated right by 15 bits, plus ``0xa282ead8``, mod 2^32."""
    return ((((crc >> 15) | (crc << 17)) & 0xFFFFFFFF) + MASK_DELTA) & 0xFFFFFFFF
