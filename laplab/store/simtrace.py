"""Simtrace CSV files exactly as deepracer-for-cloud writes them, so deepracer-utils reads them.

One row per step, 19 columns (`SIMTRACE_COLUMNS`). Conventions (from the DeepRacer simapp):
`episode` is a run-wide 0-based counter (not reset per iteration); `X`, `Y` in metres; `yaw` in
degrees; `steer` in degrees and `throttle` in m/s (the action taken); `action` is the action
index for a discrete space, or the string `[steer speed]` (space-separated, no comma) for a
continuous one; `done` and `all_wheels_on_track` are `True`/`False`; `tstamp` is simulation
time in seconds; `episode_status` is a raw status code (`EPISODE_STATUSES`); `wall_clock` is
Unix time in seconds.

Crash safety: `SimtraceWriter` appends each batch with a single write and flushes (and by
default fsyncs) it, so every finished batch stays readable if the process dies. A torn final
line (power cut mid-write) is dropped by `read_simtrace` and cut off when a writer reopens the
file. One file per training iteration; a crash loses at most the batch being written.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
from numba import njit

from laplab.store.csv_numbers import put_fixed, put_general, put_int

SIMTRACE_COLUMNS = (
    "episode", "steps", "X", "Y", "yaw", "steer", "throttle", "action", "reward", "done",
    "all_wheels_on_track", "progress", "closest_waypoint", "track_len", "tstamp",
    "episode_status", "pause_duration", "obstacle_crash_counter", "wall_clock",
)
SIMTRACE_HEADER = ",".join(SIMTRACE_COLUMNS)

EPISODE_STATUSES = (
    "prepare", "in_progress", "lap_complete", "crashed", "off_track", "immobilized",
    "reversed", "time_up", "pause", "park",
)

_INT_COLUMNS = ("episode", "steps", "closest_waypoint", "obstacle_crash_counter")
_BOOL_COLUMNS = ("done", "all_wheels_on_track")
# Decimals written per float column (trailing zeros trimmed, one kept: 30 -> "30.0"). Reward is
# written with 7 significant digits instead, switching to exponent form below 1e-5, because
# DeepRacer rewards such as 1e-3 and 1e-8 must survive.
_FLOAT_DECIMALS = {
    "X": 4, "Y": 4, "yaw": 4, "steer": 4, "throttle": 4, "progress": 4, "track_len": 4,
    "tstamp": 4, "pause_duration": 4, "wall_clock": 3,
}
_REWARD_SIGNIFICANT_DIGITS = 7
_OPTIONAL_DEFAULTS = ("pause_duration", "obstacle_crash_counter", "wall_clock")
_STRING = np.dtypes.StringDType()

# Rendering plan: each output column is (kind, slot in the int64 or float64 matrix, decimals).
_INT, _FIXED, _GENERAL, _TOKEN, _PAIR = range(5)
_TOKENS = ("False", "True", *EPISODE_STATUSES)  # bools are tokens 0/1, statuses 2 + index
_TOKEN_BYTES = np.zeros((len(_TOKENS), max(map(len, _TOKENS))), np.uint8)
for _index, _token in enumerate(_TOKENS):
    _TOKEN_BYTES[_index, : len(_token)] = np.frombuffer(_token.encode(), np.uint8)
_TOKEN_LENGTHS = np.array([len(token) for token in _TOKENS], np.int64)
_MAX_ROW_BYTES = 1024  # generous bound: 19 fields of at most ~40 bytes
_CHUNK_ROWS = 8192


# _render writes ASCII codes: 10 newline, 32 space, 44 ',', 91 '[', 93 ']'. nogil: the model folder's writer
# thread renders while the trainer's thread collects (laplab.train.background).
@njit(cache=True, nogil=True)
def _render(kinds, slots, decimals, integers, numbers, token_bytes, token_lengths, buffer):
    """CSV bytes of rows (n,) into `buffer`; integers (n, a) int64, numbers (n, b) float64.
    Returns the number of bytes written."""
    position = 0
    for row in range(integers.shape[0]):
        for column in range(kinds.shape[0]):
            kind, slot = kinds[column], slots[column]
            if kind == _INT:
                position = put_int(buffer, position, integers[row, slot])
            elif kind == _FIXED:
                position = put_fixed(buffer, position, numbers[row, slot], decimals[column])
            elif kind == _GENERAL:
                position = put_general(buffer, position, numbers[row, slot], decimals[column])
            elif kind == _TOKEN:
                token = integers[row, slot]
                length = token_lengths[token]
                buffer[position:position + length] = token_bytes[token, :length]
                position += length
            else:  # _PAIR: "[steer speed]"
                buffer[position] = 91
                position = put_fixed(buffer, position + 1, numbers[row, slot], decimals[column])
                buffer[position] = 32
                position = put_fixed(buffer, position + 1, numbers[row, slot + 1], decimals[column])
                buffer[position] = 93
                position += 1
            buffer[position] = 44 if column < kinds.shape[0] - 1 else 10
            position += 1
    return position


def _column_error(name: str, message: str) -> ValueError:
    return ValueError(f"simtrace column {name!r}: {message}")


def _as_integers(name: str, values: np.ndarray) -> np.ndarray:
    if not (np.issubdtype(values.dtype, np.integer) or values.dtype == np.bool_):
        raise _column_error(name, f"needs integers, got dtype {values.dtype}")
    return values.astype(np.int64)


def _status_tokens(values: np.ndarray) -> np.ndarray:
    """Token numbers of episode_status given as codes ('off_track') or EPISODE_STATUSES indices."""
    if np.issubdtype(values.dtype, np.integer):
        if values.size and (values.min() < 0 or values.max() >= len(EPISODE_STATUSES)):
            raise _column_error("episode_status", "integer statuses index EPISODE_STATUSES (0.."
                                f"{len(EPISODE_STATUSES) - 1}); got {values.min()}..{values.max()}")
        return values.astype(np.int64) + 2
    unique, inverse = np.unique(np.array(values.tolist(), dtype=str), return_inverse=True)  # any string dtype
    lookup = {status: index + 2 for index, status in enumerate(EPISODE_STATUSES)}
    unknown = [status for status in unique.tolist() if status not in lookup]
    if unknown:
        raise _column_error("episode_status",
                            f"unknown status(es) {unknown[:5]}; valid codes: {list(EPISODE_STATUSES)}")
    return np.array([lookup[status] for status in unique.tolist()], np.int64)[inverse.reshape(-1)]


def _render_rows(columns: dict[str, np.ndarray]) -> bytes:
    unknown = sorted(set(columns) - set(SIMTRACE_COLUMNS))
    missing = [name for name in SIMTRACE_COLUMNS if name not in columns and name not in _OPTIONAL_DEFAULTS]
    if unknown or missing:
        raise ValueError(f"simtrace columns: missing {missing}, unknown {unknown}; "
                         f"expected {list(SIMTRACE_COLUMNS)}")
    arrays = {name: np.asarray(values) for name, values in columns.items()}
    n_rows = len(arrays["episode"]) if arrays["episode"].ndim == 1 else -1
    for name, values in arrays.items():
        if name != "action" and (values.ndim != 1 or len(values) != n_rows):
            raise ValueError("simtrace columns must be 1-D arrays of equal length; got shapes "
                             f"{ {k: v.shape for k, v in arrays.items()} }")
    if n_rows == 0:
        return b""
    arrays.setdefault("pause_duration", np.zeros(n_rows))
    arrays.setdefault("obstacle_crash_counter", np.zeros(n_rows, np.int64))
    arrays.setdefault("wall_clock", np.full(n_rows, time.time()))
    integer_columns, number_columns, plan = [], [], []
    for name in SIMTRACE_COLUMNS:
        values = arrays[name]
        if name in _INT_COLUMNS:
            plan.append((_INT, len(integer_columns), 0))
            integer_columns.append(_as_integers(name, values))
        elif name in _BOOL_COLUMNS:
            if values.dtype != np.bool_ and not np.issubdtype(values.dtype, np.integer):
                raise _column_error(name, f"needs booleans, got dtype {values.dtype}")
            plan.append((_TOKEN, len(integer_columns), 0))
            integer_columns.append(values.astype(bool).astype(np.int64))
        elif name == "episode_status":
            plan.append((_TOKEN, len(integer_columns), 0))
            integer_columns.append(_status_tokens(values))
        elif name == "action" and values.shape == (n_rows,) and np.issubdtype(values.dtype, np.integer):
            plan.append((_INT, len(integer_columns), 0))
            integer_columns.append(values.astype(np.int64))
        elif name == "action":
            if values.shape != (n_rows, 2) or not np.issubdtype(values.dtype, np.number):
                raise _column_error("action", f"needs integer indices of shape ({n_rows},) for a discrete action "
                                              f"space or (steering_deg, speed) pairs of shape ({n_rows}, 2) for a "
                                              f"continuous one; got shape {values.shape}, dtype {values.dtype}")
            plan.append((_PAIR, len(number_columns), 4))
            number_columns += [values[:, 0], values[:, 1]]
        else:
            if not np.issubdtype(values.dtype, np.number) or np.iscomplexobj(values):
                raise _column_error(name, f"needs real numbers, got dtype {values.dtype}")
            general = name == "reward"
            plan.append((_GENERAL if general else _FIXED, len(number_columns),
                         _REWARD_SIGNIFICANT_DIGITS if general else _FLOAT_DECIMALS[name]))
            number_columns.append(values)
    kinds, slots, decimals = (np.array(part, np.int64) for part in zip(*plan))
    integers = np.column_stack(integer_columns).astype(np.int64)
    numbers = np.column_stack(number_columns).astype(np.float64)
    buffer = np.empty(min(n_rows, _CHUNK_ROWS) * _MAX_ROW_BYTES, np.uint8)
    chunks = []
    for start in range(0, n_rows, _CHUNK_ROWS):
        stop = start + _CHUNK_ROWS
        length = _render(kinds, slots, decimals, integers[start:stop], numbers[start:stop],
                         _TOKEN_BYTES, _TOKEN_LENGTHS, buffer)
        chunks.append(buffer[:length].tobytes())
    return b"".join(chunks)


def format_rows(columns: dict[str, np.ndarray]) -> str:
    """Simtrace rows (no header) as CSV text ending in a newline; '' for zero rows.

    `columns` maps every name in `SIMTRACE_COLUMNS` to an array of n rows: `action` is (n,)
    int for a discrete space or (n, 2) float (steering_deg, speed) for a continuous one;
    `episode_status` holds codes ('off_track') or indices into `EPISODE_STATUSES`.
    `pause_duration` and `obstacle_crash_counter` default to 0 and `wall_clock` to now.
    """
    return _render_rows(columns).decode("ascii")


def compile_renderer() -> None:
    """Compile the row renderer now (numba: several seconds on a machine whose cache is cold, e.g. a
    fresh GPU machine; then read from the cache): the model folder's writer thread calls it when a
    job starts, so the first iteration's simtrace does not wait for it (laplab.train.background)."""
    row = {name: np.zeros(1, np.int64) for name in (*_INT_COLUMNS, "action")}
    row.update({name: np.zeros(1, bool) for name in _BOOL_COLUMNS})
    row.update({name: np.zeros(1) for name in _FLOAT_DECIMALS})
    row.update(reward=np.zeros(1), episode_status=np.zeros(1, np.int64))
    _render_rows(row)  # one compiled kernel renders every column plan (discrete or continuous actions)


