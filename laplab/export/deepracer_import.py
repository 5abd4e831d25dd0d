"""``laplab import`` of DeepRacer's own model layouts: an rl_coach checkpoint becomes a laplab model.

Read (``laplab.export.import_sources`` makes any source a local folder)::

    model_metadata.json (or model/model_metadata.json)   sensors, network, algorithm, action space, version
    ip/hyperparameters.json (or hyperparameters.json)     DeepRacer's hyperparameters
    reward_function.py                                    untrusted code: kept, never run by the import
    training_params*.yaml                                 the training track (WORLD_NAME), when laplab has it
    model/<N>_Step-<S>.ckpt.index + .data-*               rl_coach's TensorFlow checkpoint
    model/deepracer_checkpoints.json, .coach_checkpoint, model/checkpoint   which checkpoint (best first)
    model/model_<N>.pb, agent/model.pb or model.pb        a car's frozen graph (when there is no checkpoint)

The checkpoint is read without TensorFlow (:mod:`laplab.export.checkpoint_bundle`); its variables
must be exactly those of the network the metadata describes (names and shapes:
:mod:`laplab.export.rl_coach_weights`), and they are written into a laplab learner of that spec,
saved as the model's one checkpoint. A bare ``model.pb`` gives the policy network only: the model
evaluates, races and exports, but its training cannot continue (no value network, no reward
function): ``laplab-import.json`` says ``"trainable": false`` and clone / resume refuse it.

The model folder is built in a hidden staging folder beside the models and renamed into place: it
appears complete or not at all. Errors are :class:`DeepRacerImportError`, naming the file at fault.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import secrets
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from laplab.errors import UserError
from laplab.export.checkpoint_bundle import BundleError, read_checkpoint, read_index
from laplab.export.import_sources import MAX_IMPORT_BYTES, staged_source
from laplab.export.tensorflow_checkpoint import RESCALER

CHECKPOINT_INDEX = re.compile(r"(.+\.ckpt)\.index")
RL_COACH_NAME = re.compile(r"([0-9]+)_Step-([0-9]+)\.ckpt")


class DeepRacerImportError(UserError, ValueError):
    """A DeepRacer model that cannot be imported; the message names the file and what is wrong."""


@dataclass(frozen=True)
class DeepRacerLayout:
    """What was found in a model folder: the JSON files parsed, the reward's source (None: absent),
    the training track (None: not given), and ``checkpoint`` (its prefix path, e.g.
    ``model/30_Step-163797.ckpt``) or, without one, ``graph`` (a model.pb)."""

    root: Path
    metadata: dict
    metadata_file: str
    hyperparameters: dict | None
    reward_source: str | None
    track: str | None
    checkpoint: Path | None
    checkpoint_metric: float | None
    graph: Path | None


@dataclass(frozen=True)
class DeepRacerImport:
    name: str
    folder: object  # laplab.store.layout.ModelFolder
    checkpoint: str  # laplab's checkpoint file name
    source_checkpoint: str  # the rl_coach checkpoint (or model.pb) it came from
    trainable: bool
    notes: tuple[str, ...]


def is_deepracer_source(source: str | os.PathLike) -> bool:
    """Whether ``source`` is one of DeepRacer's layouts rather than a laplab archive (a ``.tar.gz``
    holding ``laplab-export.json``)."""
    text = str(source)
    if text.startswith("s3://") or text.lower().endswith((".zip", ".pb")) or not Path(text).is_file():
        return True  # (a path that does not exist: its error lists every kind of source)
    if text.lower().endswith((".tar.gz", ".tgz", ".tar")) and Path(text).is_file():
        import tarfile
        try:
            with tarfile.open(text, "r:*") as tar:
                for info in tar:
                    if info.name.removeprefix("./") == "laplab-export.json":
                        return False
        except (tarfile.TarError, OSError, EOFError):
            return False  # the archive importer names the damage
        return True
    return False


def _json(path: Path, source: str) -> dict:
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DeepRacerImportError(f"{source}: {path.name} is not a readable JSON file ({exc}).",
                                   field=path.name) from None
    if not isinstance(value, dict):
        raise DeepRacerImportError(f"{source}: {path.name} holds {type(value).__name__}, not a JSON object.",
                                   field=path.name)
    return value


def _first(root: Path, *candidates: str) -> Path | None:
    return next((root / c for c in candidates if (root / c).is_file()), None)


def training_track(root: Path) -> str | None:
    """``WORLD_NAME`` of the folder's training_params*.yaml (quoted or plain YAML), if any."""
    for path in sorted(root.glob("training_params*.yaml")):
        match = re.search(r"""^\s*['"]?WORLD_NAME['"]?\s*:\s*['"]?([^'"\n]+?)['"]?\s*$""",
                          path.read_text(encoding="utf-8", errors="replace"), re.MULTILINE)
        if match:
            return match.group(1).strip()
    return None


