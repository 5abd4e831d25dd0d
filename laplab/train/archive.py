"""Model archives above the store: exports whose checkpoint is verified first, imports whose model is
validated (metadata, hyperparameters, laplab.json, the checkpoint loads into the network), and the
trust an imported reward function needs before it runs.

An archive's ``reward_function.py`` is code: importing it runs nothing, but training the model
(``--resume``, ``clone``) would run it. So an import is recorded in ``laplab-import.json`` in the
model folder with the reward's sha256, and a job refuses to run that reward until the user trusts it
once (``--trust-reward``, recorded) or gives another one (``clone --reward FILE``).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path
from typing import BinaryIO

from laplab.store import archive as store_archive
from laplab.store.archive import ArchiveError, ImportedModel
from laplab.store.atomic import CorruptFileError, atomic_write_json
from laplab.store.layout import ModelFolder, model_folder
from laplab.train.errors import JobError

IMPORT_RECORD = "laplab-import.json"


def export_model_archive(name: str, checkpoint: str = "best", out: str | os.PathLike | None = None,
                         full_state: bool = False) -> Path:
    """:func:`laplab.store.archive.export_model_archive` after checking that the checkpoint loads
    (``full_state``: with the last checkpoint's resume state)."""
    from laplab.train.checkpoint_read import load_state
    from laplab.train.model_files import check_model_files

    folder = model_folder(name)
    if folder.laplab_config.exists():
        check_model_files(folder, what="export")  # an archive that import would refuse is never written

    def verify(handle: BinaryIO, where: str) -> None:
        try:
            load_state(handle, os.path.basename(where), where)
        except CorruptFileError as exc:
            raise ArchiveError(f"{exc} Nothing was written.") from None

    return store_archive.export_model_archive(name, checkpoint, out, verify=verify, full_state=full_state)


def import_model_archive(path: str | os.PathLike, name: str | None = None) -> ImportedModel:
    """Import an archive (see :mod:`laplab.store.archive`), validating the model, and record that its
    reward function is not trusted yet."""
    imported = store_archive.import_model_archive(path, name, validate=validate_model_folder)
    source = imported.folder.reward_function.read_bytes()
    atomic_write_json(imported.folder.root / IMPORT_RECORD, {
        "archive": str(Path(path).resolve()), "imported_at": time.time(),
        "reward_sha256": hashlib.sha256(source).hexdigest(), "reward_trusted": False})
    return imported


def reward_needs_trust(folder: ModelFolder) -> bool:
    """Whether ``folder`` is an imported model whose reward function nobody has trusted yet (or whose
    reward_function.py changed since it was trusted)."""
    path = folder.root / IMPORT_RECORD
    if not path.exists():
        return False
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
        digest = hashlib.sha256(folder.reward_function.read_bytes()).hexdigest()
        return not (record.get("reward_trusted") is True and record.get("reward_sha256") == digest)
    except (OSError, ValueError, AttributeError):
        return True


def trust_reward(folder: ModelFolder) -> None:
    """Record that the user trusts the imported model's current reward function."""
    path = folder.root / IMPORT_RECORD
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        record = {}
    record.update(reward_trusted=True, trusted_at=time.time(),
                  reward_sha256=hashlib.sha256(folder.reward_function.read_bytes()).hexdigest())
    atomic_write_json(path, record)


def check_reward_trusted(folder: ModelFolder, trust: bool, command: str) -> None:
    """Refuse to run an imported model's reward function until it is trusted; ``trust`` records it."""
    if not reward_needs_trust(folder):
        return
    if trust:
        trust_reward(folder)
        return
    raise JobError(f"model {folder.name!r} was imported from an archive, and its reward function "
                   f"({folder.reward_function}) is Python code that would run on this machine with your "
                   f"permissions. Read it, then run `{command} --trust-reward` once to trust it (this is "
                   f"recorded), or give your own with --reward FILE (laplab clone).")


def check_trainable(folder: ModelFolder, command: str) -> None:
    """Refuse to train a model imported from a frozen graph (a car's model.pb): it has a policy but
    no value network or optimizer state to continue from."""
    path = folder.root / IMPORT_RECORD
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return
    if isinstance(record, dict) and record.get("trainable") is False:
        raise JobError(f"model {folder.name!r} was imported from a frozen graph ({record.get('source_checkpoint')}, "
                       f"from {record.get('source')}): it holds the policy network only, without the value network "
                       f"and training state, so `{command}` cannot continue its training. Evaluate, race or export "
                       "it; to train, import the model's folder with its rl_coach checkpoint (model/*.ckpt.*).")


def validate_model_folder(folder: ModelFolder, checkpoint: str, source: str) -> None:
    """Check that ``folder`` is a usable laplab model whose ``checkpoint`` loads into its network.
    Errors name ``source`` and the file at fault."""
    from laplab.agents.hyperparameters import HyperparameterError, from_dict as hyperparameters_from_dict
    from laplab.env.metadata import MetadataError, metadata_from_dict
    from laplab.train.config import ConfigError, TrainConfig

    def read(member: str):
        try:
            return json.loads((folder.root / member).read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ArchiveError(f"{source}: {member} is not valid JSON ({exc}).") from None

    try:
        metadata = metadata_from_dict(read("model/model_metadata.json"), f"{source}: model/model_metadata.json")
        hyper = hyperparameters_from_dict(read("ip/hyperparameters.json"), f"{source}: ip/hyperparameters.json")
        config = TrainConfig.from_dict(read("laplab.json"), f"{source}: laplab.json")
    except (MetadataError, HyperparameterError, ConfigError, TypeError) as exc:
        raise ArchiveError(str(exc)) from None
    for what, file_value, config_value in (("model/model_metadata.json", metadata, config.metadata()),
                                           ("ip/hyperparameters.json", hyper, config.hyper())):
        if file_value != config_value:
            raise ArchiveError(f"{source}: {what} differs from the one recorded in laplab.json; the model "
                               "would not train or evaluate as it was trained.")
    _check_checkpoint_loads(folder.model_dir / checkpoint, config, source)


def _check_checkpoint_loads(path: Path, config, source: str) -> None:
    import torch

    from laplab.track.geometry import TrackError
    from laplab.track.registry import load_track
    from laplab.train.trainer import build_learner

    try:
        load_track(config.track)
    except TrackError as exc:
        raise ArchiveError(f"{source}: the model's track {config.track!r} (laplab.json 'track') is not available "
                           f"here, so its checkpoint cannot be checked: {exc}") from None
    learner = build_learner(config, config.seed)  # the model's spec alone fixes its networks
    try:
        # weights_only: an archive may come from anyone, and a full unpickle can run arbitrary code.
        learner.load_state_dict(torch.load(path, map_location="cpu", weights_only=True)["learner"])
    except Exception as exc:  # a truncated or unsafe pickle, a foreign state dict, mismatched shapes ...
        reason = " ".join(str(exc).split())  # torch's messages span lines; keep one paragraph
        raise ArchiveError(f"{source}: checkpoint model/{path.name} does not load into the model's network "
                           f"(sensors {list(config.metadata().sensors)}, {config.metadata().training_algorithm}): "
                           f"{type(exc).__name__}: {reason[:300]}") from None
