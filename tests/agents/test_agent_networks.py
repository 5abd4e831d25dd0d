"""DeepRacer's named networks: layer schemes, output shapes, multi-sensor inputs, policy heads."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from torch import nn

from laplab.agents import networks
from laplab.agents.networks import (ActionSpec, ActorCritic, CameraEmbedder, ConvFeaturesFlatten, action_spec_from,
                                    build_embedder, resolve_precision, set_compute_precision)
from laplab.agents.sac_networks import (SquashedGaussianActor, TwinQ, deepracer_squashed_log_prob,
                                        squashed_gaussian_log_prob)

CAMERA = gym.spaces.Box(0, 255, (1, 120, 160), np.uint8)
STEREO = gym.spaces.Box(0, 255, (2, 120, 160), np.uint8)

# conv (filters, kernel, stride) and dense sizes from the reference doc, and the flattened conv
# output for a 120 x 160 image (valid convolutions: out = (in - kernel) // stride + 1):
#   SHALLOW: 120x160 -> 29x39 -> 13x18 -> 11x16, x64 = 11264
#   DEEP_CONVOLUTIONAL_NETWORK: -> 58x78 -> 56x76 -> 27x37 -> 25x35, x64 = 56000
#   DEEP: -> 29x39 -> 13x18 -> 5x8 -> 3x6, x64 = 1152
NETWORKS = {
    "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW": ([(32, 8, 4), (64, 4, 2), (64, 3, 1)], 11264, [512], 512),
    "DEEP_CONVOLUTIONAL_NETWORK": ([(32, 5, 2), (32, 3, 1), (64, 3, 2), (64, 3, 1)], 56000, [64, 512], 512),
    "DEEP_CONVOLUTIONAL_NETWORK_DEEP": ([(32, 8, 4), (32, 4, 2), (64, 4, 2), (64, 3, 1)], 1152,
                                        [512, 512, 256, 128], 128),
}


def _dense_sizes(module):
    return [m.out_features for m in module.modules() if isinstance(m, nn.Linear)]


@pytest.mark.parametrize("name", NETWORKS)
@pytest.mark.parametrize("space", [CAMERA, STEREO], ids=["mono", "stereo"])
def test_named_network_layers_and_output(name, space):
    convs, flat, dense, out = NETWORKS[name]
    embedder = build_embedder(space, name)
    camera = embedder.sensors["observation"]
    assert isinstance(camera, CameraEmbedder)
    layers = [m for m in camera.modules() if isinstance(m, nn.Conv2d)]
    assert [(m.out_channels, m.kernel_size[0], m.stride[0]) for m in layers] == convs
    assert layers[0].in_channels == space.shape[0]
    assert all(isinstance(m, nn.ReLU) for m in camera.convolutions if not isinstance(m, (nn.Conv2d, nn.Flatten)))
    images = torch.randint(0, 256, (3, *space.shape), dtype=torch.uint8)
    assert camera.convolutions(images.float()).shape == (3, flat)
    assert _dense_sizes(embedder) == dense
    assert embedder(images).shape == (3, out) and embedder.output_dim == out


def test_images_are_scaled_to_unit_range():
    embedder = build_embedder(CAMERA)
    first = embedder.sensors["observation"].convolutions[0]
    images = torch.full((1, 1, 120, 160), 255, dtype=torch.uint8)
    expected = nn.functional.conv2d(torch.ones(1, 1, 120, 160), first.weight, first.bias, stride=4)
    torch.testing.assert_close(first(images.float() * embedder.sensors["observation"].scale), expected)


class _GradientLayout(torch.autograd.Function):
    """Identity that records the memory layout of the gradient its backward pass receives."""

    layouts: list[str] = []

    @staticmethod
    def forward(ctx, x):
        return x.view_as(x)

    @staticmethod
    def backward(ctx, gradient):
        channels_last = gradient.is_contiguous(memory_format=torch.channels_last) and not gradient.is_contiguous()
        _GradientLayout.layouts.append("channels_last" if channels_last else "other")
        return gradient


def test_conv_features_flatten_sends_its_gradient_back_channels_last():
    """ReLU's backward pass on channels-last conv features is ~13x slower with a channels-first gradient."""
    features = torch.randn(4, 8, 5, 6).contiguous(memory_format=torch.channels_last).requires_grad_()
    weights = torch.arange(8 * 5 * 6.0)
    _GradientLayout.layouts.clear()
    for flatten in (nn.Flatten(), ConvFeaturesFlatten()):
        features.grad = None
        flat = flatten(_GradientLayout.apply(torch.relu(features)))
        torch.testing.assert_close(flat, torch.relu(features).detach().flatten(1))  # the logical NCHW order
        (flat * weights).sum().backward()
        torch.testing.assert_close(features.grad, (features > 0) * weights.reshape(1, 8, 5, 6))
    assert _GradientLayout.layouts == ["other", "channels_last"]
    with torch.no_grad():  # no gradient, no hook
        torch.testing.assert_close(ConvFeaturesFlatten()(features), features.flatten(1))


