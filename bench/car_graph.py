"""The car's toolchain end to end: a FRONT_FACING_CAMERA model trained for a short while, exported to
the car's ``model.pb`` (``laplab export --format car``), converted by OpenVINO with the inputs the car's
model optimizer passes, and driven in laplab's simulator through OpenVINO inference, against the same
model driven by its torch policy.

Also writes the console's TensorFlow checkpoint of the model (``--format console``) and prints its
size and the time to write, restore and check it. Prints, for both drivers: laps completed out of the trials and each lap time; the share of decisions
where OpenVINO picked the torch policy's action on the same frame; the OpenVINO inference latency
per frame (one frame per call, as the car runs it; single thread, median and 90th percentile); and
the same agreement (every 10th frame) for the FP16 model the car's ``--data_type FP16`` conversion makes.

Usage:
  python bench/car_graph.py [--max-time 120] [--trials 3] [--track classic_2018] [--seed 0] [--resets N]
                            [--max-trial-time 180]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from dataclasses import replace

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--max-time", type=float, default=120.0, help="training wall time, s (default 120)")
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--track", default="classic_2018")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resets", type=int, default=None, help="resets per trial (default: unlimited, the console's)")
    parser.add_argument("--max-trial-time", type=float, default=180.0, help="s of simulated time per trial (180)")
    args = parser.parse_args()
    os.environ.setdefault("LAPLAB_HOME", tempfile.mkdtemp(prefix="laplab-car-bench-"))

    from laplab.env.metadata import ModelMetadata
    from laplab.evaluate.trials import EvaluationSettings, evaluate_policy
    from laplab.export.car import build_car_graph
    from laplab.export.console import console_checkpoint
    from laplab.export.openvino_model import OpenVinoPolicy, car_optimizer_inputs
    from laplab.export.policy_layers import policy_layers
    from laplab.export.tensorflow_graph import graph_feed
    from laplab.track.registry import load_track
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    from laplab.train.policy import load_model_policy
    from laplab.vehicle.params import vehicle_preset

    name = "car-bench"
    metadata = replace(ModelMetadata(), sensors=("FRONT_FACING_CAMERA",)).to_dict()
    config = replace(TrainConfig(), track=args.track, seed=args.seed, max_time_s=args.max_time, model_metadata=metadata)
    started = time.perf_counter()
    result = create_training(name, config).run()
    print(f"trained {name}: {result.iterations} iterations, {result.episodes} episodes, {result.env_steps} steps "
          f"in {time.perf_counter() - started:.0f} s ({args.track}, FRONT_FACING_CAMERA, {config.model_metadata.neural_network})")

    started = time.perf_counter()
    graph = build_car_graph(name)
    pb = os.path.join(os.environ["LAPLAB_HOME"], "model.pb")
    with open(pb, "wb") as handle:
        handle.write(graph.data)
    export_s = time.perf_counter() - started
    policy = load_model_policy(name)
    sensors = list(policy.metadata.sensors)
    inputs = car_optimizer_inputs(sensors, policy.metadata.training_algorithm)
    started = time.perf_counter()
    openvino = OpenVinoPolicy(pb, inputs)
    convert_s = time.perf_counter() - started
    fp16 = OpenVinoPolicy(pb, inputs, fp16=True)
    layers = policy_layers(policy.network, policy.observation_space, sensors)
    print(f"model.pb {len(graph.data) / 1e6:.1f} MB from {graph.checkpoint} in {export_s:.1f} s "
          f"(max |TF - torch| {graph.parity_error:.1e}); OpenVINO convert + compile {convert_s:.1f} s")
    started = time.perf_counter()
    checkpoint, checkpoint_error = console_checkpoint(graph)
    print(f"console's TensorFlow checkpoint ({', '.join(sorted(checkpoint))}): "
          f"{sum(map(len, checkpoint.values())) / 1e6:.1f} MB written, restored and checked in "
          f"{time.perf_counter() - started:.1f} s (max |checkpoint - model.pb| {checkpoint_error:.1e})")

    latencies, checked16, agree, decisions = [], [], 0, 0
    discrete = policy.metadata.action_space.kind == "discrete"

    def drive_openvino(observations):
        nonlocal agree, decisions
        feed = graph_feed(layers, observations)
        outputs = []
        for row in range(next(iter(feed.values())).shape[0]):
            one = {key: value[row:row + 1] for key, value in feed.items()}
            t0 = time.perf_counter()
            outputs.append(openvino.run(one))
            latencies.append(time.perf_counter() - t0)
            if discrete and decisions % 10 == 0:  # the FP16 model on every 10th frame
                checked16.append(int(fp16.run(one).argmax() == outputs[-1].argmax()))
            decisions += 1
        output = np.concatenate(outputs)
        actions = output.argmax(axis=1) if discrete else np.clip(output, -1.0, 1.0)
        reference = policy.act(observations)
        agree += int(np.sum(actions == reference)) if discrete else int(np.sum(np.abs(actions - reference).max(axis=1) < 1e-3))
        return actions

    track = load_track(config.track)
    settings = EvaluationSettings(trials=args.trials, seed=args.seed, resets=args.resets,
                                  max_trial_time=args.max_trial_time)
    vehicle = vehicle_preset(policy.config.car)
    runs = {"torch": evaluate_policy(policy, track, settings),
            "OpenVINO": evaluate_policy(drive_openvino, track, settings, spec=policy.spec, vehicle=vehicle)}
    for label, run in runs.items():
        laps = [t.lap_time for t in run.trials if t.status == "lap_complete"]
        shown = ", ".join(f"{t.lap_time:.3f} s" if t.lap_time is not None else f"{t.status} at {t.completion:.1f} %"
                          for t in run.trials)
        print(f"{label:>8}: {len(laps)}/{len(run.trials)} laps: {shown}")
    torch_laps = [t.lap_time for t in runs["torch"].trials]
    ov_laps = [t.lap_time for t in runs["OpenVINO"].trials]
    gaps = [abs(a - b) / a for a, b in zip(torch_laps, ov_laps) if a is not None and b is not None]
    if gaps:
        print(f"lap time difference OpenVINO vs torch: max {100 * max(gaps):.3f} %")
    print(f"OpenVINO chose the torch policy's action on {agree}/{decisions} frames "
          f"({100 * agree / max(decisions, 1):.2f} %)" + (f"; FP16 model: same argmax as FP32 on {sum(checked16)}/{len(checked16)}"
                                                          if discrete else ""))
    ms = sorted(1000 * t for t in latencies)
    print(f"OpenVINO inference latency per frame (1 thread, batch 1): median {statistics.median(ms):.2f} ms, "
          f"p90 {ms[int(0.9 * (len(ms) - 1))]:.2f} ms over {len(ms)} frames")


if __name__ == "__main__":
    main()
