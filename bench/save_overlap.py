"""Does writing a checkpoint on the model folder's writer thread overlap with learning on this machine?

The main thread runs camera PPO gradient steps (the console's network, a batch of 64 frames); a
second thread writes one iteration's checkpoint and resume state on the model folder's writer
thread (``laplab.train.background.BackgroundListeners``, at its lower priority). Prints the learning alone, the write alone, the two one after the
other and the two overlapped (wall seconds). On 2 busy cores overlapped is about sequential; with
idle cores it approaches the learning alone.

Usage:
  python bench/save_overlap.py [--steps 12] [--trials 2]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=12, help="gradient steps timed per trial")
    parser.add_argument("--trials", type=int, default=2)
    args = parser.parse_args()
    import torch

    from camera_steps import ROWS, console_metadata  # bench/camera_steps.py
    from laplab.store.atomic import atomic_write_with
    from laplab.train.background import BackgroundListeners
    from laplab.train.config import TrainConfig
    from laplab.train.trainer import build_learner, checkpoint_writer, resume_writer

    config = replace(TrainConfig(), model_metadata=console_metadata(*ROWS["ppo-discrete"]))
    learner = build_learner(config, 0)
    for parameter in learner.model.parameters():  # one step, so that Adam's moments exist
        parameter.grad = torch.randn_like(parameter) * 1e-3
    learner.optimizer.step()
    frames = torch.randn(64, *config.spec.observation_space.shape)

    def learn(steps: int) -> None:
        for _ in range(steps):
            outputs = learner.model(frames)
            loss = sum(getattr(out, "logits", out).float().sum() for out in outputs)
            learner.optimizer.zero_grad()
            loss.backward()
            learner.optimizer.step()

    def write() -> None:
        folder = tempfile.mkdtemp(prefix="laplab-save-overlap-")
        weights, resume = checkpoint_writer(learner, 1, 1, 1, None), resume_writer(learner)
        atomic_write_with(os.path.join(folder, "checkpoint"), weights)
        atomic_write_with(os.path.join(folder, "resume"), resume)

    class CheckpointWriter:
        def on_checkpoint(self, _) -> None:
            write()

    learn(2)  # warm-up
    for _ in range(args.trials):
        started = time.perf_counter()
        learn(args.steps)
        alone = time.perf_counter() - started
        started = time.perf_counter()
        write()
        solo = time.perf_counter() - started
        started = time.perf_counter()
        writer = BackgroundListeners([CheckpointWriter()])  # as the trainer's model folder writer runs
        writer.on_checkpoint(None)
        learn(args.steps)
        writer.close()
        both = time.perf_counter() - started
        print(f"learn alone {alone:.2f} s, write alone {solo:.2f} s, one after the other {alone + solo:.2f} s, "
              f"overlapped {both:.2f} s; load average {os.getloadavg()[0]:.1f}", flush=True)


if __name__ == "__main__":
    main()
