"""A trusted warm-up of numba's compiled-code cache, copied into each user's job cache.

Jobs keep numba's cache per user (the cache is code: a shared one would let one user's job plant
code in another's). A new user's first job would then compile every kernel (tens of seconds). The
server runs this module once per ``$LAPLAB_HOME`` with laplab's own code only (two-episode
trainings with the default reward in a scratch folder, a STATE model and a front-camera one, about
a minute on 2 cores) and seeds each new user's cache from it: their first job, camera models' included,
starts without compiling (a first camera job spent ~11 s of its start compiling the camera's kernels).

``python -m laplab.jobs.warmup CACHE_DIR`` (with ``NUMBA_CACHE_DIR=CACHE_DIR``).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

READY_MARKER = "laplab-warmup-done"


def trusted_cache(home: Path) -> Path:
    return home / "sandbox" / "trusted-numba"


def seed(target: Path, home: Path) -> bool:
    """Copy the trusted cache into ``target`` (a user's numba cache) if that does not exist yet."""
    source = trusted_cache(home)
    if target.exists() or not (source / READY_MARKER).exists():
        return False
    staging = target.with_name(target.name + ".seeding")
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copytree(source, staging)
    try:
        staging.rename(target)
    except OSError:
        shutil.rmtree(staging, ignore_errors=True)
    return True


def start_warmup(home: Path) -> subprocess.Popen | None:
    """Start the warm-up in the background unless it is done (returns the process, or None)."""
    from laplab.jobs.confinement import clean_environment
    cache = trusted_cache(home)
    if (cache / READY_MARKER).exists():
        return None
    cache.mkdir(parents=True, exist_ok=True)
    env = clean_environment({"NUMBA_CACHE_DIR": str(cache)}, sandboxed=False)
    return subprocess.Popen([sys.executable, "-m", "laplab.jobs.warmup", str(cache)], env=env,
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


def main(argv: list[str] | None = None) -> int:
    from dataclasses import replace

    from laplab.settings import Settings, use_settings
    cache = Path((argv or sys.argv[1:])[0])
    with tempfile.TemporaryDirectory(prefix="laplab-warmup-") as scratch, use_settings(Settings.at(scratch)):
        from laplab.train.config import TrainConfig
        from laplab.train.jobs import create_training
        tiny = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}
        camera = TrainConfig(model_metadata={"sensor": ["FRONT_FACING_CAMERA"]})
        for name, config in (("warmup", TrainConfig()), ("warmup-camera", camera)):
            config = replace(config, max_episodes=2, max_time_s=600.0,
                             hyperparameters={**config.hyper().to_dict(), **tiny})
            with create_training(name, config) as trainer:  # its lock is released before the folder goes
                trainer.run()
    (cache / READY_MARKER).write_text("ok\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
