"""A model folder's DeepRacer files against what trained its checkpoints.

A model folder holds its action space and sensors twice: ``model/model_metadata.json`` and
``ip/hyperparameters.json`` (DeepRacer's files, which the console, the car and deepracer-for-cloud
read) and ``laplab.json`` (the job's :class:`~laplab.train.config.TrainConfig`, which laplab
trains from). A model_metadata.json edited after training (another action space, a continuous one,
a camera) would be ignored by evaluation and copied by export into an archive that import refuses;
a garbage hyperparameters.json would be ignored by ``--resume``. :func:`check_model_files` refuses
both up front with one paragraph naming the file and the key that differs. :func:`write_model_files`
writes them, with the reward function, from one config when a model folder is made.
"""

from __future__ import annotations

import json

from laplab.errors import UserError
from laplab.store.layout import ModelFolder
from laplab.train.config import TrainConfig


class ModelFilesError(UserError):
    """A model folder's model_metadata.json or hyperparameters.json that cannot be read or does not
    match laplab.json; ``field`` is ``"<file>: <key>"`` (or the file alone when it cannot be read)."""


def write_model_files(folder: ModelFolder, config: TrainConfig, reward_source: str) -> None:
    """Write a new model's files from one config: model_metadata.json, ip/hyperparameters.json, the
    reward function (its source text) and laplab.json (the caller makes the folder and holds its lock)."""
    folder.write_model_metadata(config.model_metadata.to_dict())
    folder.write_hyperparameters(config.hyper().to_dict())
    folder.write_reward_function(reward_source)
    folder.write_laplab_config(config.to_dict())


def check_model_files(folder: ModelFolder, config: TrainConfig | None = None, what: str = "use",
                      hyperparameter_keys: tuple[str, ...] | None = None) -> TrainConfig:
    """The folder's config (``config``, else read from laplab.json), after checking that its
    model_metadata.json and ip/hyperparameters.json say the same; :class:`ModelFilesError` if not.
    ``what``: the verb of the message ("load", "export", "resume"). ``hyperparameter_keys``: the
    hyperparameters compared (None: all; loading a policy needs only ``stack_size``, and a folder
    written before laplab.json recorded every hyperparameter may differ in the others)."""
    from laplab.agents.hyperparameters import HyperparameterError, from_dict as hyperparameters_from_dict
    from laplab.env.action_space import ActionSpaceError
    from laplab.env.metadata import MetadataError, metadata_from_dict

    if config is None:
        config = TrainConfig.from_dict(folder.read_laplab_config(), str(folder.laplab_config))
    checks = ((folder.model_metadata, "model_metadata", config.metadata().to_dict(),
               lambda data, source: metadata_from_dict(data, source).to_dict()),
              (folder.hyperparameters, "hyperparameters", config.hyper().to_dict(),
               lambda data, source: hyperparameters_from_dict(data, source).to_dict()))
    for path, key_in_config, trained, parse in checks:
        if not path.exists():
            continue  # a folder laplab did not write whole (a pulled subset); laplab.json decides
        try:
            text = path.read_text(encoding="utf-8")
            found = parse(json.loads(text), str(path))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ModelFilesError(f"cannot {what} model {folder.name!r}: {path} is not a readable JSON file "
                                  f"({' '.join(str(exc).split())}). {_restore(path, key_in_config)}",
                                  field=path.name) from None
        except (MetadataError, ActionSpaceError, HyperparameterError) as exc:
            raise ModelFilesError(f"cannot {what} model {folder.name!r}: {exc} {_restore(path, key_in_config)}",
                                  field=path.name) from None
        keys = sorted(set(found) | set(trained))
        if key_in_config == "hyperparameters" and hyperparameter_keys is not None:
            keys = [key for key in keys if key in hyperparameter_keys]
        differing = [key for key in keys if found.get(key) != trained.get(key)]
        if differing:
            key = differing[0]
            raise ModelFilesError(
                f"cannot {what} model {folder.name!r}: {path} was changed after training: its {key!r} is "
                f"{_show(found.get(key))}, but the model was trained with {_show(trained.get(key))} "
                f"(laplab.json, {key_in_config!r}). The checkpoints only work with what trained them. "
                f"{_restore(path, key_in_config)}", field=f"{path.name}: {key}")
    return config


def _restore(path, key_in_config: str) -> str:
    return (f"Restore {path.name} from laplab.json's {key_in_config!r}; for another action space, sensor or "
            "hyperparameters train a new model (`laplab train --name NEW ...`).")


def _show(value) -> str:
    text = "missing" if value is None else json.dumps(value)
    return text if len(text) <= 120 else text[:117] + "..."
