"""A real DeepRacer ``model.pb`` (not one laplab froze) imports and drives.

The model is third-party and never in this repository: ``LAPLAB_REAL_MODEL_PB`` names the file
(e.g. deepracer-utils' test model ``tests/deepracer/model/sample-model/model/model_48.pb``, a
front-camera clipped-PPO model of 12 discrete actions, with its ``model_metadata.json`` in the same
folder); without it, the copy `.ci/run` fetches from deepracer-utils' sdist on PyPI into
``~/.cache/laplab-test-data``; the tests skip when neither is there. Checked: the import reads every weight from the graph's
constants, laplab's network gives the graph's own action probabilities (TensorFlow runs the graph),
and the imported model completes a lap in laplab's simulator."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch", reason="the import writes a laplab (torch) checkpoint")

# .ci/run fetches deepracer-utils' sample model (its sdist on PyPI) into this cache and sets the variable
CACHED_PB = (Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "laplab-test-data"
             / "deepracer-utils-1.5.6" / "sample-model" / "model" / "model_48.pb")
REAL_PB = Path(os.environ.get("LAPLAB_REAL_MODEL_PB") or CACHED_PB)
pytestmark = pytest.mark.skipif(not REAL_PB.is_file() or not (REAL_PB.parent / "model_metadata.json").is_file(),
                                reason="set LAPLAB_REAL_MODEL_PB to a DeepRacer model.pb with its model_metadata.json")
EPS32 = float(np.finfo(np.float32).eps)


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    from laplab.export.deepracer_import import import_deepracer_model
    home = tmp_path_factory.mktemp("real-pb-home")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("LAPLAB_HOME", str(home))
        result = import_deepracer_model(REAL_PB, "real-pb")
    return home, result


def test_the_real_model_pb_gives_the_graphs_own_outputs(imported, monkeypatch):
    tf = pytest.importorskip("tensorflow")
    from export_networks import varied_observations

    from laplab.export.policy_layers import policy_layers, reference_output
    from laplab.export.tensorflow_graph import FrozenGraph, graph_feed, output_node_name
    from laplab.train.policy import load_model_policy

    home, result = imported
    assert not result.trainable and any("frozen model.pb" in note for note in result.notes)
    monkeypatch.setenv("LAPLAB_HOME", str(home))
    policy = load_model_policy("real-pb")
    layers = policy_layers(policy.network, policy.observation_space, list(policy.metadata.sensors))
    graph = FrozenGraph(REAL_PB.read_bytes(), output_node_name(layers.algorithm))
    frames = varied_observations(policy.observation_space, 32, seed=4)
    feed = graph_feed(layers, frames)
    (node,) = [name for name in graph.placeholders if name.endswith(tuple(f"/{s}" for s in policy.metadata.sensors))]
    expected = graph.run({node: next(iter(feed.values()))})
    got = reference_output(policy.network, frames)
    assert expected.shape == got.shape and np.ptp(expected, axis=0).max() > 1e-3
    # TensorFlow's float32 kernels round more than torch's (2e-5 on AVX512-BF16 hosts): a bound from the
    # network's depth (eps * sum of sqrt(fan-in)), far below what one wrong weight does
    weights = [*layers.branches[0].convs, *layers.branches[0].dense, *layers.middleware, layers.head]
    bound = EPS32 * sum(np.sqrt(np.prod(w.kernel.shape[:-1])) for w in weights)
    assert np.abs(got - expected).max() <= bound
    assert tf is not None


def test_the_real_model_pb_drives_a_lap(imported, monkeypatch):
    from laplab.evaluate.trials import EvaluationSettings, evaluate_model

    home, _ = imported
    monkeypatch.setenv("LAPLAB_HOME", str(home))
    result, _ = evaluate_model("real-pb", EvaluationSettings(trials=1, max_trial_time=300.0))
    assert result.summary.completed == 1, result.to_dict()["summary"]
