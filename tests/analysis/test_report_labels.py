"""What the report says of a model: its network as built, captions of its algorithm, no empty legends,
and the model a clone came from."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from laplab.analysis import plots
from laplab.analysis.report import losses_caption, network_text


def test_a_state_model_is_labelled_as_the_mlp_it_is():
    state = {"sensor": ["STATE"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"}
    assert network_text(state).startswith("MLP") and "STATE" in network_text(state)
    lidar = {"sensor": ["SECTOR_LIDAR"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK"}
    assert network_text(lidar).startswith("MLP")
    camera = {"sensor": ["FRONT_FACING_CAMERA"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"}
    assert network_text(camera) == "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"


def test_sac_captions_speak_of_sac():
    sac = losses_caption("sac")
    assert "SAC" in sac and "PPO" not in sac and "critic" in sac
    assert "PPO" in losses_caption("clipped_ppo") and "SAC" not in losses_caption("clipped_ppo")


def test_empty_legends_are_dropped(tmp_path):
    figure = Figure()
    ax = figure.subplots()
    ax.plot(np.arange(3), np.arange(3))  # no label
    ax.legend(handles=[])  # what a filtered legend call makes when nothing was kept
    assert ax.get_legend() is not None
    plots._save(figure, tmp_path / "f.png", plots.PlotStyle())
    assert ax.get_legend() is None and (tmp_path / "f.png").stat().st_size > 0