def test_multi_sensor_dict_concatenates_embeddings():
    space = gym.spaces.Dict({
        "STEREO_CAMERAS": STEREO,
        "LIDAR": gym.spaces.Box(0.15, 1.0, (64,), np.float32),
    })
    embedder = build_embedder(space)
    # lidar: dense 256, 256; the middleware's 512 takes camera 11264 + lidar 256
    assert _dense_sizes(embedder.sensors["LIDAR"]) == [256, 256]
    assert embedder.middleware[0].in_features == 11264 + 256
    obs = {"STEREO_CAMERAS": torch.zeros(2, 2, 120, 160, dtype=torch.uint8), "LIDAR": torch.rand(2, 64)}
    assert embedder(obs).shape == (2, 512)


def test_state_vector_mlp_uses_tanh():
    embedder = build_embedder(gym.spaces.Box(-1, 1, (6,), np.float32), "MLP")
    assert _dense_sizes(embedder) == [256, 256]
    assert any(isinstance(m, nn.Tanh) for m in embedder.modules())
    assert embedder(torch.rand(5, 6)).shape == (5, 256)
    sector = build_embedder(gym.spaces.Dict({"DISCRETIZED_SECTOR_LIDAR": gym.spaces.Box(0, 1, (8, 8)),
                                             "STATE": gym.spaces.Box(-1, 1, (3,))}), "MLP")
    assert sector({"DISCRETIZED_SECTOR_LIDAR": torch.rand(4, 8, 8), "STATE": torch.rand(4, 3)}).shape == (4, 512)