def _checkpoint_names(model_dir: Path) -> list[str]:
    """The checkpoints in ``model_dir`` (their prefixes), oldest first."""
    def order(name: str) -> tuple[int, int]:
        match = RL_COACH_NAME.fullmatch(name)
        return (int(match.group(1)), int(match.group(2))) if match else (-1, -1)

    names = [m.group(1) for p in model_dir.glob("*.ckpt.index") if (m := CHECKPOINT_INDEX.fullmatch(p.name))]
    return sorted(names, key=order)


def choose_checkpoint(model_dir: Path, source: str) -> tuple[str | None, float | None]:
    """(the checkpoint to import, its avg_eval_metric): the one deepracer_checkpoints.json names best,
    else ``.coach_checkpoint``'s, else TensorFlow's ``checkpoint`` state's, else the newest one
    (None: there is none). A named checkpoint whose files are missing is an error."""
    names = _checkpoint_names(model_dir)
    if not names:
        return None, None
    choices: list[tuple[str, str, float | None]] = []
    index = model_dir / "deepracer_checkpoints.json"
    if index.is_file():
        records = _json(index, source)
        for key in ("best_checkpoint", "last_checkpoint"):
            record = records.get(key)
            if isinstance(record, dict) and isinstance(record.get("name"), str):
                metric = record.get("avg_eval_metric")
                choices.append((record["name"], f"model/deepracer_checkpoints.json ({key})",
                                float(metric) if isinstance(metric, (int, float)) else None))
    coach = model_dir / ".coach_checkpoint"
    if coach.is_file():
        choices.append((coach.read_text(encoding="utf-8", errors="replace").strip(), "model/.coach_checkpoint", None))
    state = model_dir / "checkpoint"
    if state.is_file():
        match = re.search(r'model_checkpoint_path:\s*"([^"]+)"', state.read_text(encoding="utf-8", errors="replace"))
        if match:
            choices.append((Path(match.group(1)).name, "model/checkpoint", None))
    if choices:  # the first file that names one decides: never a silent fallback to another checkpoint
        name, where, metric = choices[0]
        if name in names:
            return name, metric
        raise DeepRacerImportError(f"{source}: {where} names checkpoint {name!r}, but model/ holds no {name}.index "
                                   f"(it has {', '.join(names)}). Copy the whole model/ folder, or fix {where}.",
                                   field=where.split(" ")[0])
    return names[-1], None


