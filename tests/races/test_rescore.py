"""A race's submissions under edited rules, from the laps they drove (laplab.races.rescore)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from laplab.races.rescore import OVER_RESET_LIMIT, course_change, rescore
from laplab.races.rules import RaceSettings, score


def lap(time=None, off=0, crash=0, status=None, penalty=None):
    """One recorded lap: its time with penalties (None: not completed), incidents and penalty served."""
    done = time is not None
    return {"status": status or ("lap_complete" if done else "off_track"), "lap_time": time,
            "duration": time or 7.0, "off_track_count": off, "crash_count": crash, "reset_count": off + crash,
            "penalty_time": penalty if penalty is not None else 2.0 * off + 5.0 * crash}


RACE = RaceSettings(name="r", track="oval", laps=3, ranking="best_lap", off_track_penalty=2.0, collision_penalty=5.0)


def driven_params(settings: RaceSettings, track: str = "oval") -> dict:
    return settings.evaluation_params(track)


def test_unchanged_rules_score_as_before():
    trials = [lap(10.0, off=1), lap(9.5), lap(None)]
    result = rescore(RACE, driven_params(RACE), driven_params(RACE), trials)
    assert result.score == score(RACE, trials) and result.notes == () and result.trials == trials


def test_a_new_ranking_method_scores_the_recorded_laps_again():
    trials = [lap(10.0), lap(9.5), lap(None)]
    total = replace(RACE, ranking="total_time")
    result = rescore(total, driven_params(total), driven_params(RACE), trials)
    assert result.score.value is None and "2 of the race's 3 laps" in result.score.reason
    average = replace(RACE, ranking="average_consecutive", consecutive_laps=2)
    assert rescore(average, driven_params(average), driven_params(RACE), trials).score.value == pytest.approx(9.75)


def test_new_penalties_re_time_each_completed_lap():
    trials = [lap(12.0, off=2, crash=0), lap(15.0, off=0, crash=1), lap(None, off=1)]
    softer = replace(RACE, off_track_penalty=0.5, collision_penalty=1.0)
    result = rescore(softer, driven_params(softer), driven_params(RACE), trials)
    assert [t["lap_time"] for t in result.trials] == [pytest.approx(9.0), pytest.approx(11.0), None]
    assert result.trials[0]["penalty_time"] == pytest.approx(1.0) and result.score.value == pytest.approx(9.0)
    assert result.notes == ("lap times re-timed with the race's penalties now (off-track 2 s → 0.5 s, "
                            "collision 5 s → 1 s)",)
    # a penalty that takes a lap past the evaluation's time cap ends it as time up
    harsh = replace(RACE, off_track_penalty=60.0)
    capped = rescore(harsh, driven_params(harsh), {**driven_params(RACE), "max_trial_time": 100.0},
                     [lap(12.0, off=2)])
    assert capped.trials[0]["status"] == "time_up" and capped.score.value is None


def test_fewer_laps_rank_on_the_first_ones_and_more_laps_say_what_is_missing():
    trials = [lap(10.0), lap(9.0), lap(8.0)]
    two = replace(RACE, laps=2)
    result = rescore(two, driven_params(two), driven_params(RACE), trials)
    assert result.score.value == 9.0 and len(result.trials) == 2 and "first 2 laps of the 3 laps" in result.notes[0]
    five_total = replace(RACE, laps=5, ranking="total_time")
    more = rescore(five_total, driven_params(five_total), driven_params(RACE), trials)
    assert more.score.value is None and more.score.reason.startswith("it drove 3 laps before the race asked 5")
    assert "submit the model again" in more.score.reason
    five_best = replace(RACE, laps=5)
    best = rescore(five_best, driven_params(five_best), driven_params(RACE), trials)
    assert best.score.value == 8.0 and best.notes == ("it drove 3 laps; the race now has 5 laps",)


def test_reset_limits():
    trials = [lap(14.0, off=2), lap(9.0), lap(None, status="off_track")]
    strict = replace(RACE, max_resets=1)
    result = rescore(strict, driven_params(strict), driven_params(RACE), trials)
    assert result.trials[0]["status"] == OVER_RESET_LIMIT and result.trials[0]["lap_time"] is None
    assert result.score.value == 9.0 and "lap 1 needed 2 resets; the race now allows 1" in result.notes[0]
    loose = replace(RACE, max_resets=3)
    eased = rescore(loose, driven_params(loose), driven_params(strict), trials)
    assert eased.score.value == 9.0 and "lap 3 ended at the old limit of 1 resets per lap" in eased.notes[0]


def test_another_course_no_longer_ranks_and_says_why():
    trials = [lap(9.0)] * 3
    for changed, says in ((replace(RACE, track="classic_2018"), "driven on oval; the race is now on classic_2018"),
                          (replace(RACE, physics="4"), "driven with the car"),
                          (replace(RACE, race_type="object_avoidance", options={"objects": 2}), "driven as a time trial")):
        result = rescore(changed, driven_params(changed, changed.track), driven_params(RACE), trials)
        assert result.score.value is None and says in result.score.reason, result.score.reason
        assert result.score.reason.endswith("submit the model again to rank")
    reversed_ = course_change({"track": "oval@reversed"}, {"track": "oval"})
    assert "the race is now on oval (reversed)" in reversed_
    # a new collision penalty alone is a scoring rule, not another course
    boxes = RaceSettings(name="b", track="oval", race_type="object_avoidance", options={"objects": 2})
    assert course_change(driven_params(replace(boxes, collision_penalty=1.0)), driven_params(boxes)) is None


def test_head_to_bot_penalty_changes_are_marked_approximate():
    bots = RaceSettings(name="b", track="oval", race_type="head_to_bot", options={"bots": 1}, ranking="best_lap",
                        laps=1)
    softer = replace(bots, collision_penalty=1.0)
    result = rescore(softer, driven_params(softer), driven_params(bots), [lap(15.0, crash=1)])
    assert result.score.value == pytest.approx(11.0) and "bots would have moved on" in result.notes[0]


def test_a_sensor_the_race_no_longer_allows_unranks_and_says_why():
    cameras_only = replace(RACE, sensors=("FRONT_FACING_CAMERA",))
    trials = [lap(9.0)] * 3
    lidar = rescore(cameras_only, driven_params(cameras_only), driven_params(RACE), trials,
                    ["FRONT_FACING_CAMERA", "SECTOR_LIDAR"])
    assert lidar.score.value is None and lidar.score.reason == (
        "the race now allows the sensors FRONT_FACING_CAMERA; this model uses SECTOR_LIDAR: submit a model with "
        "those sensors to rank")
    assert rescore(cameras_only, driven_params(cameras_only), driven_params(RACE), trials,
                   ["FRONT_FACING_CAMERA"]).score.value == 9.0
