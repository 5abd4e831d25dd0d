"""rl_coach's variables back into laplab's layers: the inverse of
:func:`laplab.export.tensorflow_checkpoint.network_variables` (its docstring lists the naming).

The expected variables of a model come from a laplab network built for its metadata (the same
sensors, network and action space): :func:`expected_variables` names every variable and shape the
checkpoint must hold, and :func:`layers_from_variables` reads them into :class:`PolicyLayers`, undoing
the channels-last row order of the first dense layer after a camera. Pure numpy.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import numpy as np

from laplab.export.policy_layers import Conv, Dense, PolicyLayers, SensorBranch
from laplab.export.tensorflow_checkpoint import (NETWORK_SCOPE, _features, channels_last_rows, conv_output_shape,
                                                 rl_coach_variables, sac_head_names)


def expected_variables(policy: PolicyLayers, value: PolicyLayers | None) -> dict[str, tuple[int, ...]]:
    """``{rl_coach variable name: shape}`` of a checkpoint of networks shaped like ``policy`` / ``value``."""
    return {name: tuple(array.shape) for name, array in rl_coach_variables(policy, value).items()}


def sac_head_layers(found: Mapping[str, tuple[int, ...]]) -> tuple[int, ...]:
    """The widths of the hidden layers of the SAC policy head in ``found`` (name -> shape): rl_coach's
    unnamed ``dense``, ``dense_1``... before the log-std layer, which has ``policy_mean``'s shape
    (deepracer-simapp: (256,)); () for laplab's own head or when there is no SAC head."""
    head = f"{NETWORK_SCOPE['sac']}/network_0/sac_policy_head_0"
    mean = found.get(f"{head}/policy_mean/kernel")
    widths: list[int] = []
    for index in range(8):
        shape = found.get(f"{head}/{'dense' if index == 0 else f'dense_{index}'}/kernel")
        if shape is None or mean is None or tuple(shape) == tuple(mean):
            break
        widths.append(int(shape[-1]))
    return tuple(widths)


OPTIMIZER_SLOTS = ("/Adam", "/Momentum", "/RMSProp", "beta1_power", "beta2_power")


def mismatches(found: Mapping[str, tuple[int, ...]], expected: Mapping[str, tuple[int, ...]],
               strict: bool = True) -> list[str]:
    """What keeps a checkpoint holding ``found`` (name -> shape) from filling ``expected``: missing
    variables, wrong shapes and (``strict``) variables of the same networks that laplab's network has
    no place for (another sensor, a deeper head), as short phrases; empty: it fits. Optimizer slots
    and variables outside the networks (a step counter) are ignored."""
    problems = []
    missing = sorted(set(expected) - set(found))
    if missing:
        problems.append(f"{len(missing)} variable(s) missing, e.g. {missing[0]!r}")
    for name in sorted(set(expected) & set(found)):
        if tuple(found[name]) != tuple(expected[name]):
            problems.append(f"{name!r} has shape {list(found[name])}, expected {list(expected[name])}")
    if strict:
        scopes = {name.rsplit("/", 1)[0].split("/network_")[0] + "/network_" for name in expected}
        extra = sorted(name for name in set(found) - set(expected) if name.startswith(tuple(scopes))
                       and not any(slot in name for slot in OPTIMIZER_SLOTS))
        if extra:
            problems.append(f"{len(extra)} variable(s) the network has no place for, e.g. {extra[0]!r}")
    return problems


def _inverse(rows: np.ndarray) -> np.ndarray:
    return np.argsort(rows, kind="stable")