def read_layout(root: Path, source: str) -> DeepRacerLayout:
    """The model files in ``root``; :class:`DeepRacerImportError` naming a missing or unreadable one."""
    metadata_path = _first(root, "model_metadata.json", "model/model_metadata.json")
    graph = _first(root, "agent/model.pb", "model.pb") or next(iter(sorted(root.glob("model/model_*.pb"))), None)
    if metadata_path is None:
        raise DeepRacerImportError(f"{source}: model_metadata.json is missing (looked for model_metadata.json and "
                                   "model/model_metadata.json); it says the model's sensors, network and action "
                                   "space. Nothing was imported.", field="model_metadata.json")
    model_dir = root / "model"
    checkpoint_name, metric = choose_checkpoint(model_dir, source) if model_dir.is_dir() else (None, None)
    if checkpoint_name is None and graph is None:
        raise DeepRacerImportError(f"{source}: no model weights: neither rl_coach's checkpoint "
                                   "(model/<N>_Step-<S>.ckpt.index with its .data file) nor a model.pb. "
                                   "Nothing was imported.", field="model")
    hyper_path = _first(root, "ip/hyperparameters.json", "hyperparameters.json")
    reward_path = _first(root, "reward_function.py")
    if checkpoint_name is not None:
        for path, name in ((hyper_path, "ip/hyperparameters.json"), (reward_path, "reward_function.py")):
            if path is None:
                raise DeepRacerImportError(f"{source}: {name} is missing; a model with rl_coach's checkpoint is "
                                           f"imported with it (DeepRacer on AWS requires it too). Nothing was "
                                           "imported.", field=name)
    reward = None
    if reward_path is not None:
        try:
            reward = reward_path.read_text(encoding="utf-8")
            compile(reward, str(reward_path), "exec")
        except (SyntaxError, UnicodeDecodeError, ValueError, RecursionError, MemoryError) as exc:
            raise DeepRacerImportError(f"{source}: reward_function.py does not compile: {exc}. Nothing was imported.",
                                       field="reward_function.py") from None
    return DeepRacerLayout(root, _json(metadata_path, source), str(metadata_path.relative_to(root)),
                           None if hyper_path is None else _json(hyper_path, source), reward, training_track(root),
                           None if checkpoint_name is None else model_dir / checkpoint_name, metric,
                           None if checkpoint_name is not None else graph)


def _config(layout: DeepRacerLayout, source: str):
    from laplab.agents.hyperparameters import HyperparameterError
    from laplab.env.action_space import ActionSpaceError
    from laplab.env.metadata import MetadataError, metadata_from_dict
    from laplab.track.geometry import TrackError
    from laplab.track.registry import DEFAULT_TRACK, load_track
    from laplab.train.config import ConfigError, TrainConfig

    try:
        metadata = metadata_from_dict(layout.metadata, f"{source}: {layout.metadata_file}")
    except (MetadataError, ActionSpaceError, TypeError) as exc:
        raise DeepRacerImportError(f"{exc} Nothing was imported.", field=layout.metadata_file) from None
    notes = []
    track = DEFAULT_TRACK
    if layout.track:
        try:
            load_track(layout.track)
            track = layout.track
        except TrackError:
            notes.append(f"the training track {layout.track!r} (training_params.yaml) is not one laplab has; the "
                         f"model trains on {DEFAULT_TRACK} unless you clone it with --track")
    hyperparameters = layout.hyperparameters
    if hyperparameters is not None:
        from dataclasses import fields

        from laplab.agents.hyperparameters import Hyperparameters
        known = {f.name for f in fields(Hyperparameters)}
        unknown = sorted(set(hyperparameters) - known)
        if unknown:  # a newer DeepRacer's keys: kept out of the model, said once
            notes.append(f"ip/hyperparameters.json: {', '.join(unknown)} ignored (laplab does not use them)")
            hyperparameters = {key: value for key, value in hyperparameters.items() if key in known}
    try:
        config = TrainConfig(track=track, model_metadata=metadata, hyperparameters=hyperparameters)
        config.hyper()
    except (HyperparameterError, ConfigError, TypeError) as exc:
        raise DeepRacerImportError(f"{source}: ip/hyperparameters.json: {exc} Nothing was imported.",
                                   field="hyperparameters.json") from None
    return config, notes


def _templates(learner, config):
    from laplab.export.policy_layers import policy_layers, value_layers
    spec = config.spec
    network = learner.policy_network
    sensors = list(config.metadata().sensors)
    policy = policy_layers(network, spec.observation_space, sensors)
    value = value_layers(network, spec.observation_space, sensors) if policy.algorithm == "clipped_ppo" else None
    return network, spec.observation_space, policy, value


