"""Micro-benchmarks of camera training with the DeepRacer console's files: one collection step (the
observations of 20 cars, the policy, the simulator and reward) and one learning step (SAC: one
gradient step of batch_size; PPO: one minibatch), per algorithm and action space.

Prints milliseconds per call (median of ``--repeat`` timings) and env steps per second for a
collection step of 20 cars. Run it twice with different PYTHONPATHs (e.g. a checkout of an older
commit) to compare; on a shared machine interleave the runs and compare ratios.

Usage:
  python bench/camera_steps.py [--rows sac ppo-continuous ppo-discrete] [--repeat 20] [--precision auto]
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import time
from dataclasses import replace

CONSOLE_CONTINUOUS = {"action_space": {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 1, "high": 4}},
                      "action_space_type": "continuous"}
ROWS = {"sac": ("sac", CONSOLE_CONTINUOUS), "ppo-continuous": ("clipped_ppo", CONSOLE_CONTINUOUS),
        "ppo-discrete": ("clipped_ppo", None)}


def console_metadata(algorithm: str, action_space: dict | None) -> dict:
    """model_metadata.json as the console writes it: front camera, SHALLOW network."""
    from laplab.env.metadata import ModelMetadata
    metadata = replace(ModelMetadata(), sensors=("FRONT_FACING_CAMERA",),
                       neural_network="DEEP_CONVOLUTIONAL_NETWORK_SHALLOW").to_dict()
    metadata["training_algorithm"] = algorithm
    if action_space is not None:
        metadata.update(action_space)
    return metadata


def _median_ms(call, repeat: int) -> float:
    call()  # warm-up
    timings = []
    for _ in range(repeat):
        started = time.perf_counter()
        call()
        timings.append(time.perf_counter() - started)
    return 1000 * statistics.median(timings)


def measure(row: str, repeat: int, precision: str) -> dict:
    import numpy as np

    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training

    algorithm, action_space = ROWS[row]
    config = replace(TrainConfig(), model_metadata=console_metadata(algorithm, action_space), precision=precision,
                     max_time_s=60.0)
    trainer = create_training(f"bench-camera-{row}-{int(time.time() * 1000) % 10**8}", config)
    learner, hp = trainer.learner, trainer.hp
    trainer.sim.reset()
    policy = trainer._policy(False)

    def collect_step():
        obs = trainer.observations.observe()
        _, env_action, _, _ = policy(obs)
        trainer.stepper.step(env_action, trace=True)
        if not (trainer.sim.state.status == 0).any():
            trainer.sim.reset()

    collect_ms = _median_ms(collect_step, repeat)
    obs_space = trainer.spec.observation_space
    rng = np.random.default_rng(0)
    if algorithm == "sac":
        frames = 2000
        for _ in range(frames // 20):
            obs = trainer.observations.observe()
            step = learner.act(obs)
            learner.observe(obs, step.action, rng.random(20, dtype=np.float32), obs, np.zeros(20, np.float32))
        learn_ms = _median_ms(lambda: learner.update(1), repeat)
    else:
        batch = hp.batch_size
        obs = {k: rng.integers(0, 255, (batch, *s.shape), dtype=np.uint8) for k, s in obs_space.spaces.items()} \
            if hasattr(obs_space, "spaces") else rng.integers(0, 255, (batch, *obs_space.shape), dtype=np.uint8)
        step = learner.act(obs)
        import torch
        zeros = torch.zeros(batch)
        stream = getattr(learner, "value_stream", None)  # older learners (before session 11) have none
        with stream() if stream is not None else contextlib.nullcontext(None) as value_side:
            extra = () if value_side is None else (value_side,)
            learn_ms = _median_ms(lambda: learner._minibatch_step(obs, step.action, torch.as_tensor(step.log_prob),
                                                                  zeros, zeros, *extra), repeat)
    return {"collect_ms": collect_ms, "learn_ms": learn_ms, "collect_steps_s": 20 / (collect_ms / 1000),
            "precision": getattr(learner, "precision", "?")}


def main() -> None:
    import os
    import tempfile
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", nargs="+", default=list(ROWS), choices=list(ROWS))
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--precision", default="auto")
    args = parser.parse_args()
    os.environ.setdefault("LAPLAB_HOME", tempfile.mkdtemp(prefix="laplab-bench-"))
    print(f"{'row':16s} {'precision':9s} {'collect step ms':>15s} {'collect steps/s':>15s} {'learn step ms':>13s}")
    for row in args.rows:
        r = measure(row, args.repeat, args.precision)
        print(f"{row:16s} {r['precision']:9s} {r['collect_ms']:15.1f} {r['collect_steps_s']:15.0f} {r['learn_ms']:13.1f}")


if __name__ == "__main__":
    main()
