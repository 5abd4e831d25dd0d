"""Summary figures on hand-made trials, the leaderboard's ranking over hand-made evaluations, the
optimal lap time cache, and ``laplab leaderboard``."""

from __future__ import annotations

import json
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from laplab.cli import main
from laplab.evaluate import EvaluationError, TrialResult, best_consecutive_average, summarize
from laplab.evaluate.leaderboard import leaderboard
from laplab.evaluate.optimal import cache_dir, optimal_lap_time
from laplab.store.atomic import atomic_write_json
from laplab.store.layout import model_folder
from laplab.track.registry import load_track

OPTIMAL = 5.0
T0 = datetime(2024, 5, 1, 12, 0, 0, tzinfo=timezone.utc)


@pytest.fixture(autouse=True)
def home(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    return tmp_path / "home"


def trials(laps, completion_if_not=50.0, off_track=0):
    """TrialResults with the given lap times (None: the trial ended off track at 50 %)."""
    out = []
    for index, lap in enumerate(laps):
        done = lap is not None
        out.append(TrialResult(index=index, status="lap_complete" if done else "off_track",
                               lap_time=lap, duration=lap if done else 7.0, start_time=0.0,
                               completion=100.0 if done else completion_if_not, off_track_count=off_track))
    return out


@pytest.mark.parametrize("laps, expected", [
    ([10.0, None, 11.0, 12.0, 13.0], 12.0),
    ([10.0, 11.0, None, 12.0, 13.0], None),  # no 3 completed in a row
    ([12.0, 11.0, 10.0, 9.0], 10.0),  # the best window, not the first
    ([9.0, 9.0], None),
])
def test_best_average_of_three_consecutive_laps(laps, expected):
    result = best_consecutive_average(laps)
    assert result == (None if expected is None else pytest.approx(expected))


def test_summary_figures():
    summary = summarize(trials([10.0, None, 11.0, 12.0], off_track=1), optimal_lap_time=OPTIMAL)
    assert (summary.trials, summary.completed, summary.best_lap) == (4, 3, 10.0)
    assert summary.average_lap == pytest.approx(11.0) and summary.average_3 is None
    assert summary.completion_rate == 0.75 and summary.average_completion == pytest.approx(87.5)
    assert summary.off_track_count == 4
    assert summary.gap_to_optimal == pytest.approx(2.0)
    assert summarize(trials([None, None])).best_lap is None
    with pytest.raises(ValueError):
        summarize([])


def add_evaluation(model, laps, track="classic_2018", minutes=0, race_type=None, **kwargs):
    folder = model_folder(model)
    if not folder.laplab_config.exists():
        folder.create().write_laplab_config({"track": track})
    stamp = folder.new_evaluation(when=T0 + timedelta(minutes=minutes))
    ts = trials(laps, **kwargs)
    document = {"model": model, "checkpoint": "1_Step-10.ckpt", "track": {"name": track},
                "trials": [t.to_dict() for t in ts], "summary": summarize(ts, OPTIMAL).to_dict()}
    if race_type is not None:
        document["race_type"] = race_type
    atomic_write_json(folder.evaluation_dir(stamp) / "summary.json", document)
    return stamp


@pytest.fixture
def evaluations():
    stamps = {
        "alpha-1": add_evaluation("alpha", [10.0, 11.0, 12.0]),
        "alpha-2": add_evaluation("alpha", [9.0, None, 9.5], minutes=1),  # faster lap, no 3 in a row
        "bravo": add_evaluation("bravo", [10.5, 10.5, 10.5]),
        "charlie": add_evaluation("charlie", [8.0, None, None], completion_if_not=60.0),
        "foxtrot": add_evaluation("foxtrot", [8.0, None, None], completion_if_not=40.0),
        "delta": add_evaluation("delta", [None, None, None]),
        "echo": add_evaluation("echo", [8.5, None, 9.0], track="oval"),
    }
    other_tool = model_folder("golf").create()  # an evaluation with DeepRacer's files only
    other_tool.write_laplab_config({})
    other_tool.new_evaluation(when=T0)
    return stamps


def test_models_ranked_by_average_of_three_then_best_lap_then_completion(evaluations):
    boards = leaderboard()
    assert list(boards) == ["classic_2018", "oval"]
    classic = boards["classic_2018"]
    assert [e.model for e in classic] == ["bravo", "alpha", "charlie", "foxtrot", "delta"]
    assert [e.rank for e in classic] == [1, 2, 3, 4, 5]
    alpha = classic[1]
    assert alpha.stamp == evaluations["alpha-1"]  # its evaluation with an average of three counts
    assert (alpha.average_3, alpha.best_lap, alpha.completion) == (pytest.approx(11.0), 10.0, 100.0)
    assert alpha.gap_to_optimal == pytest.approx(10.0 / OPTIMAL)
    assert classic[-1].best_lap is None and classic[-1].gap_to_optimal is None
    assert [e.model for e in boards["oval"]] == ["echo"]
    assert list(leaderboard("oval")) == ["oval"] and leaderboard("nowhere") == {}


def test_leaderboard_cli_json_and_table(evaluations, capsys):
    assert main(["leaderboard", "--track", "classic_2018", "--json"]) == 0
    (board,) = json.loads(capsys.readouterr().out)
    assert board["track"] == "classic_2018"
    assert [row["model"] for row in board["entries"]] == ["bravo", "alpha", "charlie", "foxtrot", "delta"]
    assert board["entries"][0]["average_3"] == 10.5
    assert main(["leaderboard"]) == 0
    out = capsys.readouterr().out
    assert "leaderboard: classic_2018" in out and "leaderboard: oval" in out and "x2.100" in out


def test_race_types_are_ranked_apart(evaluations):
    add_evaluation("hotel", [7.0, 7.0, 7.0], race_type={"kind": "object_avoidance", "objects": 3})
    boards = leaderboard("classic_2018")
    board = "classic_2018 [object avoidance: 3 boxes, evenly spaced]"
    assert list(boards) == ["classic_2018", board]
    assert [e.model for e in boards[board]] == ["hotel"] and boards[board][0].race.startswith("object avoidance")
    assert "hotel" not in [e.model for e in boards["classic_2018"]]


def test_leaderboard_without_evaluations(capsys):
    assert main(["leaderboard"]) == 0
    assert "no evaluations" in capsys.readouterr().out


def test_unreadable_summary_names_the_file(evaluations):
    folder = model_folder("bravo")
    path = folder.evaluation_dir(evaluations["bravo"]) / "summary.json"
    document = json.loads(path.read_text())
    del document["summary"]["best_lap"]
    path.write_text(json.dumps(document))
    with pytest.raises(EvaluationError, match="summary"):
        leaderboard()
    assert main(["leaderboard"]) == 2


def test_optimal_lap_time_is_cached_per_track_direction(monkeypatch):
    from laplab.track import raceline_cache
    track = load_track("classic_2018")
    first = optimal_lap_time(track)
    assert len(list(cache_dir().glob("*"))) == 1
    assert 2.0 < first < 15.0
    raceline_cache.clear_memory_cache()

    def no_solving(*args, **kwargs):
        raise AssertionError("the race line was solved again")
    monkeypatch.setattr(raceline_cache, "compute_raceline_for_track", no_solving)
    assert optimal_lap_time(track) == first  # from the cache file
    with pytest.raises(AssertionError, match="solved again"):
        optimal_lap_time(track.reversed())  # the other direction is another race line


def test_leaderboard_fills_a_missing_gap_from_the_cache(evaluations):
    folder = model_folder("bravo")
    path = folder.evaluation_dir(evaluations["bravo"]) / "summary.json"
    document = json.loads(path.read_text())
    document["summary"]["optimal_lap_time"] = document["summary"]["gap_to_optimal"] = None
    path.write_text(json.dumps(document))
    bravo = leaderboard("classic_2018")["classic_2018"][0]
    optimal = optimal_lap_time(load_track("classic_2018"))
    assert bravo.gap_to_optimal == pytest.approx(10.5 / optimal)
    assert np.isfinite(bravo.gap_to_optimal)


def test_summary_names_the_flying_and_the_standing_start_optimum():
    from laplab.evaluate.optimal import standing_start_optimal_lap_time
    from laplab.evaluate.summary import summary_lines
    track = load_track("classic_2018")
    flying, standing = optimal_lap_time(track), standing_start_optimal_lap_time(track)
    # from rest the car spends its first metres accelerating: slower than the flying lap, by well under a second
    assert flying < standing < flying + 1.0
    text = "\n".join(summary_lines(summarize(trials([6.0]), flying, standing)))
    assert f"{flying:.3f} s (race line, flying; {standing:.3f} s from a standing start)" in text
    assert "unknown" in "\n".join(summary_lines(summarize(trials([6.0]))))
