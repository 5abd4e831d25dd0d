"""Fixtures of the export tests: each policy of :data:`export_networks.CASES` is built once per
session, with its TensorFlow graph, a set of varied observations and the torch reference outputs on
them, and shared by the graph, OpenVINO and checkpoint tests (each rebuilt them before)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest


@dataclass
class BuiltCase:
    """One case: the torch ``model`` and its observation ``space``, laplab's ``layers``, the frozen
    graph (``graph_path``, model.pb), ``observations`` (SAMPLES of them) and the torch policy's
    ``expected`` outputs on them, (SAMPLES, actions), as the graph's output node holds them (SAC:
    the mean before tanh); :meth:`frozen` loads the graph in TensorFlow."""

    model: object
    space: object
    layers: object
    graph_path: Path
    observations: object
    expected: object
    _frozen: tuple | None = None

    def frozen(self, output_node: str):
        """(the FrozenGraph of model.pb, its (SAMPLES, actions) outputs on ``observations``), made once."""
        if self._frozen is None:
            from laplab.export.tensorflow_graph import FrozenGraph, graph_feed
            graph = FrozenGraph(self.graph_path.read_bytes(), output_node)
            self._frozen = graph, graph.run(graph_feed(self.layers, self.observations))
        return self._frozen


@pytest.fixture(scope="session")
def built_case(tmp_path_factory):
    """``built_case(case) -> BuiltCase``, built on first use and kept for the session."""
    from export_networks import SAMPLES, make_network, varied_observations
    from laplab.export.policy_layers import graph_reference_output, policy_layers
    from laplab.export.tensorflow_graph import graph_bytes

    cache: dict = {}

    def get(case) -> BuiltCase:
        if case not in cache:
            model, space = make_network(*case)
            layers = policy_layers(model, space, list(case[0]))
            path = tmp_path_factory.mktemp("graphs") / "model.pb"
            path.write_bytes(graph_bytes(layers))
            observations = varied_observations(space, SAMPLES, seed=11)
            cache[case] = BuiltCase(model, space, layers, path, observations,
                                   graph_reference_output(model, observations))
        return cache[case]
    return get


@pytest.fixture(scope="session")
def console_exports(tmp_path_factory):
    """``{name: folder}``: each model of :data:`deepracer_models.MODELS`, made in a $LAPLAB_HOME of its
    own and exported with ``laplab export --format console`` (TensorFlow needed); the environment is
    restored afterwards, so each test module imports into its own home. ``"home"``: that home."""
    pytest.importorskip("tensorflow", reason="the console export needs tensorflow-cpu")
    from deepracer_models import MODELS, make_model
    from laplab.export.console import export_console

    home = tmp_path_factory.mktemp("exported-home")
    out = tmp_path_factory.mktemp("console-exports")
    folders = {"home": home}
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("LAPLAB_HOME", str(home))
        for name, meta in MODELS.items():
            make_model(name, **meta)
            folders[name] = export_console(name, out=out / name).folder
    return folders