class SimtraceWriter:
    """Appends batches of rows to one simtrace CSV (header written when the file is new).

    Use as a context manager or call `close()`. Reopening an existing file appends to it after
    checking its header and cutting off a torn last line. `fsync=False` skips the per-batch
    fsync (faster; rows then survive a process crash but not a power cut).
    """

    def __init__(self, path: str | os.PathLike, fsync: bool = True):
        self.path = Path(path)
        self.fsync = fsync
        self.rows_written = 0
        self._descriptor = -1
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._descriptor = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_APPEND, 0o644)
        try:
            self._prepare_existing_file()
        except BaseException:
            self.close()
            raise

    def _prepare_existing_file(self) -> None:
        size = os.fstat(self._descriptor).st_size
        header = (SIMTRACE_HEADER + "\n").encode()
        if size > 0:
            head = os.pread(self._descriptor, len(header), 0)
            if head != header[: len(head)]:
                raise ValueError(
                    f"{str(self.path)!r} exists but does not start with the simtrace header "
                    f"{SIMTRACE_HEADER!r}; refusing to append to it (move it away or pick another path)"
                )
            tail_start = max(0, size - 65536)
            tail = os.pread(self._descriptor, size - tail_start, tail_start)
            last_newline = tail.rfind(b"\n")
            # Keep through the last complete line; a torn header means starting the file afresh.
            torn_header = last_newline < 0 or tail_start + last_newline < len(header) - 1
            keep = 0 if torn_header else tail_start + last_newline + 1
            if keep != size:
                os.ftruncate(self._descriptor, keep)
                size = keep
        if size == 0:
            self._write(header)

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            written = os.write(self._descriptor, view)
            view = view[written:]
        if self.fsync:
            os.fsync(self._descriptor)

    def write_rows(self, columns: dict[str, np.ndarray]) -> int:
        """Append n rows given as columns (see `format_rows`); returns n."""
        if self._descriptor < 0:
            raise ValueError(f"SimtraceWriter for {str(self.path)!r} is closed")
        data = _render_rows(columns)
        n_rows = data.count(b"\n")
        if n_rows:
            self._write(data)
            self.rows_written += n_rows
        return n_rows

    def close(self) -> None:
        if self._descriptor >= 0:
            os.close(self._descriptor)
            self._descriptor = -1

    def __enter__(self) -> "SimtraceWriter":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()


