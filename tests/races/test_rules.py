"""The pure rules of races: settings checks, windows, sensors, scoring by each ranking method, ranking."""

from __future__ import annotations

import pytest

from laplab.races.rules import RaceError, RaceSettings, rank, score, sensor_refusal, window_refusal


def lap(t):
    return {"status": "lap_complete", "lap_time": t} if t is not None else {"status": "off_track", "lap_time": None}


def test_settings_defaults_and_evaluation_params():
    race = RaceSettings(name="Class race", track="oval", direction="clockwise", laps=3, max_resets=2)
    params = race.evaluation_params("oval@reversed")
    assert params["track"] == "oval@reversed" and params["trials"] == 3 and params["continuous"] is True
    assert params["resets"] == 2 and params["video"] is True and params["physics"] == race.physics
    assert RaceSettings.from_dict(race.to_dict()) == race


@pytest.mark.parametrize("field,value", [("laps", 0), ("laps", 6), ("ranking", "fastest"), ("direction", "up"),
                                         ("race_type", "drag_race"), ("off_track_penalty", -1), ("max_resets", -2),
                                         ("max_submissions", 0), ("consecutive_laps", 4), ("name", ""),
                                         ("sensors", ["RADAR"]), ("physics", "warp-drive"), ("closes", 5.0)])
def test_bad_settings_name_their_field(field, value):
    with pytest.raises(RaceError) as caught:
        RaceSettings.from_dict({"name": "r", "track": "oval", "opens": 10.0, field: value})
    assert caught.value.field == field and str(caught.value).startswith(field)


def test_object_avoidance_and_head_to_bot_races_drive_their_options():
    boxes = RaceSettings(name="Boxes", track="oval", race_type="object_avoidance", collision_penalty=3.0,
                         options={"objects": 2, "randomize_objects": True})
    driven = boxes.evaluation_params("oval")["race_type"]
    assert (driven["kind"], driven["objects"], driven["randomize_objects"], driven["collision_penalty"]) == \
        ("object_avoidance", 2, True, 3.0)
    bots = RaceSettings(name="Bots", track="oval", race_type="head_to_bot", options={"bots": 2, "bot_speed": 1.0})
    assert bots.race().summary().startswith("head-to-bot") or "bot" in bots.race().summary()
    assert "race_type" not in RaceSettings(name="Trial", track="oval").evaluation_params("oval")
    for race_type, options, says in (("head_to_bot", {"bot_speed": 9.0}, "bot-speed must be within 0.1..4"),
                                     ("object_avoidance", {"bots": 2}, "'bots' is not one"),
                                     ("time_trial", {"objects": 3}, "none for a time trial"),
                                     ("object_avoidance", {"objects": 13}, "objects must be an integer within 1..")):
        with pytest.raises(RaceError, match=says) as caught:
            RaceSettings(name="r", track="oval", race_type=race_type, options=options)
        assert caught.value.field == "options"


def test_unknown_setting_is_refused():
    with pytest.raises(RaceError, match="colour: not a race setting"):
        RaceSettings.from_dict({"name": "r", "track": "oval", "colour": "red"})


def test_window():
    race = RaceSettings(name="r", track="oval", opens=100.0, closes=200.0)
    assert "not opened" in window_refusal(race, False, 50.0)
    assert window_refusal(race, False, 150.0) is None
    assert "closed" in window_refusal(race, False, 200.0)
    assert "closed" in window_refusal(race, True, 150.0)


def test_sensors():
    race = RaceSettings(name="r", track="oval", sensors=("FRONT_FACING_CAMERA",))
    assert sensor_refusal(race, ["FRONT_FACING_CAMERA"]) is None
    assert "SECTOR_LIDAR" in sensor_refusal(race, ["FRONT_FACING_CAMERA", "SECTOR_LIDAR"])
    assert sensor_refusal(RaceSettings(name="r", track="oval"), ["LIDAR"]) is None


def test_scores_by_ranking_method():
    trials = [lap(10.0), lap(None), lap(9.0), lap(8.0), lap(12.0)]
    avg2 = RaceSettings(name="r", track="oval", laps=5, consecutive_laps=2)
    assert score(avg2, trials).value == pytest.approx(8.5)
    avg3 = RaceSettings(name="r", track="oval", laps=5, consecutive_laps=3)
    assert score(avg3, trials).value == pytest.approx((9 + 8 + 12) / 3)
    avg4 = RaceSettings(name="r", track="oval", laps=5, consecutive_laps=4)
    assert score(avg4, trials).value is None and "4 consecutive" in score(avg4, trials).reason
    best = RaceSettings(name="r", track="oval", laps=5, ranking="best_lap")
    assert score(best, trials).value == 8.0
    total = RaceSettings(name="r", track="oval", laps=5, ranking="total_time")
    assert score(total, trials).value is None and "4 of the race's 5" in score(total, trials).reason
    assert score(total, [lap(10.0)] * 5).value == pytest.approx(50.0)
    assert score(best, [lap(None)]).reason == "no lap completed"


def test_rank_best_per_racer_ties_by_submission_time():
    entries = [{"user": "a", "score": 10.0, "created": 1.0}, {"user": "a", "score": 9.0, "created": 5.0},
               {"user": "b", "score": 9.0, "created": 3.0}, {"user": "c", "score": None, "created": 0.5},
               {"user": "d", "score": 11.0, "created": 0.1}]
    board = rank(entries)
    assert [(e["user"], e["rank"], e["score"]) for e in board] == [("b", 1, 9.0), ("a", 2, 9.0), ("d", 3, 11.0)]