def _describe(config) -> str:
    meta = config.metadata()
    return (f"{meta.training_algorithm}, sensors {list(meta.sensors)}, {meta.neural_network}, "
            f"{meta.action_space.kind} action space of {len(meta.action_space.actions) or 2} outputs")


def _found_variables(layout: DeepRacerLayout) -> tuple[str, dict[str, tuple[int, ...]], dict | None]:
    """(the file read, {variable: shape} it holds, the graph's constants or None for a checkpoint)."""
    from laplab.export.frozen_graph_weights import graph_constants

    if layout.checkpoint is not None:
        _, entries = read_index(f"{layout.checkpoint}.index")
        return (f"{layout.checkpoint.relative_to(layout.root)}.index",
                {name: entry.shape for name, entry in entries.items()}, None)
    constants = graph_constants(layout.graph)
    return str(layout.graph.relative_to(layout.root)), {name: a.shape for name, a in constants.items()}, constants


def load_weights(layout: DeepRacerLayout, config, source: str, notes: list[str]):
    """(a learner holding the layout's weights, the config it was built from: ``config`` with the SAC
    policy head the checkpoint holds); the checkpoint's (or graph's) variables are checked against the
    metadata's network first. A DeepRacer SAC policy keeps its own trunk and its critics start fresh
    (one line in ``notes``)."""
    from dataclasses import replace

    from laplab.export.policy_layers import load_policy_layers
    from laplab.export.rl_coach_weights import expected_variables, layers_from_variables, mismatches, sac_head_layers
    from laplab.train.trainer import build_learner

    try:
        where, found, constants = _found_variables(layout)
        if config.metadata().training_algorithm == "sac":
            try:
                config = replace(config, policy_head_layers=sac_head_layers(found))
            except UserError as exc:
                raise DeepRacerImportError(f"{source}: {where}: SAC policy head: {exc}. Nothing was imported.",
                                           field=where) from None
        learner = build_learner(config, config.seed, precision="float32")
        network, space, policy, value = _templates(learner, config)
        expected = expected_variables(policy, None if constants is not None else value)
        if constants is not None:  # a frozen graph: the rescaler may be folded out, the log-std pruned
            value = None
            optional = (RESCALER, "policy_log_std/kernel", "policy_log_std/bias", "ppo_head_0/policy_log_std",
                        f"dense_{len(policy.head_hidden)}/kernel", f"dense_{len(policy.head_hidden)}/bias")
            expected = {name: shape for name, shape in expected.items()
                        if not name.endswith(optional) or name in found}
        problems = mismatches(found, expected, strict=constants is None)
        if problems:
            raise DeepRacerImportError(
                f"{source}: {where} does not hold the network {layout.metadata_file} describes ({_describe(config)}): "
                f"{'; '.join(problems[:3])}{' ...' if len(problems) > 3 else ''}. Is model_metadata.json the one this "
                "model was trained with? Nothing was imported.", field=where)
        variables = (read_checkpoint(layout.checkpoint, set(expected)) if constants is None
                     else {name: constants[name] for name in expected})
    except BundleError as exc:
        raise DeepRacerImportError(f"{source}: {exc} Nothing was imported.", field=exc.field) from None
    broken = next((name for name in sorted(variables) if not np.isfinite(variables[name]).all()), None)
    if broken is not None:
        raise DeepRacerImportError(f"{source}: {where}: variable {broken!r} holds NaN or infinite weights; the "
                                   "checkpoint is damaged (or its training diverged). Nothing was imported.",
                                   field=where)
    if policy.head_hidden:  # deepracer-simapp's SAC: rl_coach's separate networks
        learner.set_shared_trunk(False)
        network = learner.policy_network
        notes.append("SAC: the policy is DeepRacer's, weight for weight; the critics (Q networks) start fresh, "
                     "as rl_coach's q and v networks have no counterpart in laplab's twin critic")
    loaded_policy, loaded_value = layers_from_variables(policy, value, variables)
    load_policy_layers(network, space, loaded_policy, loaded_value)
    return learner, config


