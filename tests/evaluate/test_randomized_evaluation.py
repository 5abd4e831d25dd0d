"""Evaluation under the camera's domain randomisation (``--domain-randomization``, issue 30): the
option reaches the renderer, repeats with its seed, is recorded, is refused for a model without a
camera and for a value that is not a boolean, and travels unchanged through every door's request."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from laplab.env.metadata import ModelMetadata
from laplab.env.spec import model_spec
from laplab.evaluate import EvaluationError, EvaluationSettings, evaluate_policy
from laplab.evaluate.leaderboard import standard_rules
from laplab.evaluate.trials import EvaluateRequest
from laplab.track.registry import load_track

CAMERA = model_spec(replace(ModelMetadata(), sensors=("FRONT_FACING_CAMERA",)))
SHORT = dict(trials=1, max_trial_time=0.5)  # s: 8 decisions, enough to see the frames


class FrameRecorder:
    """A policy that drives straight at the slowest action and keeps every observation it was given."""

    def __init__(self) -> None:
        self.frames: list[np.ndarray] = []

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        self.frames.append(np.array(observations))
        return np.zeros(len(observations), dtype=np.int64)


@pytest.fixture(scope="module")
def track():
    return load_track("oval")


def _frames(track, **settings) -> tuple[np.ndarray, object]:
    """The first camera frame of an evaluation's first trial, (C, 120, 160) uint8, and the result."""
    recorder = FrameRecorder()
    result = evaluate_policy(recorder, track, EvaluationSettings(**SHORT, **settings), spec=CAMERA)
    return recorder.frames[0][0], result


def test_the_option_reaches_the_renderer_and_repeats_with_its_seed(track):
    plain, plain_result = _frames(track)
    randomized, result = _frames(track, domain_randomization=True, seed=3)
    again, _ = _frames(track, domain_randomization=True, seed=3)
    other, _ = _frames(track, domain_randomization=True, seed=4)
    # The same pose (the start line, at rest), another look: training's variations are in the frame.
    assert np.abs(randomized.astype(int) - plain.astype(int)).mean() > 2
    np.testing.assert_array_equal(randomized, again)
    assert (other != randomized).any()
    assert result.to_dict()["settings"]["domain_randomization"] is True
    assert plain_result.to_dict()["settings"]["domain_randomization"] is False


def test_a_randomized_evaluation_does_not_rank():
    document = {"settings": EvaluationSettings(domain_randomization=True).to_dict()}
    assert not standard_rules(document)
    assert standard_rules({"settings": EvaluationSettings().to_dict()})


def test_a_model_without_a_camera_is_refused_naming_the_option(track):
    with pytest.raises(EvaluationError) as refused:
        evaluate_policy(FrameRecorder(), track, EvaluationSettings(**SHORT, domain_randomization=True),
                        spec=model_spec(ModelMetadata()))  # laplab's default: STATE
    assert refused.value.field == "domain_randomization"
    assert "no camera (sensors: STATE)" in str(refused.value) and "\n" not in str(refused.value)


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_a_value_that_is_not_a_boolean_is_refused(value):
    with pytest.raises(EvaluationError) as refused:
        EvaluationSettings(domain_randomization=value)
    assert refused.value.field == "domain_randomization"
    assert str(refused.value) == f"domain randomization must be true or false, got {value!r}"


def test_the_request_round_trips_through_every_door(monkeypatch):
    request = EvaluateRequest(trials=2, seed=5, domain_randomization=True)
    assert EvaluateRequest.from_mapping(request.to_dict()) == request  # a job's params, a summary's settings
    from laplab.console.bodies import EVALUATION_FIELDS, Evaluate
    body = Evaluate(trials=2, seed=5, domain_randomization=True)  # the console's API body
    assert EvaluateRequest.from_mapping(body.model_dump(), EVALUATION_FIELDS) == request
    assert Evaluate().domain_randomization is False

    import laplab.api as api
    from laplab.cli import build_parser
    sent = []
    monkeypatch.setattr(api, "_run", lambda args, what: (sent.append(args) or "{}", None))
    api.evaluate("some-model", trials=2, domain_randomization=True)  # the Python API runs `laplab evaluate`
    args = build_parser().parse_args(sent[0])
    assert args.domain_randomization is True and args.trials == 2
    api.evaluate("some-model")
    assert build_parser().parse_args(sent[1]).domain_randomization is False
