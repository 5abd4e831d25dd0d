"""A DeepRacer SAC checkpoint as deepracer-simapp writes it imports: the policy weight for weight (its
outputs equal TensorFlow's on the same frames), the critics fresh, and the model clones and trains on.

The checkpoint is built here with TensorFlow the way rl_coach builds the simapp's three SAC networks
(``policy``, ``q``, ``v``). The head's unnamed dense layers are named as ``tf.compat.v1.layers.dense``
names them (Keras 3 removed it; its naming was ``variable_scope(name, default_name="dense")``, kept
here), so ``dense``, ``policy_mean``, ``dense_1`` are TensorFlow's own counter's, not laplab's.
The embedders' names (``Conv2d_0`` ...) are those of a real console checkpoint (test_deepracer_import).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch", reason="the import writes a laplab (torch) checkpoint")
tf = pytest.importorskip("tensorflow", reason="the checkpoint is written with tensorflow-cpu")

from export_networks import varied_observations  # noqa: E402

from laplab.env.metadata import ModelMetadata  # noqa: E402
from laplab.export.deepracer_import import import_deepracer_model  # noqa: E402
from laplab.export.policy_layers import policy_layers, reference_output  # noqa: E402
from laplab.train.config import TrainConfig  # noqa: E402
from laplab.train.policy import load_model_policy  # noqa: E402
from laplab.train.trainer import build_learner  # noqa: E402

ROOT = "main_level/agent"
CONTINUOUS = {"steering_angle": {"low": -30.0, "high": 30.0}, "speed": {"low": 0.5, "high": 3.0}}
METADATA = {**ModelMetadata().to_dict(), "version": "5", "sensor": ["FRONT_FACING_CAMERA"],
            "training_algorithm": "sac", "action_space_type": "continuous", "action_space": CONTINUOUS}
FRAMES = 16


def _embedder_shapes(config: TrainConfig) -> tuple[list[tuple[int, ...]], list[int], list[int]]:
    """(conv kernel shapes, conv strides, middleware widths) of the metadata's network."""
    learner = build_learner(config, 0, precision="float32")
    layers = policy_layers(learner.policy_network, config.spec.observation_space, list(config.metadata().sensors))
    (camera,) = layers.branches
    return ([conv.kernel.shape for conv in camera.convs], [conv.stride for conv in camera.convs],
            [dense.kernel.shape[1] for dense in layers.middleware])


def float32_rounding(policy, outputs: np.ndarray) -> float:
    """How far torch's float32 outputs may sit from an exact (float64) evaluation: each layer's sum of
    fan-in terms rounds like a random walk, eps * sqrt(fan-in), the layers' errors add, on the outputs'
    scale. A weight off by an optimizer step (2e-5 here) is 10x outside it."""
    layers = policy_layers(policy.network, policy.observation_space, list(policy.metadata.sensors))
    weights = [*layers.branches[0].convs, *layers.middleware, *layers.head_hidden, layers.head]
    walk = sum(np.sqrt(np.prod(w.kernel.shape[:-1])) for w in weights)
    return float(np.finfo(np.float32).eps * walk * np.abs(outputs).max())


def _dense(x, units: int, activation=None, name: str | None = None):
    """``tf.compat.v1.layers.dense``: variables ``kernel`` (in, out) and ``bias`` in scope ``name``, or
    TensorFlow's next free ``dense``, ``dense_1``... of the enclosing scope when ``name`` is None."""
    with tf.compat.v1.variable_scope(name, default_name="dense"):
        kernel = tf.compat.v1.get_variable("kernel", [int(x.shape[-1]), units],
                                           initializer=tf.compat.v1.glorot_uniform_initializer())
        bias = tf.compat.v1.get_variable("bias", [units], initializer=tf.compat.v1.random_normal_initializer(0, 0.1))
        y = tf.nn.bias_add(tf.matmul(x, tf.cast(kernel, tf.float64)), tf.cast(bias, tf.float64))
    return y if activation is None else activation(y)


