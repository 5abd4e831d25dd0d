"""The physical car's model: ``model.pb`` + ``model_metadata.json`` in a ``.tar.gz`` (docs/car.md).

The car's upload page (aws-deepracer-webserver-pkg ``models.py``) saves ``NAME.tar.gz`` and the
model loader (aws-deepracer-systems-pkg ``model_loader_node.py``) extracts it, takes the archive's
only ``.pb`` file (searched in every folder; two or more and the archive is ignored) as
``artifacts/NAME/model.pb`` and ``model_metadata.json`` from the archive's top level. The archive
here has the layout of the console's car download and of deepracer-for-cloud's ``carfile.tar.gz``
(the SageMaker ``/opt/ml/model`` folder): ``agent/model.pb`` and ``model_metadata.json``.
"""

from __future__ import annotations

import io
import json
import tarfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from laplab.errors import UserError

CAR_SENSORS = ("FRONT_FACING_CAMERA", "LEFT_CAMERA", "STEREO_CAMERAS", "LIDAR", "SECTOR_LIDAR")
CONSOLE_SENSORS = CAR_SENSORS + ("DISCRETIZED_SECTOR_LIDAR",)
CAR_GRAPH_MEMBER = "agent/model.pb"
METADATA_MEMBER = "model_metadata.json"
PARITY_TOLERANCE = 1e-4  # max |TensorFlow - torch| accepted by the export's self-check
PARITY_SAMPLES = 16


class CarExportError(UserError, ValueError):
    """A model that cannot go to the car or the console; the message says why and what to do."""


@dataclass(frozen=True)
class CarGraph:
    """A model's policy as DeepRacer's frozen graph: ``data`` (model.pb bytes), the metadata to ship
    with it, the checkpoint it came from, and the max |TensorFlow - torch| on random observations.
    ``layers`` / ``value_layers``: the policy's (and PPO's value network's) weights, from which the
    console's TensorFlow checkpoint is written."""

    name: str
    checkpoint: str
    data: bytes
    metadata: dict
    parity_error: float
    layers: Any = None
    value_layers: Any = None


def check_exportable(metadata: dict, stack_size: int, allowed: tuple[str, ...], where: str) -> None:
    """Refuse, with the reason, a model ``where`` (the car / the console) cannot run."""
    sensors = list(metadata.get("sensor", []))
    unsupported = [s for s in sensors if s not in allowed]
    if unsupported:
        hint = (" STATE is laplab's own simulator-only sensor; train with FRONT_FACING_CAMERA (and LIDAR) "
                "for the car." if "STATE" in unsupported else "")
        raise CarExportError(f"model_metadata.json: sensor {unsupported[0]!r} is not supported by {where} "
                             f"(it takes {', '.join(allowed)}).{hint}")
    if stack_size != 1:
        raise CarExportError(f"hyperparameters: stack_size is {stack_size}; {where} feeds one frame per camera "
                             "(stack_size 1).")


def check_model_exportable(name: str, allowed: tuple[str, ...] = CAR_SENSORS,
                           where: str = "the DeepRacer car") -> None:
    """:func:`check_exportable` from model ``name``'s files alone (no torch, no TensorFlow): a job
    refuses a model the car cannot run before it pays for loading either."""
    from laplab.store.layout import model_folder
    folder = model_folder(name)
    if not folder.model_metadata.exists():
        return  # the export itself names what is missing
    if folder.laplab_config.exists():
        from laplab.train.model_files import check_model_files
        check_model_files(folder, what="export", hyperparameter_keys=("stack_size",))
    hyper = folder.read_laplab_config().get("hyperparameters", {}) if folder.laplab_config.exists() else {}
    check_exportable(folder.read_model_metadata(), int(hyper.get("stack_size", 1)), allowed, where)


def car_metadata(metadata: dict) -> dict:
    """The model_metadata.json the car gets. laplab's ``lidar_config`` (DISCRETIZED_SECTOR_LIDAR's
    num_sectors / num_values_per_sector / clipping_dist) is not the car's (num_values, min_angle, ...):
    it is left out, and the car uses its defaults, which are laplab's LIDAR and SECTOR_LIDAR."""
    return {key: value for key, value in metadata.items() if key != "lidar_config"}


def build_car_graph(name: str, checkpoint: str = "best", allowed: tuple[str, ...] = CAR_SENSORS,
                    where: str = "the DeepRacer car") -> CarGraph:
    """Load model ``name`` at ``checkpoint``, check the car can run it, build its graph and check the
    graph against the torch policy (TensorFlow vs torch on 16 random observations)."""
    from laplab.agents.onnx_export import random_observations
    from laplab.agents.networks import ActorCritic
    from laplab.export.policy_layers import graph_reference_output, policy_layers, value_layers
    from laplab.export.tensorflow_graph import FrozenGraph, graph_bytes, graph_feed, output_node_name
    from laplab.train.policy import load_model_policy

    policy = load_model_policy(name, checkpoint)
    metadata = policy.folder.read_model_metadata()
    check_exportable(metadata, int(policy.config.hyper().stack_size), allowed, where)
    sensors = list(policy.metadata.sensors)
    layers = policy_layers(policy.network, policy.observation_space, sensors)
    data = graph_bytes(layers)
    observations = random_observations(policy.observation_space, PARITY_SAMPLES, seed=0)
    graph = FrozenGraph(data, output_node_name(layers.algorithm))
    error = float(np.max(np.abs(graph.run(graph_feed(layers, observations))
                                - graph_reference_output(policy.network, observations))))
    if not error <= PARITY_TOLERANCE:
        raise CarExportError(f"the TensorFlow graph of {name!r} differs from the torch policy by {error:.3g} "
                             f"(> {PARITY_TOLERANCE}); nothing was written. Please report this as a bug.")
    value = value_layers(policy.network, policy.observation_space, sensors) \
        if isinstance(policy.network, ActorCritic) else None
    return CarGraph(name, policy.checkpoint, data, metadata, error, layers, value)


def _member(name: str, data: bytes, mtime: float) -> tuple[tarfile.TarInfo, io.BytesIO]:
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode = len(data), int(mtime), 0o644
    return info, io.BytesIO(data)


def write_car_archive(graph: CarGraph, out: str | Path | None = None) -> Path:
    """``<name>.tar.gz`` (or ``out``; a folder gets ``<name>.tar.gz`` inside) holding
    ``agent/model.pb`` and ``model_metadata.json``, written atomically. The car names the model
    after the file name up to its first dot."""
    from laplab.store.atomic import atomic_write_with

    target = Path(out) if out is not None else Path.cwd()
    if target.is_dir():
        target = target / f"{graph.name}.tar.gz"
    metadata = json.dumps(car_metadata(graph.metadata), indent=2).encode() + b"\n"
    now = time.time()

    def write(temporary: Path) -> None:
        with tarfile.open(temporary, "w:gz", format=tarfile.GNU_FORMAT) as tar:
            for member, data in ((METADATA_MEMBER, metadata), (CAR_GRAPH_MEMBER, graph.data)):
                tar.addfile(*_member(member, data, now))

    return atomic_write_with(target, write)


def export_car(name: str, checkpoint: str = "best", out: str | Path | None = None) -> tuple[Path, CarGraph]:
    """``laplab export NAME --format car``: the car's tar.gz. Returns its path and the graph."""
    graph = build_car_graph(name, checkpoint)
    return write_car_archive(graph, out), graph

