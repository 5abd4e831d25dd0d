"""``laplab race MODEL_A MODEL_B``: two trained models race on one track; their cars, times and a
picture are kept; an opponent on another physics version is refused before anything runs."""

from __future__ import annotations

import json

import pytest

from laplab.cli import main
from tests.evaluate.conftest import train_tiny_model


@pytest.fixture(autouse=True)
def home(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    return tmp_path / "home"


def test_two_models_race_and_the_picture_shows_both(home, capsys):
    train_tiny_model("alpha", max_episodes=8)
    train_tiny_model("bravo", max_episodes=8, race_type={"kind": "object_avoidance", "objects": 2})
    assert main(["race", "alpha", "bravo", "--laps", "1", "--max-time", "20"]) == 0
    out = capsys.readouterr().out
    assert "alpha" in out and "bravo" in out and "race on classic_2018" in out
    (folder,) = (home / "races").iterdir()
    document = json.loads((folder / "race.json").read_text())
    assert sorted(r["name"] for r in document["racers"]) == ["alpha", "bravo"]
    assert sorted(r["position"] for r in document["racers"]) == [1, 2]
    assert (folder / "topdown.png").stat().st_size > 1000


def test_an_opponent_on_another_car_is_refused(home, capsys):
    train_tiny_model("six", max_episodes=4)
    train_tiny_model("four", max_episodes=4, vehicle="deepracer-v4")
    assert main(["race", "six", "four"]) == 2
    err = capsys.readouterr().err
    assert "opponent 'four' drives deepracer-v4" in err
    assert not (home / "races").exists()