@pytest.mark.parametrize("space, network, message", [
    (gym.spaces.Dict({"FRONT_CAMERA": CAMERA}), "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "Unknown sensor"),
    (gym.spaces.Dict({"FRONT_FACING_CAMERA": CAMERA, "LEFT_CAMERA": CAMERA}),
     "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "at most one camera"),
    (CAMERA, "MLP", "no convolutions"),
    (CAMERA, "RESNET", "Unknown neural_network"),
    (gym.spaces.Box(0, 255, (120, 160, 1), np.uint8), "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "channels-first"),
    (gym.spaces.Box(0, 255, (1, 12, 16), np.uint8), "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "too small"),
])
def test_bad_spaces_give_clear_errors(space, network, message):
    with pytest.raises(ValueError, match=message):
        build_embedder(space, network)


def test_action_spec_from_forms():
    assert action_spec_from(5) == ActionSpec(True, 5)
    assert action_spec_from(gym.spaces.Discrete(3)) == ActionSpec(True, 3)
    assert action_spec_from(gym.spaces.Box(-1, 1, (2,))) == ActionSpec(False, 2)
    metadata = {"action_space": [{"steering_angle": -30, "speed": 0.6}, {"steering_angle": 0, "speed": 1.2}],
                "action_space_type": "discrete"}
    assert action_spec_from(metadata) == ActionSpec(True, 2)
    continuous = {"action_space": {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 4}},
                  "action_space_type": "continuous"}
    assert action_spec_from(continuous) == ActionSpec(False, 2)
    with pytest.raises(ValueError, match="action space"):
        action_spec_from("steer")


def test_actor_critic_discrete_on_camera():
    model = ActorCritic(CAMERA, 5)
    obs = torch.randint(0, 256, (4, 1, 120, 160), dtype=torch.uint8)
    step = model.act(obs)
    assert step.action.shape == (4,) and step.value.shape == (4,) and step.log_prob.shape == (4,)
    log_prob, entropy, value = model.evaluate(obs, step.action)
    torch.testing.assert_close(log_prob, step.log_prob)
    # the starting policy is near uniform over 5 actions
    assert torch.allclose(entropy, torch.full((4,), np.log(5.0)), atol=1e-2)
    assert model.value_trunk is not None  # DeepRacer: separate policy and value networks


def test_actor_critic_continuous_clips_only_env_action():
    torch.manual_seed(0)
    model = ActorCritic(gym.spaces.Box(-1, 1, (3,), np.float32), ActionSpec(False, 2), "MLP")
    obs = torch.zeros(2000, 3)
    step = model.act(obs)
    assert step.action.shape == (2000, 2)
    assert step.action.abs().max() > 1.0  # std 1 at the start: raw samples leave [-1, 1]
    assert step.env_action.abs().max() <= 1.0
    torch.testing.assert_close(step.env_action, step.action.clamp(-1, 1))
    log_prob, _, _ = model.evaluate(obs, step.action)
    torch.testing.assert_close(log_prob, step.log_prob)
    deterministic = model.act(obs[:3], deterministic=True)
    torch.testing.assert_close(deterministic.action, model.policy_head(model.policy_trunk(obs[:3])))


def test_sac_networks_shapes_and_squash():
    space = gym.spaces.Box(0, 255, (2, 120, 160), np.uint8)
    actor, critic = SquashedGaussianActor(space, 2), TwinQ(space, 2)
    obs = torch.randint(0, 256, (3, 2, 120, 160), dtype=torch.uint8)
    actions, log_probs = actor(obs)
    assert actions.shape == (3, 2) and log_probs.shape == (3,) and actions.abs().max() < 1.0
    q1, q2 = critic(obs, actions)
    assert q1.shape == q2.shape == (3,)


def test_squashed_log_prob_matches_change_of_variables():
    # log p(tanh u) = log N(u) - log(1 - tanh(u)^2), summed over dims
    u = torch.tensor([[0.3, -1.2]])
    normal = torch.distributions.Normal(torch.tensor([[0.1, 0.0]]), torch.tensor([[0.5, 2.0]]))
    expected = (normal.log_prob(u) - torch.log(1 - torch.tanh(u) ** 2)).sum(-1)
    torch.testing.assert_close(squashed_gaussian_log_prob(u, normal), expected)


def test_deepracer_log_prob_drops_the_squash_correction_where_the_scaled_jacobian_passes_one():
    # deepracer-simapp's SAC head: log N(u) - sum log(clip(scale * (1 - tanh(u)^2) + eps, 1e-10, 1))
    u = torch.tensor([[0.3, -1.2], [3.0, 0.2]])
    mean = torch.tensor([[0.1, 0.0], [2.0, 0.0]])
    normal = torch.distributions.Normal(mean, torch.tensor([[0.5, 2.0], [0.5, 2.0]]))
    scale = torch.tensor([30.0, 1.5])
    jacobian = (scale * (1 - torch.tanh(u) ** 2) + np.finfo(np.float32).eps).clamp(1e-10, 1.0)
    expected = (normal.log_prob(u) - torch.log(jacobian)).sum(-1)
    got = deepracer_squashed_log_prob(u, normal, scale)
    torch.testing.assert_close(got, expected)
    # steering at 0.3: 30 * (1 - tanh^2) > 1, no correction; speed at -1.2: 1.5 * 0.31 < 1, corrected
    torch.testing.assert_close(got[0], (normal.log_prob(u)[0]).sum() - torch.log(1.5 * (1 - torch.tanh(u[0, 1]) ** 2)))
    # reparameterised (u = mean + std * noise), the clip leaves the policy's mean no pull towards the
    # middle of the range from the entropy term; the exact change of variables has one
    mean = torch.tensor([[0.1, 0.2]], requires_grad=True)
    std, noise = torch.tensor([[0.5, 2.0]]), torch.tensor([[0.4, 0.1]])
    for log_prob, pulled in ((lambda u, n: deepracer_squashed_log_prob(u, n, scale), False),
                             (squashed_gaussian_log_prob, True)):
        (grad,) = torch.autograd.grad(log_prob(mean + std * noise, torch.distributions.Normal(mean, std)).sum(), mean)
        assert bool((grad.abs() > 1e-3).all()) == pulled


def test_a_sac_actor_with_action_scales_keeps_them_out_of_its_state_dict():
    space = gym.spaces.Box(-1, 1, (4,), np.float32)
    actor = SquashedGaussianActor(space, 2, "MLP", action_scale=(30.0, 1.5))
    assert "action_scale" not in actor.state_dict()
    plain = SquashedGaussianActor(space, 2, "MLP")
    plain.load_state_dict(actor.state_dict())  # exports and evaluation build the actor without scales
    obs = torch.zeros(3, 4)
    torch.testing.assert_close(plain(obs, deterministic=True)[0], actor(obs, deterministic=True)[0])


STATE_VECTOR = gym.spaces.Box(-np.inf, np.inf, (27,), np.float32)


def test_auto_precision_is_bfloat16_only_for_camera_networks_on_native_hardware(monkeypatch):
    camera, state = ActorCritic(CAMERA, 5), ActorCritic(STATE_VECTOR, 5, "MLP")
    assert resolve_precision("auto", state) == "float32"
    for native in (True, False):
        monkeypatch.setattr(networks, "native_bfloat16", lambda: native)
        assert resolve_precision("auto", camera) == ("bfloat16" if native else "float32")
    assert resolve_precision("bfloat16", state) == "bfloat16"
    with pytest.raises(ValueError, match="precision must be one of"):
        resolve_precision("float16", camera)


def test_auto_precision_asks_the_device_the_network_lives_on(monkeypatch):
    """A learner on a GPU gets bfloat16 from the GPU's support, not from the host CPU's (an H200's
    learner on a host with AVX512-BF16 once resolved "auto" by the CPU)."""
    monkeypatch.setattr(networks, "native_bfloat16", lambda: True)
    elsewhere = ActorCritic(CAMERA, 5).to("meta")  # a device with no bfloat16 arithmetic of ours
    assert resolve_precision("auto", elsewhere) == "float32"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    for supported in (True, False):
        monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *args, **kwargs: supported)
        assert networks.bfloat16_is_native("cuda") is supported
    monkeypatch.setattr(networks, "native_bfloat16", lambda: False)
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *args, **kwargs: True)
    assert networks.bfloat16_is_native("cuda") and not networks.bfloat16_is_native("cpu")


def test_bfloat16_trunks_keep_float32_weights_features_and_gradients():
    torch.manual_seed(0)
    model = ActorCritic(CAMERA, 5)
    images = torch.randint(0, 256, (4, 1, 120, 160), dtype=torch.uint8)
    reference_dist, reference_values = model(images)
    assert set_compute_precision(model, "bfloat16") == "bfloat16"
    dist, values = model(images)
    assert dist.logits.dtype == values.dtype == torch.float32
    # bfloat16 keeps 8 bits of mantissa: features agree to ~1 %, not to float32's 1e-6.
    assert torch.allclose(values, reference_values, rtol=0.05, atol=0.02)
    assert not torch.equal(values, reference_values)
    (values.sum() + dist.logits.sum()).backward()
    assert all(p.dtype == torch.float32 and p.grad is not None and torch.isfinite(p.grad).all()
               for p in model.parameters() if p.requires_grad and p is not model.log_std)
    set_compute_precision(model, "float32")
    assert torch.equal(model(images)[1], reference_values)


def test_distribution_alone_matches_the_full_forward():
    model = ActorCritic(CAMERA, 5)
    images = torch.randint(0, 256, (3, 1, 120, 160), dtype=torch.uint8)
    assert torch.equal(model.distribution(images).logits, model(images)[0].logits)


# deepracer-simapp's STEREO_CAMERAS embedder with the deeper networks (get_stereo_camera_embedders):
# 120x160 -> 118x158 -> 58x78 -> 56x76 -> 27x37 -> 25x35, x128 = 112000, no dense layer; the
# network's middleware follows (DEEP_CONVOLUTIONAL_NETWORK: 512; _DEEP: 256, 128).
STEREO_CONVS = [(32, 3, 1), (64, 3, 2), (64, 3, 1), (128, 3, 2), (128, 3, 1)]


@pytest.mark.parametrize("name, middleware", [("DEEP_CONVOLUTIONAL_NETWORK", [512]),
                                              ("DEEP_CONVOLUTIONAL_NETWORK_DEEP", [256, 128])])
def test_stereo_with_a_deeper_network_builds_deepracers_stereo_embedder(name, middleware):
    from laplab.env.spec import network_layout
    layout = network_layout(name, ["STEREO_CAMERAS", "LIDAR"])
    assert layout == f"{name}+STEREO_CAMERAS"
    assert network_layout(name, ["STEREO_CAMERAS"], "laplab-1") == name  # laplab's older stereo models
    assert network_layout(name, ["FRONT_FACING_CAMERA"]) == name
    assert network_layout("DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", ["STEREO_CAMERAS"]) == "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
    embedder = build_embedder(gym.spaces.Dict({"STEREO_CAMERAS": STEREO}), layout)
    camera = embedder.sensors["STEREO_CAMERAS"]
    layers = [m for m in camera.modules() if isinstance(m, nn.Conv2d)]
    assert [(m.out_channels, m.kernel_size[0], m.stride[0]) for m in layers] == STEREO_CONVS
    assert layers[0].in_channels == 2
    images = torch.randint(0, 256, (2, *STEREO.shape), dtype=torch.uint8)
    assert camera.convolutions(images.float()).shape == (2, 112000)
    assert _dense_sizes(embedder) == middleware  # no dense layer in the stereo embedder
    assert embedder({"STEREO_CAMERAS": images}).shape == (2, middleware[-1])


def test_a_spec_builds_its_stereo_layout_and_refuses_an_unknown_one():
    from laplab.env.metadata import MetadataError, metadata_from_dict
    from laplab.env.spec import model_spec
    meta = metadata_from_dict({"sensor": ["STEREO_CAMERAS"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_DEEP"})
    assert model_spec(meta).network_layout == "DEEP_CONVOLUTIONAL_NETWORK_DEEP+STEREO_CAMERAS"
    assert model_spec(meta, stereo_layout="laplab-1").network_layout == "DEEP_CONVOLUTIONAL_NETWORK_DEEP"
    with pytest.raises(MetadataError, match="stereo_layout"):
        model_spec(meta, stereo_layout="other")