def _camera(x, kernels, strides):
    """rl_coach's image embedder: 0-255 grey levels scaled to [0, 1], 'valid' convolutions + relu
    named Conv2d_0, Conv2d_2, ... (its activation layers take the odd numbers), flattened (H, W, C)."""
    x = x / 255.0
    with tf.compat.v1.variable_scope("FRONT_FACING_CAMERA"):
        for index, (shape, stride) in enumerate(zip(kernels, strides)):
            with tf.compat.v1.variable_scope(f"Conv2d_{2 * index}"):
                kernel = tf.compat.v1.get_variable("kernel", shape,
                                                   initializer=tf.compat.v1.glorot_uniform_initializer())
                bias = tf.compat.v1.get_variable("bias", [shape[3]],
                                                 initializer=tf.compat.v1.random_normal_initializer(0, 0.1))
            x = tf.nn.conv2d(x, tf.cast(kernel, tf.float64), [1, stride, stride, 1], "VALID")
            x = tf.nn.relu(tf.nn.bias_add(x, tf.cast(bias, tf.float64)))
    return tf.reshape(x, [-1, int(np.prod(x.shape[1:]))])


def _head_input(x):
    """rl_coach's head input: ``(1 - r) * stop_gradient(x) + r * x`` with the trainable rescaler ``r``
    (1.0): the features themselves, whatever an optimizer does to ``r``."""
    rescaler = tf.cast(tf.compat.v1.get_variable("gradients_from_head_0-0_rescalers", [],
                                                 initializer=tf.ones_initializer()), tf.float64)
    return (1 - rescaler) * tf.stop_gradient(x) + rescaler * x


def simapp_sac_checkpoint(folder: Path, config: TrainConfig, prefix: str = "4_Step-2400.ckpt", seed: int = 7):
    """rl_coach's SAC graph (deepracer-simapp's SACPolicyHead, SACQHead, VHead) saved to
    ``folder/prefix``, and its policy frozen to ``folder/model.pb``; returns (the names saved, a
    function frames (B, H, W, C) -> tanh(policy mean)).
    The variables are float32, as rl_coach's; the graph computes in float64, so the reference is exact
    (TensorFlow's float32 kernels round 100x more than torch's on AVX512-BF16 hosts: 2e-5 here)."""
    kernels, strides, middleware = _embedder_shapes(config)
    actions = 2
    graph = tf.Graph()
    with graph.as_default():
        tf.compat.v1.set_random_seed(seed)
        frames = tf.compat.v1.placeholder(tf.float64, [None, 120, 160, 1], name="frames")
        with tf.compat.v1.variable_scope(f"{ROOT}/policy/online/network_0"):
            x = _camera(frames, kernels, strides)
            with tf.compat.v1.variable_scope("middleware_fc_embedder"):
                for index, width in enumerate(middleware):
                    x = _dense(x, width, tf.nn.relu, name=f"Dense_{2 * index}")
            x = _head_input(x)
            with tf.compat.v1.variable_scope("sac_policy_head_0"):
                hidden = _dense(x, 256, tf.nn.relu)  # unnamed, as the simapp's
                mean = tf.identity(_dense(hidden, actions, name="policy_mean"), name="policy")
                squashed = tf.tanh(mean)  # what the car drives: scale * tanh(mean) + bias in the model's units
                log_std = tf.clip_by_value(_dense(hidden, actions), -20, 2)
        policy_loss = tf.reduce_mean(mean ** 2) + tf.reduce_mean(log_std)
        with tf.compat.v1.variable_scope(f"{ROOT}/q/online/network_0"):  # no middleware; actions join the head
            features = _head_input(_camera(frames, kernels, strides))
            taken = tf.compat.v1.placeholder(tf.float64, [None, actions], name="actions")
            with tf.compat.v1.variable_scope("q_values_head_0"):
                for head in ("q1", "q2"):
                    with tf.compat.v1.variable_scope(f"{head}_head"):
                        q = tf.concat([features, taken], -1)
                        for _ in range(2):
                            q = _dense(q, 256, tf.nn.relu)
                        _dense(q, 1, name=f"{head}_output")
        for scope in ("online", "target"):
            with tf.compat.v1.variable_scope(f"{ROOT}/v/{scope}/network_0"):
                x = _camera(frames, kernels, strides)
                with tf.compat.v1.variable_scope("middleware_fc_embedder"):
                    for index, width in enumerate(middleware):
                        x = _dense(x, width, tf.nn.relu, name=f"Dense_{2 * index}")
                with tf.compat.v1.variable_scope("v_values_head_0"):
                    _dense(_head_input(x), 1, name="output")
        train = tf.compat.v1.train.AdamOptimizer(1e-4).minimize(policy_loss)  # optimizer slots in the file too
        saver = tf.compat.v1.train.Saver(max_to_keep=None)
        session = tf.compat.v1.Session(graph=graph)
        session.run(tf.compat.v1.global_variables_initializer())
        session.run(train, {frames: np.random.default_rng(seed).uniform(0, 255, (4, 120, 160, 1))})
        saver.save(session, str(folder / prefix), write_meta_graph=False, write_state=False)
        names = [name for name, _ in tf.train.list_variables(str(folder / prefix))]
        frozen = tf.compat.v1.graph_util.convert_variables_to_constants(  # the car's model.pb, frozen as
            session, graph.as_graph_def(), [mean.op.name])                  # DeepRacer freezes it
        (folder / "model.pb").write_bytes(frozen.SerializeToString())
    return names, lambda batch: session.run(squashed, {frames: batch})


