import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from laplab.store.simtrace import SIMTRACE_HEADER, SimtraceWriter, format_rows, read_simtrace

REPO_ROOT = Path(__file__).resolve().parents[2]


def test_header_is_the_exact_deepracer_header(tmp_path):
    assert SIMTRACE_HEADER == (
        "episode,steps,X,Y,yaw,steer,throttle,action,reward,done,all_wheels_on_track,progress,"
        "closest_waypoint,track_len,tstamp,episode_status,pause_duration,obstacle_crash_counter,wall_clock"
    )
    with SimtraceWriter(tmp_path / "0-iteration.csv"):
        pass
    assert (tmp_path / "0-iteration.csv").read_text() == SIMTRACE_HEADER + "\n"


def test_row_text_matches_the_simapp_conventions(simtrace_columns):
    discrete = simtrace_columns(0, [2], continuous=False)
    discrete.update(action=np.array([3, 0]), reward=np.array([1e-3, 1e-8]), X=np.array([1.23456, -0.5]),
                    wall_clock=np.array([1700000000.25, 1700000000.5]))
    lines = format_rows(discrete).splitlines()
    fields = lines[0].split(",")
    assert len(fields) == 19
    assert fields[2] == "1.2346" and fields[7] == "3" and fields[8] == "0.001"
    assert fields[9] == "False" and fields[10] == "True" and fields[15] == "in_progress"
    assert lines[1].split(",")[8] == "1.0e-08" and lines[1].split(",")[18] == "1700000000.5"
    continuous = simtrace_columns(0, [1], continuous=True)
    continuous["action"] = np.array([[-12.5, 2.25]])
    assert format_rows(continuous).split(",")[7] == "[-12.5 2.25]"


@pytest.mark.parametrize("continuous", [False, True])
def test_round_trip_through_the_reader(tmp_path, simtrace_columns, continuous):
    first = simtrace_columns(0, [5, 3], continuous, seed=1)
    second = simtrace_columns(2, [4], continuous, seed=2)
    path = tmp_path / "training-simtrace" / "0-iteration.csv"
    with SimtraceWriter(path, fsync=False) as writer:
        assert writer.write_rows(first) == 8
        writer.write_rows(second)
        assert writer.rows_written == 12
    table = read_simtrace(path)
    expected = {name: np.concatenate([first[name], second[name]]) for name in first}
    for name in ("episode", "steps", "closest_waypoint", "done", "all_wheels_on_track"):
        np.testing.assert_array_equal(table[name], expected[name])
    for name in ("X", "Y", "yaw", "steer", "throttle", "progress", "track_len", "tstamp"):
        np.testing.assert_allclose(table[name], expected[name], atol=5e-5)
    np.testing.assert_allclose(table["reward"], expected["reward"], rtol=1e-6)
    assert table["episode_status"].tolist() == expected["episode_status"].tolist()
    if continuous:
        assert table["action"].shape == (12, 2)
        np.testing.assert_allclose(table["action"], expected["action"], atol=5e-5)
    else:
        np.testing.assert_array_equal(table["action"], expected["action"])
    np.testing.assert_array_equal(table["pause_duration"], 0.0)
    np.testing.assert_array_equal(table["obstacle_crash_counter"], 0)
    assert np.all(table["wall_clock"] > 1.6e9)


def test_rows_survive_a_crash_and_a_torn_line_is_repaired(tmp_path, simtrace_columns):
    path = tmp_path / "3-iteration.csv"
    child = f"""
import os, sys
sys.path.insert(0, {str(REPO_ROOT)!r}); sys.path.insert(0, {str(Path(__file__).parent)!r})
from conftest import make_simtrace_columns
from laplab.store.simtrace import SimtraceWriter
writer = SimtraceWriter({str(path)!r})
writer.write_rows(make_simtrace_columns(0, [4, 2], continuous=False))
writer.write_rows(make_simtrace_columns(2, [3], continuous=False))
os._exit(9)  # dies without closing anything
"""
    assert subprocess.run([sys.executable, "-c", child], timeout=60).returncode == 9
    assert len(read_simtrace(path)["episode"]) == 9
    with open(path, "a") as handle:  # a power cut tore the next batch mid-line
        handle.write("3,1,0.5,0.25,90.0,0.0,1.0,2,0.5,False,Tr")
    assert len(read_simtrace(path)["episode"]) == 9
    with SimtraceWriter(path) as writer:
        writer.write_rows(simtrace_columns(3, [1], continuous=False))
    table = read_simtrace(path)
    assert table["episode"].tolist() == [0] * 4 + [1] * 2 + [2] * 3 + [3]


def test_refuses_to_append_to_a_foreign_file(tmp_path):
    path = tmp_path / "0-iteration.csv"
    path.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(ValueError, match="0-iteration.csv.*header"):
        SimtraceWriter(path)
    with pytest.raises(ValueError, match="0-iteration.csv.*header"):
        read_simtrace(path)
    assert path.read_text() == "a,b,c\n1,2,3\n"