def _empty_columns() -> dict[str, np.ndarray]:
    columns = {name: np.zeros(0, np.float64) for name in SIMTRACE_COLUMNS}
    columns.update({name: np.zeros(0, np.int64) for name in (*_INT_COLUMNS, "action")})
    columns.update({name: np.zeros(0, bool) for name in _BOOL_COLUMNS})
    columns["episode_status"] = np.zeros(0, _STRING)
    return columns


def read_simtrace(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a simtrace CSV into arrays keyed by column name, each of n rows.

    Integers come back as int64, floats as float64, `done`/`all_wheels_on_track` as bool,
    `episode_status` as strings, `action` as int64 (n,) when every row holds an index or
    float64 (n, 2) `[steer speed]` pairs. A torn last line (no trailing newline) is dropped.
    """
    source = Path(path)
    data = source.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise ValueError(f"{str(source)!r} is not a simtrace CSV: line {line} (byte {exc.start}) is not UTF-8 "
                         f"text ({exc.reason}); simtrace files are text with the header "
                         f"{SIMTRACE_HEADER[:40]!r}...") from None
    header, _, body = text.partition("\n")
    if header.strip() != SIMTRACE_HEADER:
        raise ValueError(f"{str(source)!r} does not start with the simtrace header {SIMTRACE_HEADER!r}; "
                         f"found {header[:200]!r}")
    lines = body.split("\n")
    lines.pop()  # '' after the final newline, or a torn line written by a crashed writer
    if not lines:
        return _empty_columns()
    fields = ",".join(lines).split(",")
    width = len(SIMTRACE_COLUMNS)
    if len(fields) != width * len(lines):
        bad = next(i for i, line in enumerate(lines) if line.count(",") != width - 1)
        raise ValueError(f"{str(source)!r} line {bad + 2} has {lines[bad].count(',') + 1} fields, "
                         f"expected {width}: {lines[bad][:200]!r}")
    table = np.array(fields, dtype=_STRING).reshape(len(lines), width)
    columns: dict[str, np.ndarray] = {}
    for index, name in enumerate(SIMTRACE_COLUMNS):
        cells = table[:, index]
        try:
            if name in _INT_COLUMNS:
                columns[name] = cells.astype(np.int64)
            elif name in _BOOL_COLUMNS:
                columns[name] = cells == "True"
            elif name == "episode_status":
                columns[name] = cells
            elif name == "action":
                columns[name] = _parse_action(cells)
            else:
                columns[name] = cells.astype(np.float64)
        except ValueError as error:
            raise ValueError(f"{str(source)!r} column {name!r}: {error}") from None
    return columns


def _parse_action(cells: np.ndarray) -> np.ndarray:
    try:
        return cells.astype(np.int64)
    except ValueError:
        pass
    numbers = " ".join(cells.tolist()).replace("[", " ").replace("]", " ").split()
    if len(numbers) != 2 * len(cells):
        raise ValueError("expected every action to be an integer index or a '[steer speed]' pair")
    return np.array(numbers, dtype=np.float64).reshape(len(cells), 2)