def model_folder_of(tmp_path: Path, config: TrainConfig) -> tuple[Path, list[str], object]:
    folder = tmp_path / "sac-simapp"
    (folder / "model").mkdir(parents=True)
    (folder / "ip").mkdir()
    names, run = simapp_sac_checkpoint(folder / "model", config)
    (folder / "model" / ".coach_checkpoint").write_text("4_Step-2400.ckpt")
    (folder / "model_metadata.json").write_text(json.dumps(METADATA))
    (folder / "ip" / "hyperparameters.json").write_text(json.dumps({**config.hyper().to_dict(), "batch_size": 32}))
    (folder / "reward_function.py").write_text("def reward_function(params):\n    return 1.0\n")
    return folder, names, run


@pytest.fixture(scope="module")
def simapp(tmp_path_factory):
    config = TrainConfig(model_metadata=METADATA)
    return model_folder_of(tmp_path_factory.mktemp("simapp"), config)


@pytest.fixture
def home(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    return tmp_path / "home"


def test_tensorflow_names_the_simapp_head_as_laplab_reads_it(simapp):
    _, names, _ = simapp
    head = f"{ROOT}/policy/online/network_0/sac_policy_head_0"
    assert {f"{head}/dense/kernel", f"{head}/policy_mean/kernel", f"{head}/dense_1/kernel"} <= set(names)
    assert f"{ROOT}/q/online/network_0/q_values_head_0/q1_head/q1_output/kernel" in names
    assert any(name.endswith("/Adam") for name in names)


def test_simapp_sac_checkpoint_imports_with_its_policy_exact(home, simapp):
    folder, _, run = simapp
    imported = import_deepracer_model(folder, "sac-simapp")
    assert imported.trainable and imported.source_checkpoint == "4_Step-2400.ckpt"
    assert any("critics (Q networks) start fresh" in note for note in imported.notes)
    policy = load_model_policy("sac-simapp")
    assert policy.config.policy_head_layers == (256,)
    frames = varied_observations(policy.observation_space, FRAMES, seed=3)
    got = reference_output(policy.network, frames)
    expected = run(np.transpose(frames, (0, 2, 3, 1)).astype(np.float64))
    assert np.ptp(expected, axis=0).max() > 1e-3  # the outputs differ between frames: the check means something
    assert np.abs(got - expected).max() <= float32_rounding(policy, expected)  # 1.1e-7 measured, bound 2e-6


def test_simapp_sac_model_pb_imports_its_policy(home, simapp, tmp_path):
    folder, _, run = simapp
    car = tmp_path / "car"
    car.mkdir()
    (car / "model.pb").write_bytes((folder / "model" / "model.pb").read_bytes())  # log-std pruned by the freeze
    (car / "model_metadata.json").write_text(json.dumps(METADATA))
    imported = import_deepracer_model(car / "model.pb", "sac-car")
    assert not imported.trainable
    policy = load_model_policy("sac-car")
    assert policy.config.policy_head_layers == (256,)
    frames = varied_observations(policy.observation_space, FRAMES, seed=3)
    expected = run(np.transpose(frames, (0, 2, 3, 1)).astype(np.float64))
    assert np.abs(reference_output(policy.network, frames) - expected).max() <= float32_rounding(policy, expected)


def test_car_graph_of_an_imported_simapp_sac_is_the_simapps_model_pb(home, simapp, tmp_path):
    """laplab's car export of a DeepRacer SAC model holds what DeepRacer's own model.pb holds under
    sac_policy_head_0/policy: the mean before tanh (the car clips it to [-1, 1]), not laplab's tanh."""
    from laplab.export.car import build_car_graph
    from laplab.export.tensorflow_graph import FrozenGraph, graph_feed, output_node_name
    folder, _, run = simapp
    import_deepracer_model(folder, "sac-simapp")
    policy = load_model_policy("sac-simapp")
    frames = varied_observations(policy.observation_space, FRAMES, seed=3)
    simapp_graph = FrozenGraph((folder / "model" / "model.pb").read_bytes(), output_node_name("sac"))
    simapp_node = simapp_graph.run({"frames": np.transpose(frames, (0, 2, 3, 1)).astype(np.float64)})
    assert np.abs(np.tanh(simapp_node) - run(np.transpose(frames, (0, 2, 3, 1)).astype(np.float64))).max() < 1e-12
    car = build_car_graph("sac-simapp")
    got = FrozenGraph(car.data, output_node_name("sac")).run(graph_feed(car.layers, frames))
    tolerance = 10 * float32_rounding(policy, simapp_node)  # TensorFlow's float32 kernels round more than torch's
    assert np.abs(got - simapp_node).max() <= tolerance
    assert np.abs(np.tanh(got) - simapp_node).max() > 5 * tolerance  # a tanh'd node (laplab before) fails
    (tmp_path / "car").mkdir()  # and that model.pb imports back as the same policy
    (tmp_path / "car" / "model.pb").write_bytes(car.data)
    (tmp_path / "car" / "model_metadata.json").write_text(json.dumps(METADATA))
    import_deepracer_model(tmp_path / "car" / "model.pb", "sac-car-again")
    again = load_model_policy("sac-car-again")
    assert again.config.policy_head_layers == (256,)
    assert np.abs(reference_output(again.network, frames) - reference_output(policy.network, frames)).max() <= 1e-6


def test_imported_simapp_sac_exports_and_imports_back(home, simapp, tmp_path):
    from laplab.export.console import export_console
    import_deepracer_model(simapp[0], "sac-simapp")
    again = export_console("sac-simapp", out=tmp_path / "again").folder
    import_deepracer_model(again, "sac-again")
    a, b = load_model_policy("sac-simapp"), load_model_policy("sac-again")
    sa, sb = a.network.state_dict(), b.network.state_dict()
    assert "head.0.weight" in sa and sa.keys() == sb.keys()
    assert all(np.array_equal(sa[key].numpy(), sb[key].numpy()) for key in sa)


def test_imported_simapp_sac_clones_and_trains_on(home, simapp):
    import torch

    from laplab.train.jobs import clone_config
    import_deepracer_model(simapp[0], "sac-simapp")
    config, weights = clone_config("sac-simapp", {}, trust_reward=True)
    assert config.policy_head_layers == (256,) and config.spec.policy_head_layers == (256,)
    learner = build_learner(config, 0, precision="float32")
    learner.load_weights(weights)
    assert not learner.shared_trunk  # the imported policy keeps its own trunk
    before = {k: v.clone() for k, v in learner.actor.state_dict().items()}
    space = config.spec.observation_space
    rng = np.random.default_rng(0)
    count = learner.hyperparameters.batch_size
    obs = varied_observations(space, count, seed=1)
    learner.observe(obs, rng.uniform(-1, 1, (count, 2)).astype(np.float32), rng.normal(size=count).astype(np.float32),
                    varied_observations(space, count, seed=2), np.zeros(count, bool))
    stats = learner.update(2)
    assert stats["num_gradient_steps"] == 2 and np.isfinite(stats["critic_loss"])
    after = learner.actor.state_dict()
    assert not torch.equal(before["head.0.weight"], after["head.0.weight"])  # the policy head learns


def test_policy_head_layers_belong_to_sac():
    from laplab.train.config import ConfigError
    with pytest.raises(ConfigError, match="policy_head_layers"):
        TrainConfig(policy_head_layers=(256,))  # a PPO model
    with pytest.raises(ConfigError, match="policy_head_layers"):
        TrainConfig(model_metadata=METADATA, policy_head_layers=(0,))
    config = TrainConfig(model_metadata=METADATA, policy_head_layers=[256])
    assert TrainConfig.from_dict(config.to_dict()).policy_head_layers == (256,)
    assert replace(config, policy_head_layers=()).spec.policy_head_layers == ()