def test_bad_columns_are_named_in_the_error(simtrace_columns):
    columns = simtrace_columns(0, [3], continuous=False)
    with pytest.raises(ValueError, match=r"missing \['reward'\].*unknown \['speed'\]"):
        format_rows({**{k: v for k, v in columns.items() if k != "reward"}, "speed": columns["X"]})
    with pytest.raises(ValueError, match="equal length"):
        format_rows({**columns, "X": columns["X"][:2]})
    with pytest.raises(ValueError, match="'episode_status'.*'offtrack'"):
        format_rows({**columns, "episode_status": np.array(["in_progress", "offtrack", "in_progress"])})
    with pytest.raises(ValueError, match="'action'.*\\(3, 2\\)"):
        format_rows({**columns, "action": np.zeros((3, 3))})
    with pytest.raises(ValueError, match="'steps'.*integers"):
        format_rows({**columns, "steps": columns["steps"] + 0.5})
    with pytest.raises(ValueError, match="'episode_status'.*0..9"):
        format_rows({**columns, "episode_status": np.array([1, 1, 10])})
    columns["wall_clock"] = np.full(3, 1.7e9)
    as_indices = {**columns, "episode_status": np.array([1, 1, 4])}  # in_progress, in_progress, off_track
    assert format_rows(as_indices) == format_rows({**columns, "episode_status": ["in_progress"] * 2 + ["off_track"]})
    assert format_rows({name: values[:0] for name, values in columns.items()}) == ""


def test_reader_reports_a_malformed_line(tmp_path):
    path = tmp_path / "0-iteration.csv"
    path.write_text(SIMTRACE_HEADER + "\n" + "0,1,2\n")
    with pytest.raises(ValueError, match="line 2 has 3 fields, expected 19"):
        read_simtrace(path)
    path.write_text(SIMTRACE_HEADER + "\n")
    empty = read_simtrace(path)
    assert len(empty) == 19 and all(len(values) == 0 for values in empty.values())


def test_number_text_parity_with_python_formatting(simtrace_columns):
    rng = np.random.default_rng(3)
    magnitudes = 10.0 ** rng.uniform(-12, 13, 400) * rng.choice([-1.0, 1.0], 400)
    values = np.concatenate([magnitudes, [0.0, -0.0, 1e-8, 1e-3, 9.99999996e-6, 0.5, 30.0, 2.5e19, -7e25]])
    columns = simtrace_columns(0, [len(values)], continuous=True)
    columns.update(X=values, reward=values, action=np.column_stack([values, -values]))
    table = np.array([line.split(",") for line in format_rows(columns).splitlines()])
    for text, value in zip(table[:, 2], values):
        expected = float(f"{value:.4f}") if abs(value) < 1e14 else value
        assert np.isclose(float(text), expected, rtol=1e-14, atol=0), (text, value)
        assert not (text.endswith("0") and "." in text and not text.endswith(".0") and "e" not in text)
    for text, value in zip(table[:, 8], values):
        assert float(text) == float(f"{value:.7g}"), (text, value)
    pairs = [cell.strip("[]").split(" ") for cell in table[:, 7]]
    np.testing.assert_allclose([[float(a), float(b)] for a, b in pairs],
                               np.round(np.column_stack([values, -values]), 4), rtol=1e-14)
    special = simtrace_columns(0, [3], continuous=False)
    special["X"] = np.array([np.nan, np.inf, -np.inf])
    assert [line.split(",")[2] for line in format_rows(special).splitlines()] == ["nan", "inf", "-inf"]


def test_rows_read_back_can_be_written_again(tmp_path):
    """read_simtrace's columns (episode_status as numpy StringDType) feed SimtraceWriter unchanged."""
    from laplab.store.simtrace import SimtraceWriter, read_simtrace
    columns = {"episode": np.array([0, 0]), "steps": np.array([1, 2]), "X": np.zeros(2), "Y": np.zeros(2),
               "yaw": np.zeros(2), "steer": np.zeros(2), "throttle": np.zeros(2), "action": np.array([0, 1]),
               "reward": np.ones(2), "done": np.array([False, True]), "all_wheels_on_track": np.array([True, True]),
               "progress": np.array([1.0, 2.0]), "closest_waypoint": np.array([0, 1]), "track_len": np.ones(2),
               "tstamp": np.ones(2), "episode_status": np.array(["in_progress", "off_track"])}
    with SimtraceWriter(tmp_path / "a.csv") as writer:
        writer.write_rows(columns)
    rows = read_simtrace(tmp_path / "a.csv")
    with SimtraceWriter(tmp_path / "b.csv") as writer:
        writer.write_rows(rows)
    assert read_simtrace(tmp_path / "b.csv")["episode_status"].tolist() == ["in_progress", "off_track"]