def network_layers(template: PolicyLayers, variables: Mapping[str, np.ndarray], scope: str,
                   head: str) -> PolicyLayers:
    """``template``'s layers with the weights of the rl_coach network at ``scope`` (head scope ``head``)."""
    def take(name: str) -> np.ndarray:
        return np.ascontiguousarray(variables[name], dtype=np.float32)

    branches: list[SensorBranch] = []
    merged_rows, offset = [], 0
    for branch in template.branches:
        base = f"{scope}/{branch.sensor}"
        convs = tuple(Conv(take(f"{base}/Conv2d_{2 * i}/kernel"), take(f"{base}/Conv2d_{2 * i}/bias"), conv.stride,
                           conv.activation) for i, conv in enumerate(branch.convs))
        dense = []
        for index, layer in enumerate(branch.dense):
            name = f"{base}/Dense_{2 * (len(branch.convs) + index)}"
            kernel = take(f"{name}/kernel")
            if index == 0 and branch.is_camera:
                kernel = kernel[_inverse(channels_last_rows(*conv_output_shape(branch)))]
            dense.append(Dense(kernel, take(f"{name}/bias"), layer.activation))
        loaded = replace(branch, convs=convs, dense=tuple(dense))
        branches.append(loaded)
        count, rows = _features(loaded)
        merged_rows.append(offset + (np.arange(count) if rows is None else rows))
        offset += count
    inverse = _inverse(np.concatenate(merged_rows))
    middleware = []
    for index, layer in enumerate(template.middleware):
        name = f"{scope}/middleware_fc_embedder/Dense_{2 * index}"
        kernel = take(f"{name}/kernel")
        middleware.append(Dense(kernel[inverse] if index == 0 else kernel, take(f"{name}/bias"), layer.activation))
    first = template.head_hidden[0] if template.head_hidden else template.head  # the layer reading the features
    head_rows = inverse if not template.middleware else np.arange(first.kernel.shape[0])
    log_std, log_std_head, head_hidden = None, None, []
    if template.algorithm == "sac" and template.output == "tanh":
        hidden_names, mean_name, log_std_name = sac_head_names(len(template.head_hidden))
        for index, (name, dense) in enumerate(zip(hidden_names, template.head_hidden)):
            kernel = take(f"{scope}/{head}/{name}/kernel")
            head_hidden.append(Dense(kernel[head_rows] if index == 0 else kernel, take(f"{scope}/{head}/{name}/bias"),
                                     dense.activation))
        if head_hidden:
            head_rows = np.arange(template.head.kernel.shape[0])
        layer = f"{scope}/{head}/{mean_name}"
        std = f"{scope}/{head}/{log_std_name}"
        if template.log_std_head is not None and f"{std}/kernel" in variables:  # (a frozen graph has none)
            log_std_head = Dense(take(f"{std}/kernel")[head_rows], take(f"{std}/bias"), "none")
        else:
            log_std_head = template.log_std_head
    elif head.startswith("v_values_head"):
        layer = f"{scope}/{head}/output"
    else:
        layer = f"{scope}/{head}/{'policy_fc' if template.output == 'softmax' else 'policy_mean'}"
        if template.log_std is not None:  # (a frozen graph has none: the template's stays)
            name = f"{scope}/{head}/policy_log_std"
            log_std = take(name).reshape(-1) if name in variables else template.log_std
    head_layer = Dense(take(f"{layer}/kernel")[head_rows], take(f"{layer}/bias"), "none")
    return PolicyLayers(template.algorithm, tuple(branches), tuple(middleware), head_layer, template.output,
                        log_std, log_std_head, tuple(head_hidden))


def layers_from_variables(policy: PolicyLayers, value: PolicyLayers | None,
                          variables: Mapping[str, np.ndarray]) -> tuple[PolicyLayers, PolicyLayers | None]:
    """(policy, value) layers shaped like the templates, with the checkpoint's weights (PPO:
    ``network_1`` the policy, ``network_0`` the value; SAC: ``network_0`` the policy)."""
    root = NETWORK_SCOPE[policy.algorithm]
    if policy.algorithm == "sac":
        return network_layers(policy, variables, f"{root}/network_0", "sac_policy_head_0"), None
    loaded_value = None if value is None else network_layers(value, variables, f"{root}/network_0", "v_values_head_0")
    return network_layers(policy, variables, f"{root}/network_1", "ppo_head_0"), loaded_value
