"""RaceRequest: the head-to-model race's options, shared by `laplab race` and the console's race job."""

from __future__ import annotations

import pytest

from laplab.cli import main
from laplab.train.request import RaceRequest, RequestError


def test_a_race_request_round_trips_through_a_jobs_params():
    request = RaceRequest(models=("a", "b"), track="oval@reversed", laps=2, max_time_s=30)
    assert request.to_mapping() == {"models": ["a", "b"], "track": "oval@reversed", "laps": 2, "max_time_s": 30.0,
                                    "checkpoint": "best", "video": False}
    assert RaceRequest.from_mapping(request.to_mapping()) == request


@pytest.mark.parametrize("values, field", [
    ({"models": ["a"]}, "models"), ({"models": ["a", "a"]}, "models"), ({"models": "ab"}, "models"),
    ({"models": ["a", "b"], "laps": 0}, "laps"), ({"models": ["a", "b"], "laps": 2.5}, "laps"),
    ({"models": ["a", "b"], "max_time_s": 0.5}, "max_time_s"), ({"models": ["a", "b"], "max_time_s": True}, "max_time_s"),
    ({"models": ["a", "b"], "checkpoint": "../x"}, "checkpoint"), ({"models": ["a", "b"], "video": "yes"}, "video"),
    ({"models": ["a", "b"], "opponent": "c"}, "opponent"),
])
def test_bad_race_options_name_their_field(values, field):
    with pytest.raises(RequestError) as error:
        RaceRequest.from_mapping(values)
    assert error.value.field == field


def test_the_cli_names_its_option(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    assert main(["race", "a", "b", "--laps", "0"]) == 2
    assert "--laps must be an integer within 1..20, got 0" in capsys.readouterr().err
    assert not (tmp_path / "races").exists()
