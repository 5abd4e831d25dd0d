"""Reading a checkpoint safely while a job may be writing the folder, with clear errors for damaged files.

Checkpoints are written atomically (a reader sees the old file or the complete new one), but a
training job prunes old ones: between reading ``deepracer_checkpoints.json`` and opening the file,
the named checkpoint may be deleted. :func:`open_checkpoint` opens the file (an open file stays
readable after it is deleted) and re-reads the index if it vanished first.
"""

from __future__ import annotations

from typing import BinaryIO

from laplab.store.atomic import CorruptFileError
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import ModelFolder

_ATTEMPTS = 5


def open_checkpoint(folder: ModelFolder, which: str = "best") -> tuple[str, BinaryIO]:
    """``(file name, open binary file)`` of checkpoint ``which`` ('best', 'last' or a file name)."""
    store = CheckpointStore(folder)
    for attempt in range(_ATTEMPTS):
        path = store.resolve(which)
        try:
            return path.name, open(path, "rb")  # noqa: SIM115 - the caller closes it
        except FileNotFoundError:
            if attempt == _ATTEMPTS - 1 or which not in ("best", "last"):
                raise
    raise AssertionError("unreachable")


def load_state(handle: BinaryIO, name: str, where: str) -> dict:
    """The checkpoint dict in ``handle``; a damaged file raises :class:`CorruptFileError` naming it."""
    import torch
    try:
        state = torch.load(handle, map_location="cpu", weights_only=True)  # tensors and plain data: no code runs
    except Exception as exc:  # noqa: BLE001 - truncated zip, bad pickle, foreign file ...
        reason = " ".join(str(exc).split())[:200]
        raise CorruptFileError(f"checkpoint {where!r} is damaged and cannot be read ({type(exc).__name__}: "
                               f"{reason}); it may have been cut short by a full disk or an unfinished copy. "
                               f"Choose another checkpoint (--checkpoint last, or a file name from model/).") from None
    if not isinstance(state, dict) or "learner" not in state:
        raise CorruptFileError(f"checkpoint {where!r} is not a laplab checkpoint (no 'learner' state).")
    return state


def read_checkpoint(folder: ModelFolder, which: str = "best") -> tuple[str, dict]:
    """``(file name, state)`` of checkpoint ``which`` of ``folder``; see :func:`open_checkpoint`."""
    name, handle = open_checkpoint(folder, which)
    with handle:
        return name, load_state(handle, name, str(folder.model_dir / name))


def read_resume_state(folder: ModelFolder) -> tuple[str, dict]:
    """``(file name, state)`` of the last checkpoint with its resume state (optimizers, targets) folded
    in when the folder has it; without it (an imported model, an older folder) the state holds what the
    checkpoint holds and the learner starts fresh optimizers."""
    from laplab.train.checkpoint_state import merge_resume_state
    name, state = read_checkpoint(folder, "last")
    resume_path = CheckpointStore(folder).resume_path(name)
    try:
        handle = open(resume_path, "rb")  # noqa: SIM115 - closed below
    except FileNotFoundError:
        return name, state
    with handle:
        try:
            import torch

            from laplab.train.resume_codec import unpack_state
            resume = unpack_state(torch.load(handle, map_location="cpu", weights_only=True))
        except ImportError as exc:
            raise CorruptFileError(f"resume state {str(resume_path)!r} needs the {exc.name!r} package to be read: "
                                   f'install laplab\'s train extra (pip install -e ".[train]").') from None
        except Exception as exc:  # noqa: BLE001 - a damaged file: say which, resume from the weights
            raise CorruptFileError(f"resume state {str(resume_path)!r} is damaged ({type(exc).__name__}); delete it "
                                   f"to resume from the checkpoint's weights with fresh optimizers.") from None
    return name, merge_resume_state(state, resume)
