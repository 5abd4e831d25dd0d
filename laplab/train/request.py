"""One request type per job: the options of a training, an evaluation, an export and a race, their
defaults, their ranges and their error messages in one place.

Every door builds the same request: ``laplab train`` from its options, the console's API from its
JSON body (its pydantic body is generated from the dataclass, so ``/openapi.json`` documents the
same fields and defaults), the job worker from the job's params, and :mod:`laplab.api` before it
starts its ``laplab train`` process (whose options it then writes out). A bad value raises a
:class:`~laplab.errors.UserError` whose ``field`` is the request's field name (``max_time_s``,
``physics``, ...); the console shows the message next to that field, the CLI names the option of
:data:`CLI_OPTIONS`.

Standard library only at import time (the heavier checks import their modules when they run);
nothing here imports torch.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Mapping

from laplab.errors import UserError

DEFAULT_MAX_TIME_S = 20 * 60.0  # the one default training time of every door (CLI, console, laplab.api)
MAX_WORKERS = 1024

# request field -> the `laplab train` (or `laplab race`, `laplab export`) option that sets it
CLI_OPTIONS = {"name": "--name", "track": "--track", "tracks": "--track", "reward_path": "--reward",
               "model_metadata": "--model-metadata", "hyperparameters": "--hyperparameters",
               "max_time_s": "--max-time", "max_episodes": "--max-episodes", "seed": "--seed",
               "physics": "--physics", "race_type": "--race-type", "workers": "--workers",
               "domain_randomization": "--domain-randomization", "precision": "--precision",
               "format": "--format", "checkpoint": "--checkpoint",
               "laps": "--laps", "video": "--video"}  # the last two: `laplab race`'s


def as_cli_error(error: UserError) -> UserError:
    """``error`` as ``laplab train`` reports it: its field is the option (``--physics``), and its
    message names the option (a message starting with the field's name starts with the option
    instead, another one gets ``--option: `` before it); unchanged for a field without an option."""
    option = CLI_OPTIONS.get(error.field)
    if option is None:
        return error
    message = str(error)
    if message.startswith(f"{error.field} ") or message.startswith(f"{error.field}:"):
        message = option + message[len(error.field):]
    elif not message.startswith(option):
        message = f"{option}: {message}"
    cli = type(error).__new__(type(error))
    UserError.__init__(cli, message, field=option)
    return cli


class RequestError(UserError, ValueError):
    """A job request's value out of range; ``field`` is the request's field it is about."""


@dataclass(frozen=True)
class TrainRequest:
    """A training job as every door asks for it (a new model; a clone takes the same fields).

    - ``name``: the new model's name (letters, digits, hyphens); None where the door names it apart.
    - ``track``: a track name (``name@reversed`` drives it the other way); None: laplab's default
      track. ``tracks``: a multi-track job's tracks (rollout worker i drives track i mod count).
    - ``reward_path``: the reward function's file (None: laplab's default example).
    - ``model_metadata`` / ``hyperparameters``: DeepRacer's JSON objects (None: the defaults).
    - ``max_time_s``: stop after this many seconds (default 20 min); ``max_episodes``: after this
      many training episodes (None: the hyperparameters' ``term_cond_max_episodes``).
    - ``seed``: seeds the network initialisation, sampling and shuffling.
    - ``physics``: DeepRacer's car: 4, 5, 6, ``classic`` or a car's name (None: the one the model
      metadata's ``version`` chooses).
    - ``race_type``: :class:`laplab.sim.race_type.RaceType`'s fields (None: a time trial).
    - ``workers``: rollout workers (None: 1, or the console's Ray cluster's default).
    - ``domain_randomization``, ``precision``: as :class:`laplab.train.config.TrainConfig`'s.
    """

    name: str | None = None
    track: str | None = None
    tracks: tuple[str, ...] = ()
    reward_path: str | None = None
    model_metadata: dict | None = None
    hyperparameters: dict | None = None
    max_time_s: float = DEFAULT_MAX_TIME_S
    max_episodes: int | None = None
    seed: int = 0
    physics: str | None = None
    race_type: dict | None = None
    workers: int | None = None
    domain_randomization: bool = False
    precision: str = "auto"

    def __post_init__(self) -> None:
        """The checks of single values (cheap, no files read); :meth:`to_config` checks the rest."""
        max_time = self.max_time_s
        if isinstance(max_time, bool) or not isinstance(max_time, (int, float)) or not (math.isfinite(max_time)
                                                                                        and max_time > 0):
            shown = f"{max_time:g}" if isinstance(max_time, (int, float)) and not isinstance(max_time, bool) \
                else repr(max_time)  # -5 and -5.0 (a JSON body's float) read alike
            raise RequestError(f"max time must be a positive number of seconds, got {shown}", field="max_time_s")
        object.__setattr__(self, "max_time_s", float(max_time))
        if self.max_episodes is not None and (not _is_int(self.max_episodes) or self.max_episodes < 1):
            raise RequestError(f"max episodes must be an integer >= 1, got {self.max_episodes!r}",
                               field="max_episodes")
        if not _is_int(self.seed):
            raise RequestError(f"seed must be an integer, got {self.seed!r}", field="seed")
        if self.workers is not None and (not _is_int(self.workers) or not 1 <= self.workers <= MAX_WORKERS):
            raise RequestError(f"workers must be an integer within 1..{MAX_WORKERS}, got {self.workers!r}",
                               field="workers")
        if isinstance(self.tracks, str) or not all(isinstance(t, str) for t in self.tracks):
            raise RequestError(f"tracks must be a list of track names, got {self.tracks!r}", field="tracks")
        object.__setattr__(self, "tracks", tuple(self.tracks))
        for name in ("model_metadata", "hyperparameters", "race_type"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, Mapping):
                raise RequestError(f"{name} must be a JSON object, got {value!r}", field=name)
        if self.physics is not None:
            from laplab.vehicle.physics import resolve_physics
            object.__setattr__(self, "physics", resolve_physics(str(self.physics), option="physics"))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "TrainRequest":
        """A request from a JSON body or a job's params; None values take the defaults. An unknown
        key is refused, naming it (``vehicle``, the resolved car of older job params, is ``physics``)."""
        data = {k: v for k, v in dict(data).items() if v is not None}
        if "vehicle" in data:
            data.setdefault("physics", data.pop("vehicle"))
        return cls(**_known_options(cls, data, "training", ("tracks", "track names")))

    def to_mapping(self) -> dict[str, Any]:
        """The request as JSON types (a job's params, a body): every field that is set (not None, not
        an empty list); :meth:`from_mapping` reads it back."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is not None and value != ():
                out[f.name] = list(value) if isinstance(value, tuple) else value
        return out

    def config_values(self) -> dict[str, Any]:
        """The :class:`~laplab.train.config.TrainConfig` fields this request sets (None: the config's)."""
        values: dict[str, Any] = {"max_time_s": self.max_time_s, "seed": self.seed,
                                  "domain_randomization": self.domain_randomization, "precision": self.precision,
                                  "workers": self.workers or 1}
        if len(self.tracks) > 1:
            values["tracks"] = self.tracks
        elif self.tracks or self.track:
            values["track"] = self.tracks[0] if self.tracks else self.track
        optional = {"reward_path": self.reward_path, "max_episodes": self.max_episodes, "vehicle": self.physics,
                    "model_metadata": self.model_metadata, "hyperparameters": self.hyperparameters,
                    "race_type": self.race_type}
        values.update({k: v for k, v in optional.items() if v is not None})
        if self.race_type is not None:
            from laplab.sim.race_type import RaceType
            try:
                values["race_type"] = RaceType.from_dict(dict(self.race_type), "race_type")
            except UserError as exc:  # its field names a CLI option (--objects): the request's is race_type
                exc.field = "race_type"
                raise
            except (TypeError, ValueError) as exc:
                raise RequestError(f"race_type: {exc}", field="race_type") from None
        return values

    def to_config(self, base=None):
        """The :class:`~laplab.train.config.TrainConfig` (``base``'s other fields: a clone's source,
        else the defaults); its validators' errors carry this request's field names."""
        from laplab.train.config import TrainConfig
        config = _checked(lambda: replace(base or TrainConfig(), **self.config_values()))
        _check_randomization(config)
        return config

    def validate(self):
        """The name (when given), :meth:`to_config`, then the track loaded and the race type checked on
        it (what a job does before its first step); returns the config."""
        from laplab.track.registry import load_track
        if self.name is not None:
            from laplab.store.layout import validate_model_name
            validate_model_name(self.name)
        config = self.to_config()
        track = _checked(load_track, config.track, field="track")
        try:
            config.race_type.check_track(track.length, track.name)
        except UserError as exc:  # its field names a CLI option (--objects): the request's is race_type
            exc.field = "race_type"
            raise
        return config


def _check_randomization(config) -> None:
    """A :class:`RequestError` naming ``domain_randomization`` when ``config`` asks for it and its model
    has no camera (nothing would be randomised: laplab evaluate refuses it alike)."""
    metadata = config.model_metadata
    if config.domain_randomization and metadata.camera is None:
        raise RequestError(f"domain randomization changes what a camera sees, and this model has no camera "
                           f"(sensors: {', '.join(metadata.sensors)}): train it without domain randomization, or pick a "
                           f"camera sensor", field="domain_randomization")


def _known_options(cls, data: dict, kind: str, listed: tuple[str, str] | None = None) -> dict:
    """``data`` when every key is one of request ``cls``'s fields, else a :class:`RequestError` naming
    the first unknown key (``kind``: "training", "export", "race"); ``listed = (field, what)``: that
    field must be a JSON list of ``what``."""
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise RequestError(f"unknown {kind} option {unknown[0]!r}: known are {', '.join(sorted(names))}",
                           field=unknown[0])
    if listed is not None and listed[0] in data and not isinstance(data[listed[0]], (list, tuple)):
        raise RequestError(f"{listed[0]} must be a list of {listed[1]}, got {data[listed[0]]!r}", field=listed[0])
    return data


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _checked(call, *args, field: str | None = None):
    """``call(*args)``: a TypeError/ValueError becomes a :class:`RequestError` about ``field``, and a
    UserError without a field gets ``field``."""
    try:
        return call(*args)
    except UserError as exc:
        if exc.field is None and field is not None:
            exc.field = field
        raise
    except (TypeError, ValueError) as exc:
        raise RequestError(str(exc), field=field) from None


EXPORT_FORMATS = ("tar", "onnx", "car", "console")  # the CLI's; the console builds car and console as jobs
JOB_EXPORT_FORMATS = ("car", "console")


@dataclass(frozen=True)
class ExportRequest:
    """An export of a model's checkpoint: ``format`` (``tar``: the model folder, ``onnx``, ``car``:
    the physical car's tar.gz, ``console``: the DeepRacer console's import layout) and
    ``checkpoint`` (``best``, ``last`` or a checkpoint file name)."""

    format: str = "car"
    checkpoint: str = "best"

    def __post_init__(self) -> None:
        if self.format not in EXPORT_FORMATS:
            raise RequestError(f"format must be one of {', '.join(EXPORT_FORMATS)}, got {self.format!r}",
                               field="format")
        if not isinstance(self.checkpoint, str) or not self.checkpoint or len(self.checkpoint) > 200:
            raise RequestError(f"checkpoint must be 'best', 'last' or a checkpoint file name, got {self.checkpoint!r}",
                               field="checkpoint")

    def as_job(self) -> "ExportRequest":
        """This request, refused unless the console's worker builds its format (car, console)."""
        if self.format not in JOB_EXPORT_FORMATS:
            raise RequestError(f"format {self.format!r} is not built as a job: use one of "
                               f"{', '.join(JOB_EXPORT_FORMATS)} (tar and onnx download at once)", field="format")
        return self

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "ExportRequest":
        return cls(**_known_options(cls, {k: v for k, v in data.items() if v is not None}, "export"))

    def to_mapping(self) -> dict[str, Any]:
        return asdict(self)


RACE_LAPS = (1, 20)
RACE_MAX_TIME_S = (1.0, 3600.0)


@dataclass(frozen=True)
class RaceRequest:
    """A head-to-model race (``laplab race``, the console's race job): ``models`` (two or more different
    model names; the first is the home model, whose track is the default), ``track`` (a track name,
    ``name@reversed`` the other way; None: the first model's track and direction), ``laps`` (1..20),
    ``max_time_s`` (simulated seconds after which the race ends, 1..3600), ``checkpoint`` (``best``
    or ``last`` of every model) and ``video`` (also an MP4 of the top-down view)."""

    models: tuple[str, ...] = ()
    track: str | None = None
    laps: int = 3
    max_time_s: float = 180.0
    checkpoint: str = "best"
    video: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.models, str) or not all(isinstance(m, str) and m for m in self.models):
            raise RequestError(f"models must be a list of model names, got {self.models!r}", field="models")
        object.__setattr__(self, "models", tuple(self.models))
        if len(self.models) < 2 or len(set(self.models)) != len(self.models):
            raise RequestError("name two or more different models: laplab race MODEL_A MODEL_B", field="models")
        if not _is_int(self.laps) or not RACE_LAPS[0] <= self.laps <= RACE_LAPS[1]:
            raise RequestError(f"laps must be an integer within {RACE_LAPS[0]}..{RACE_LAPS[1]}, got {self.laps!r}",
                               field="laps")
        low, high = RACE_MAX_TIME_S
        if isinstance(self.max_time_s, bool) or not isinstance(self.max_time_s, (int, float)) \
                or not low <= self.max_time_s <= high:
            raise RequestError(f"max time must be within {low:g}..{high:g} simulated seconds, got "
                               f"{self.max_time_s!r}", field="max_time_s")
        object.__setattr__(self, "max_time_s", float(self.max_time_s))
        if self.checkpoint not in ("best", "last"):
            raise RequestError(f"checkpoint must be 'best' or 'last', got {self.checkpoint!r}", field="checkpoint")
        if self.track is not None and (not isinstance(self.track, str) or not self.track):
            raise RequestError(f"track must be a track name, got {self.track!r}", field="track")
        if not isinstance(self.video, bool):
            raise RequestError(f"video must be true or false, got {self.video!r}", field="video")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "RaceRequest":
        """A request from a JSON body or a job's params; None values take the defaults; an unknown key
        is refused, naming it."""
        data = {k: v for k, v in dict(data).items() if v is not None}
        return cls(**_known_options(cls, data, "race", ("models", "model names")))

    def to_mapping(self) -> dict[str, Any]:
        """The request as JSON types (a job's params); :meth:`from_mapping` reads it back."""
        out = asdict(self)
        out["models"] = list(self.models)
        return {k: v for k, v in out.items() if v is not None}
