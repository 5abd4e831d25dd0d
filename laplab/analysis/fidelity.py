"""How closely a car drives as DeepRacer's simulator did: replay logged simtraces, measure the gap.

Any DeepRacer simtrace works (training or evaluation; the console's, deepracer-for-cloud's or DeepRacer on
AWS's layout; discrete or continuous actions): a CSV with the columns ``episode, steps, X, Y, yaw, steer,
throttle, tstamp``. From the logged pose at each row, the car drives the next ``horizon`` logged actions
with the logged simulation times; its reference point is compared with the logged one ``horizon`` rows
later. Its speed and steering state come from the logged rows before it (the distance and the turn of
the step before; the ``lead`` actions before the row). Rows are cut into episodes at an episode change,
a gap in ``steps`` or a jump of the car (a reset), so no window spans two runs of the car.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from laplab.vehicle.params import VehicleParams
from laplab.vehicle.replay import replay_windows

REQUIRED_COLUMNS = ("episode", "steps", "X", "Y", "yaw", "steer", "throttle", "tstamp")
MIN_DISTANCE = 0.01  # m in a step: below it the logged curvature says nothing
MAX_JUMP = 0.5  # m between two rows: more is a reset (4 m/s covers 0.27 m in a 15 Hz step)


class SimtraceReadError(ValueError):
    """A simtrace file that cannot be read (names the file and what is wrong)."""


@dataclass(frozen=True)
class Windows:
    """W replay windows: ``start`` (W, 3) logged reference pose (x, y m; yaw rad) at the window's row,
    ``speed0`` (W,) m/s, ``commands`` (W, lead + H, 2) (steer rad, speed m/s), ``times`` (W, lead + H + 1)
    s, ``curvature0`` (W,) 1/m over the step before the row, ``logged`` (W, H, 3) the logged poses of the
    H rows after it, ``source`` (W,) index into ``files``."""

    start: np.ndarray
    speed0: np.ndarray
    curvature0: np.ndarray
    commands: np.ndarray
    times: np.ndarray
    logged: np.ndarray
    source: np.ndarray
    lead: int
    files: tuple[str, ...]

    @property
    def size(self) -> int:
        return int(self.start.shape[0])

    def subset(self, rows: np.ndarray) -> "Windows":
        return Windows(self.start[rows], self.speed0[rows], self.curvature0[rows], self.commands[rows],
                       self.times[rows],
                       self.logged[rows], self.source[rows], self.lead, self.files)


@dataclass(frozen=True)
class FidelityScore:
    """Errors after the whole horizon, over W windows: position (m) and heading (rad), (W,) each."""

    position_error: np.ndarray
    heading_error: np.ndarray

    @property
    def windows(self) -> int:
        return int(self.position_error.size)

    def summary(self) -> str:
        """``fidelity: N windows, position error after 1 s median X cm p90 Y cm, heading error median Z deg``."""
        if self.windows == 0:
            return ("fidelity: 0 windows, position error after 1 s median nan cm p90 nan cm, "
                    "heading error median nan deg")
        return (f"fidelity: {self.windows} windows, position error after 1 s median "
                f"{100 * np.median(self.position_error):.1f} cm p90 {100 * np.quantile(self.position_error, 0.9):.1f} "
                f"cm, heading error median {math.degrees(float(np.median(self.heading_error))):.1f} deg")


def find_simtraces(root: str | Path) -> list[Path]:
    """Every CSV below ``root`` (or ``root`` itself) whose header has the simtrace columns, sorted."""
    root = Path(root)
    if not root.exists():
        raise SimtraceReadError(f"{root}: no such file or folder")
    candidates = [root] if root.is_file() else sorted(root.rglob("*.csv"))
    found = []
    for path in candidates:
        try:
            with path.open(newline="", encoding="utf-8") as handle:
                header = next(csv.reader(handle), [])
        except (OSError, UnicodeDecodeError):
            continue
        if all(name in header for name in REQUIRED_COLUMNS):
            found.append(path)
    return found


def read_trace(path: str | Path) -> dict[str, np.ndarray]:
    """The columns replay needs, as float64 arrays (yaw and steer converted to radians)."""
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.reader(handle)
            header = next(reader)
            index = [header.index(name) for name in REQUIRED_COLUMNS]
            rows = []
            for line_number, row in enumerate(reader, start=2):
                if not row:
                    continue
                try:
                    rows.append([float(row[i]) for i in index])
                except (ValueError, IndexError):
                    raise SimtraceReadError(f"{path} line {line_number}: cannot read the columns "
                                            f"{', '.join(REQUIRED_COLUMNS)} as numbers: "
                                            f"{','.join(row)[:120]!r}") from None
    except (OSError, UnicodeDecodeError, StopIteration, ValueError) as error:
        if isinstance(error, SimtraceReadError):
            raise
        raise SimtraceReadError(f"{path}: not a readable simtrace CSV ({error})") from None
    table = np.array(rows, dtype=np.float64).reshape(-1, len(REQUIRED_COLUMNS))
    columns = dict(zip(REQUIRED_COLUMNS, table.T))
    columns["yaw"] = np.radians(columns["yaw"])
    columns["steer"] = np.radians(columns["steer"])
    return columns


def _segments(trace: dict[str, np.ndarray]) -> list[np.ndarray]:
    """Row indices of each uninterrupted run of the car in a trace."""
    n = trace["X"].size
    if n == 0:
        return []
    jump = np.hypot(np.diff(trace["X"]), np.diff(trace["Y"])) > MAX_JUMP
    cut = (np.diff(trace["episode"]) != 0) | (np.diff(trace["steps"]) != 1) | jump | (np.diff(trace["tstamp"]) <= 0)
    bounds = np.concatenate([[0], np.flatnonzero(cut) + 1, [n]])
    return [np.arange(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def build_windows(paths: list[Path], horizon: int = 15, lead: int = 24, stride: int = 1) -> Windows:
    """Every window of ``horizon`` steps (every ``stride``-th row) of the simtraces in ``paths``."""
    starts, speeds, curvatures, commands, times, logged, sources = ([] for _ in range(7))
    for source, path in enumerate(paths):
        trace = read_trace(path)
        for rows in _segments(trace):
            if rows.size < horizon + 2:
                continue
            x, y, yaw, t = (trace[k][rows] for k in ("X", "Y", "yaw", "tstamp"))
            cmd = np.column_stack([trace["steer"][rows], trace["throttle"][rows]])
            # before the run: the car at rest, no command, 15 Hz
            padded_cmd = np.concatenate([np.zeros((lead, 2)), cmd])
            padded_t = np.concatenate([t[0] - np.arange(lead, 0, -1) / 15.0, t])
            for k in range(1, rows.size - horizon, stride):
                dt = t[k] - t[k - 1]
                distance = math.hypot(x[k] - x[k - 1], y[k] - y[k - 1])
                turn = (yaw[k] - yaw[k - 1] + math.pi) % (2 * math.pi) - math.pi
                starts.append((x[k], y[k], yaw[k]))
                speeds.append(distance / dt)
                curvatures.append(turn / distance if distance > MIN_DISTANCE else math.nan)
                commands.append(padded_cmd[k: k + lead + horizon])
                times.append(padded_t[k: k + lead + horizon + 1])
                logged.append(np.column_stack([x[k + 1: k + 1 + horizon], y[k + 1: k + 1 + horizon],
                                               yaw[k + 1: k + 1 + horizon]]))
                sources.append(source)
    if not starts:
        return Windows(np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros((0, lead + horizon, 2)),
                       np.zeros((0, lead + horizon + 1)), np.zeros((0, horizon, 3)), np.zeros(0, np.int64), lead,
                       tuple(str(p) for p in paths))
    return Windows(np.array(starts), np.array(speeds), np.array(curvatures), np.array(commands), np.array(times),
                   np.array(logged),
                   np.array(sources, dtype=np.int64), lead, tuple(str(p) for p in paths))


def score(vehicle: VehicleParams, windows: Windows) -> FidelityScore:
    """Replay every window with ``vehicle`` and measure the errors after the last step."""
    if windows.size == 0:
        return FidelityScore(np.zeros(0), np.zeros(0))
    poses = replay_windows(windows.start, windows.speed0, windows.commands, windows.times, windows.lead, vehicle,
                           windows.curvature0)
    final, logged = poses[:, -1], windows.logged[:, -1]
    position = np.hypot(final[:, 0] - logged[:, 0], final[:, 1] - logged[:, 1])
    heading = np.abs(np.mod(final[:, 2] - logged[:, 2] + np.pi, 2 * np.pi) - np.pi)
    return FidelityScore(position, heading)
