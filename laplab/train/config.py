"""The full configuration of a training job, stored in the model folder as ``laplab.json``."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields, replace

from laplab.agents.hyperparameters import PRECISIONS, Hyperparameters, from_dict as hyperparameters_from_dict
from laplab.env.metadata import MetadataError, ModelMetadata, metadata_from_dict
from laplab.env.spec import STEREO_LAYOUTS, ModelSpec, model_spec, uses_stereo_scheme, validate_head_layers
from laplab.errors import UserError
from laplab.train.request import DEFAULT_MAX_TIME_S
from laplab.sim.race_type import RaceType
from laplab.sim.state import EpisodeParams
from laplab.track.registry import DEFAULT_TRACK
from laplab.vehicle.params import PRESETS
from laplab.vehicle.physics import car_for_version, car_of_config, version_for_car

# 2: ``vehicle`` names one of DeepRacer's cars; in 1, "deepracer" was laplab's classic car.
# 3: ``stereo_layout``: STEREO_CAMERAS with a deeper network builds DeepRacer's stereo embedder; older
#    folders with that choice built the camera scheme and keep it ("laplab-1").
CONFIG_VERSION = 3


class ConfigError(UserError, ValueError):
    """A training option out of range."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a training job (the model folder embeds it, so a job can resume).

    - ``track``: name or path; ``reverse``: drive it the other way; ``alternate_direction``: switch
      direction every episode.
    - ``reward_path``: the reward file (None: laplab's default, the ``lap_pace`` example).
    - ``model_metadata`` (:class:`ModelMetadata`) / ``hyperparameters`` (:class:`Hyperparameters`), typed
      and frozen; hyperparameters None: laplab's defaults for this model (:func:`default_hyperparameters`).
      DeepRacer's JSON forms (dicts) are accepted and validated into them; they are written out only
      by :meth:`to_dict` (``laplab.json``). :attr:`spec` is the model's :class:`ModelSpec`.
    - ``max_time_s``: stop after this much wall time; ``max_episodes``: after this many training
      episodes (default: ``term_cond_max_episodes``); the average score stop uses
      ``term_cond_avg_score`` against the mean total reward of the last iteration's episodes.
    - ``eval_episodes``: greedy evaluation laps run after each iteration, from starts spread evenly over
      the lap (their mean progress picks the best checkpoint).
    - ``seed``: seeds the network initialisation, sampling and shuffling.
    - ``domain_randomization``: randomise camera frames in training (lighting, colours, noise, blur,
      camera jitter; see :mod:`laplab.sensors.randomize`), for models meant for the physical car.
    - ``num_threads``: torch threads (None: laplab's choice for this machine).
    - ``precision``: the networks' arithmetic in training: ``float32``, ``bfloat16`` (mixed
      precision: trunks compute in bfloat16, weights and optimizer stay float32) or ``auto``
      (bfloat16 for camera networks on CPUs that multiply bfloat16 natively, ~2x faster updates).
    - ``tracks``: the training tracks of a multi-track job (deepracer-for-cloud's
      ``DR_TRAIN_MULTI_CONFIG``), each ``name`` or ``name@reversed``; rollout worker i drives
      ``tracks[i % len(tracks)]`` and evaluation runs on every one. Empty: the one ``track`` /
      ``reverse``. When given, ``track`` / ``reverse`` are the first of them.
    - ``workers``: rollout workers (``1``: in-process collection, no Ray; more: Ray actors, see
      :mod:`laplab.cluster`); the last session's count (``--resume --workers N`` changes it).
    - ``vehicle``: the car (a :mod:`laplab.vehicle.params` preset); empty: the one DeepRacer drives for
      the model metadata's ``version`` (:func:`laplab.vehicle.physics.car_for_version`; :attr:`car` is
      the car either way, and ``laplab.json`` records it). A car given explicitly (``--physics``) sets
      the metadata's version to match, so the model folder, its exports and DeepRacer agree on it.
    - ``race_type`` (:class:`~laplab.sim.race_type.RaceType`): time trial (default; a ``laplab.json``
      without it is one), object avoidance, head-to-bot or head-to-model, with its options; its
      objects are on the track in training and evaluation, and a STATE model's vector carries their
      summary.
    - ``policy_head_layers``: SAC's policy head layers (:class:`ModelSpec`): () laplab's; an imported
      DeepRacer SAC model keeps deepracer-simapp's (256,), and so do its clones.
    - ``stereo_layout``: the layers of a STEREO_CAMERAS model with a deeper network
      (:data:`laplab.env.spec.STEREO_LAYOUTS`): ``"deepracer"``, deepracer-simapp's stereo embedder;
      ``"laplab-1"``, the camera scheme laplab built before (what a laplab.json of version 2 or older
      with that choice trained, and keeps). Clones keep it.
    - ``cloned_from``: for a clone, the model and checkpoint its weights came from
      (``"SOURCE (checkpoint NAME)"``); None for a model trained from scratch.
    """

    track: str = DEFAULT_TRACK
    reward_path: str | None = None
    model_metadata: ModelMetadata = field(default_factory=ModelMetadata)
    hyperparameters: Hyperparameters | None = None
    max_time_s: float = DEFAULT_MAX_TIME_S
    max_episodes: int | None = None
    eval_episodes: int = 3
    seed: int = 0
    reverse: bool = False
    alternate_direction: bool = False
    vehicle: str = ""
    domain_randomization: bool = False
    num_threads: int | None = None
    precision: str = "auto"
    tracks: tuple[str, ...] = ()
    workers: int = 1
    cloned_from: str | None = None
    policy_head_layers: tuple[int, ...] = ()
    stereo_layout: str = "deepracer"
    race_type: RaceType = field(default_factory=RaceType)
    version: int = CONFIG_VERSION

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_time_s) and self.max_time_s > 0):
            raise ConfigError(f"max time must be a positive number of seconds, got {self.max_time_s!r}",
                              field="max_time_s")
        if self.max_episodes is not None and self.max_episodes < 1:
            raise ConfigError(f"max episodes must be >= 1, got {self.max_episodes!r}",
                              field="max_episodes")
        if not 1 <= self.eval_episodes <= 20:
            raise ConfigError(f"eval episodes must be within 1..20, got {self.eval_episodes!r}",
                              field="eval_episodes")
        if self.precision not in PRECISIONS:
            raise ConfigError(f"precision must be one of {', '.join(PRECISIONS)}, got {self.precision!r}",
                              field="precision")
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or not 1 <= self.workers <= 1024:
            raise ConfigError(f"workers must be an integer within 1..1024, got {self.workers!r}",
                              field="workers")
        if isinstance(self.tracks, str) or not all(isinstance(t, str) for t in self.tracks):
            raise ConfigError(f"tracks must be a list of track names, got {self.tracks!r}",
                              field="tracks")
        object.__setattr__(self, "tracks", tuple(self.tracks))
        if self.tracks:
            first, reverse = parse_track_spec(self.tracks[0])
            object.__setattr__(self, "track", first)
            object.__setattr__(self, "reverse", reverse)
        if isinstance(self.model_metadata, dict):  # a model_metadata.json object: validated here
            object.__setattr__(self, "model_metadata", metadata_from_dict(self.model_metadata, "model_metadata"))
        elif not isinstance(self.model_metadata, ModelMetadata):
            raise ConfigError(f"model_metadata must be a ModelMetadata, got {type(self.model_metadata).__name__}")
        if isinstance(self.hyperparameters, dict):  # a hyperparameters.json object: validated here
            object.__setattr__(self, "hyperparameters", hyperparameters_from_dict(self.hyperparameters,
                                                                                 "hyperparameters"))
        elif self.hyperparameters is not None and not isinstance(self.hyperparameters, Hyperparameters):
            raise ConfigError(f"hyperparameters must be Hyperparameters, got {type(self.hyperparameters).__name__}")
        try:
            object.__setattr__(self, "policy_head_layers",
                               validate_head_layers(tuple(self.policy_head_layers)
                                                    if isinstance(self.policy_head_layers, (list, tuple))
                                                    else self.policy_head_layers,
                                                    self.model_metadata.training_algorithm))
        except MetadataError as exc:
            raise ConfigError(str(exc), field="policy_head_layers") from None
        if self.stereo_layout not in STEREO_LAYOUTS:
            raise ConfigError(f"stereo_layout must be one of {', '.join(STEREO_LAYOUTS)}, got {self.stereo_layout!r}",
                              field="stereo_layout")
        if isinstance(self.race_type, dict):  # laplab.json's object: validated here
            object.__setattr__(self, "race_type", RaceType.from_dict(self.race_type, "race_type"))
        elif not isinstance(self.race_type, RaceType):
            raise ConfigError(f"race_type must be a RaceType, got {type(self.race_type).__name__}", field="race_type")
        if self.race_type.kind == "head_to_model":
            raise ConfigError("--race-type head_to_model races trained models against each other (laplab race MODEL_A "
                              "MODEL_B); train for it with object_avoidance or head_to_bot", field="--race-type")
        if self.vehicle:
            if self.vehicle not in PRESETS:
                raise ConfigError(f"physics: unknown car {self.vehicle!r}; known: {', '.join(sorted(PRESETS))}",
                                  field="physics")
            version = version_for_car(self.vehicle, self.model_metadata.version)
            if version != self.model_metadata.version:
                object.__setattr__(self, "model_metadata", replace(self.model_metadata, version=version))

    def metadata(self) -> ModelMetadata:
        return self.model_metadata

    @property
    def car(self) -> str:
        """The car this job drives (a :mod:`laplab.vehicle.params` preset name): ``vehicle``, else the
        one the metadata's ``version`` chooses."""
        return self.vehicle or car_for_version(self.model_metadata.version)

    def hyper(self) -> Hyperparameters:
        """The hyperparameters, laplab's defaults for this model when none were given."""
        if self.hyperparameters is None:
            return default_hyperparameters(self.model_metadata)
        return self.hyperparameters

    @property
    def spec(self) -> ModelSpec:
        """The model's spec: its metadata with the hyperparameters' ``stack_size``."""
        return model_spec(self.model_metadata, self.hyper().stack_size, self.race_type.has_objects,
                          self.policy_head_layers, self.stereo_layout)

    @property
    def episode_limit(self) -> int:
        return self.max_episodes if self.max_episodes is not None else self.hyper().term_cond_max_episodes

    def training_tracks(self) -> list[tuple[str, bool]]:
        """(track, reverse) of every training track (one unless this is a multi-track job)."""
        if not self.tracks:
            return [(self.track, self.reverse)]
        return [parse_track_spec(spec) for spec in self.tracks]

    def episode_params(self) -> EpisodeParams:
        return EpisodeParams(reverse=self.reverse, alternate_direction=self.alternate_direction)

    def to_dict(self) -> dict:
        """The config with every value written out (laplab.json: a resumed job keeps its
        hyperparameters even if laplab's defaults change)."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        return {**values, "tracks": list(self.tracks), "policy_head_layers": list(self.policy_head_layers),
                "model_metadata": self.model_metadata.to_dict(),
                "hyperparameters": self.hyper().to_dict(), "vehicle": self.car,
                "race_type": self.race_type.to_dict()}

    @classmethod
    def from_dict(cls, data: dict, source: str = "laplab.json") -> "TrainConfig":
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ConfigError(f"{source}: unknown key {unknown[0]!r}")
        data = dict(data)
        data["vehicle"] = car_of_config(data)  # a folder from before DeepRacer's cars keeps the car it learnt on
        written_version = data.get("version") if isinstance(data.get("version"), int) else 1
        data["version"] = CONFIG_VERSION
        if "model_metadata" in data:
            data["model_metadata"] = metadata_from_dict(data["model_metadata"], f"{source}: model_metadata")
            meta = data["model_metadata"]
            if written_version < 3 and "stereo_layout" not in data \
                    and uses_stereo_scheme(meta.neural_network, meta.sensors):
                data["stereo_layout"] = "laplab-1"  # trained before laplab built DeepRacer's stereo embedder
        if data.get("hyperparameters") is not None:
            data["hyperparameters"] = hyperparameters_from_dict(data["hyperparameters"], f"{source}: hyperparameters")
        data["race_type"] = RaceType.from_dict(data.get("race_type"), f"{source}: race_type")
        return cls(**data)


def default_hyperparameters(metadata: ModelMetadata) -> Hyperparameters:
    """The console's defaults, except for camera models: deepracer-for-cloud's ``num_epochs`` 5
    instead of 10. A camera network's updates take most of a CPU's training time; 5 passes per
    iteration run 1.8x the env steps per second and lap faster after 5 minutes (BENCHMARKS.md)."""
    if metadata.camera is not None:
        return Hyperparameters(num_epochs=5)
    return Hyperparameters()


REVERSED_SUFFIX = "@reversed"


def parse_track_spec(spec: str) -> tuple[str, bool]:
    """``"name"`` -> (name, False); ``"name@reversed"`` -> (name, True) (``--track`` of a multi-track job)."""
    text = str(spec).strip()
    reverse = text.endswith(REVERSED_SUFFIX)
    name = text[: -len(REVERSED_SUFFIX)] if reverse else text
    if not name or "@" in name:
        raise ConfigError(f"cannot read the track {spec!r}: write a track name or path, optionally followed "
                          f"by {REVERSED_SUFFIX} (e.g. reInvent2019_track{REVERSED_SUFFIX})")
    return name, reverse


_DURATION = re.compile(r"^\s*([-+]?\d+(?:\.\d+)?)\s*(s|sec|m|min|h|hr)?\s*$", re.IGNORECASE)


def parse_duration(text: str) -> float:
    """``"90s"``, ``"20m"``, ``"1.5h"`` or plain seconds -> seconds."""
    match = _DURATION.match(str(text))
    if not match:
        raise ConfigError(f"cannot read the duration {text!r}: write e.g. 90s, 20m or 1.5h")
    value, unit = float(match.group(1)), (match.group(2) or "s").lower()
    seconds = value * {"s": 1, "sec": 1, "m": 60, "min": 60, "h": 3600, "hr": 3600}[unit]
    if seconds <= 0:
        raise ConfigError(f"the duration {text!r} must be positive")
    return seconds