def import_deepracer_model(source: str | os.PathLike, name: str | None = None,
                           max_bytes: int = MAX_IMPORT_BYTES) -> DeepRacerImport:
    """Import the DeepRacer model at ``source`` (folder, .tar.gz/.zip, model.pb or s3://) as model
    ``name`` (default: the source's folder or file name)."""
    from laplab.store.layout import model_folder, validate_model_name

    text = str(source)
    new_name = validate_model_name(name if name is not None else default_name(text))
    target = model_folder(new_name)
    if target.exists():
        raise DeepRacerImportError(f"a model named {new_name!r} already exists at {target.root}; models are "
                                   "immutable: import under another name with --name NEW.", field="name")
    with staged_source(source, max_bytes) as root:
        layout = read_layout(root, text)
        config, notes = _config(layout, text)
        learner, config = load_weights(layout, config, text, notes)
        return _write_model(new_name, layout, config, learner, text, notes)


def default_name(source: str) -> str:
    """A model name from the source: the prefix's or folder's last part, the archive's name."""
    stem = source.rstrip("/").split("/")[-1]
    if stem.lower() == "model.pb":
        stem = Path(source).resolve().parent.name or "imported"
    for suffix in (".tar.gz", ".tgz", ".tar", ".zip", ".pb"):
        if stem.lower().endswith(suffix):
            stem = stem[: -len(suffix)]
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", stem).strip("-.") or "imported"


def _write_model(name: str, layout: DeepRacerLayout, config, learner, source: str,
                 notes: list[str]) -> DeepRacerImport:
    from laplab.env.vector import DEFAULT_REWARD
    from laplab.store.atomic import atomic_write_json
    from laplab.store.checkpoints import CheckpointStore
    from laplab.store.layout import ModelFolder, model_folder, models_root
    from laplab.train.archive import IMPORT_RECORD
    from laplab.train.model_files import write_model_files
    from laplab.train.trainer import checkpoint_writer

    trainable = layout.checkpoint is not None
    origin = layout.checkpoint.name if trainable else layout.graph.name
    match = RL_COACH_NAME.fullmatch(origin) if trainable else None
    iteration, steps = (int(match.group(1)), int(match.group(2))) if match else (0, 0)
    reward = layout.reward_source
    if reward is None:
        reward = DEFAULT_REWARD.read_text()
        notes.append("no reward_function.py came with the model; laplab's default reward was written in its place")
    if not trainable:
        notes.append("imported from a frozen model.pb: it evaluates, races and exports, but cannot be cloned or "
                     "trained further (the graph holds the policy only: no value network, no optimizer state)")
    root = models_root()
    root.mkdir(parents=True, exist_ok=True)
    staging = ModelFolder(root / f".import-{name}-{secrets.token_hex(6)}")  # hidden: list_models skips it
    target = model_folder(name)
    try:
        staging.create()
        write_model_files(staging, config, reward)
        path = CheckpointStore(staging).save(checkpoint_writer(learner, iteration, steps, 0, None),
                                             iteration=iteration, steps=steps, metric=layout.checkpoint_metric)
        atomic_write_json(staging.root / IMPORT_RECORD, {
            "source": source, "format": "rl_coach checkpoint" if trainable else "frozen graph (model.pb)",
            "source_checkpoint": origin, "imported_at": time.time(), "trainable": trainable,
            "reward_sha256": hashlib.sha256(reward.encode()).hexdigest(), "reward_trusted": False, "notes": notes})
        try:
            os.rename(staging.root, target.root)
        except OSError as exc:
            raise DeepRacerImportError(f"cannot create {target.root}: {exc}. Nothing was imported.") from None
    except BaseException:
        shutil.rmtree(staging.root, ignore_errors=True)
        raise
    return DeepRacerImport(name, target, path.name, origin, trainable, tuple(notes))
