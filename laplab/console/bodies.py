"""The JSON bodies the console's API accepts, derived from the job requests' dataclasses
(:class:`laplab.train.request.TrainRequest`, :class:`laplab.evaluate.trials.EvaluationSettings`), so
that the console, the CLI, the job worker and ``laplab.api`` share one set of fields, types and defaults;
the requests' own checks give the error messages and their fields."""

from __future__ import annotations

from dataclasses import fields
from typing import get_type_hints

from pydantic import BaseModel, ConfigDict, Field
from pydantic import create_model as pydantic_model

from laplab.evaluate.trials import EvaluationSettings
from laplab.train.request import TrainRequest


class _ModelBody(BaseModel):
    """What every new model names besides its training: its name, description and reward function."""
    model_config = ConfigDict(extra="forbid")
    name: str
    description: str = Field("", max_length=255)
    reward_function: str | None = Field(None, max_length=100_000)


# The training fields of the console's bodies: TrainRequest's (laplab.train.request), with its types and
# defaults, so that the console, the CLI, the worker and laplab.api cannot drift; the request's own
# checks give the error messages and their fields.
CLONE_FIELDS = ("track", "model_metadata", "hyperparameters", "max_time_s", "max_episodes", "workers")
CREATE_FIELDS = (*CLONE_FIELDS, "seed", "physics", "race_type", "domain_randomization")
_FIELD_HELP = {"workers": "rollout workers on the console's Ray cluster",
               "physics": "DeepRacer's car: 4, 5, 6 or classic (None: the one model_metadata's version chooses)",
               "race_type": "laplab.sim.race_type.RaceType's fields (None: time trial)",
               "max_time_s": "stop after this many seconds of training",
               "domain_randomization": "train under the camera's domain randomisation (a camera model only)"}


def _train_body(name: str, names: tuple[str, ...], doc: str) -> type[BaseModel]:
    hints = get_type_hints(TrainRequest)
    defaults = {f.name: f.default for f in fields(TrainRequest)}
    return pydantic_model(name, __base__=_ModelBody, __doc__=doc,
                          **{n: (hints[n], Field(defaults[n], description=_FIELD_HELP.get(n))) for n in names})


CloneModel = _train_body("CloneModel", CLONE_FIELDS, "A clone of a model: its name and what changes (the action "
                                                     "space and sensors cannot).")
CreateModel = _train_body("CreateModel", CREATE_FIELDS, "A new model: what a clone gives, the training seed, "
                                                        "DeepRacer's car, the race type and the domain randomisation.")


class Resume(BaseModel):
    model_config = ConfigDict(extra="forbid")
    max_time_s: float | None = None
    workers: int | None = Field(None, ge=1, le=1024, description="rollout workers on the console's Ray cluster")


# What the console lets a user set of an evaluation: every EvaluationSettings field but ``force``
# (the console keeps DeepRacer's 1..5 trials). The request model is derived from the dataclass, so
# the two cannot drift; the dataclass's own checks give the error messages.
EVALUATION_FIELDS = tuple(f.name for f in fields(EvaluationSettings) if f.name != "force")


def _evaluate_model() -> type[BaseModel]:
    hints = get_type_hints(EvaluationSettings)
    defaults = {f.name: f.default for f in fields(EvaluationSettings)}
    return pydantic_model("Evaluate", __config__=ConfigDict(extra="forbid"), __doc__=EvaluationSettings.__doc__,
                        **{name: (hints[name], defaults[name]) for name in EVALUATION_FIELDS})


Evaluate = _evaluate_model()


class ValidateReward(BaseModel):
    model_config = ConfigDict(extra="forbid")
    source: str = Field(max_length=100_000)
    track: str | None = None
    model_metadata: dict | None = None
    race_type: dict | None = None
