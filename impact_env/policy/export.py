"""Exporting policies: any policy spec that ``compare`` accepts to a compiled policy file
(:mod:`impact_env.control.policy`), and compiled networks to ONNX.

* A named classic law (``pd-penetration:kp=3e5``) becomes its compiled law with the same gains
  (the law's ``compiled()``).
* A saved stable-baselines3 model (``ppo:PATH.zip``, ``sac:PATH.zip``, ...) becomes an MLP: the
  actor's ``Linear`` layers and activations, read from the torch modules, and the output
  transform SB3's ``predict(deterministic=True)`` applies (:func:`impact_env.policy.sb3.sb3_layers` says which).
  No ``VecNormalize`` is involved: the env's observations are already of order one, and
  ``agents.train`` does not normalise.
* ``compiled:FILE`` is loaded and written again.

:func:`write_onnx` writes a compiled MLP as an ONNX graph (``Gemm`` and activation nodes, the
output transform, float32), for people who deploy with other tools; classic laws carry memory
and branches and are not exported to ONNX.
"""

from __future__ import annotations

import typing
from pathlib import Path

import numpy as np

from impact_env.config import ConfigError
from impact_env.control.observation import OBS_LIMIT
from impact_env.control.policy import CompiledPolicy
from impact_env.policy.registry import is_model_spec, make_policy
from impact_env.policy.sb3 import path_stem, sb3_layers
from impact_env.scene import load_scene


def export_policy(spec: str, scene) -> CompiledPolicy:
    """The compiled policy of ``spec`` on ``scene`` (see the module doc)."""

    scene = load_scene(scene)
    if spec.startswith("compiled:"):
        pol = CompiledPolicy.load(spec.partition(":")[2])
        pol.check_scene(scene)
        return pol
    policy = make_policy(spec, scene)
    if isinstance(policy, CompiledPolicy):  # a model behind the filter is loaded compiled already
        return policy
    if is_model_spec(spec):
        return export_sb3(policy, scene, spec=spec)
    if not hasattr(policy, "compiled"):
        raise ConfigError(f"policy {spec!r} ({type(policy).__name__}) cannot be compiled: it has no "
                          "compiled() method")
    return policy.compiled()


def export_sb3(policy, scene, spec: str = "") -> CompiledPolicy:
    """A loaded :class:`~impact_env.policy.sb3.ModelPolicy` as a compiled MLP, with the hold and
    the residual law it was trained with (its ``model.json``)."""
    model = policy.model
    space = model.action_space
    if space.shape != (1,):
        raise ConfigError(f"the model's action space {space} is not the shaker's one command")
    layers, output = sb3_layers(model)
    low, high = float(space.low[0]), float(space.high[0])
    source = {"spec": spec, "algo": type(model).__name__.lower()}
    residual = None if policy.residual is None else export_policy(policy.residual, scene)
    return CompiledPolicy.from_mlp(path_stem(spec), layers, output, low, high, scene, policy.observation,
                                   policy.history, hold_ticks=policy.hold_ticks, residual=residual, source=source)


def onnx_metadata(pol: CompiledPolicy) -> dict[str, str]:
    """What a user of another toolchain needs to feed the network and use its output, as ONNX
    ``metadata_props`` (strings; lists and dicts as JSON): the observation (kind, entry names,
    units, reference scales: obs = value / scale, clipped to +-obs_limit; history), the command
    scale and rate, the hold and the residual law (whose output is added every tick, the sum
    clipped to [-1, 1]), and the policy file's sha256."""
    import json

    lay = pol.layout
    names = list(lay.names)
    full = [f"{n}[t-{h}]" if h else n for h in range(lay.history) for n in names]
    if lay.history > 1:
        full += [f"action[t-{h + 1}]" for h in range(lay.history)]
    res = pol.residual_policy()
    return {
        "impact_env.observation": pol.observation,
        "impact_env.observation_names": json.dumps(full),
        "impact_env.frame_names": json.dumps(names),
        "impact_env.frame_units": json.dumps(list(lay.units)),
        "impact_env.frame_scales": json.dumps([float(x) for x in lay.scales]),
        "impact_env.obs_limit": repr(float(OBS_LIMIT)),
        "impact_env.history": str(lay.history),
        "impact_env.hold_ticks": str(pol.hold_ticks),
        "impact_env.control_rate_hz": repr(float(pol.control_rate)),
        "impact_env.command_scale_n": repr(float(pol.command_scale)),
        "impact_env.action": "command in [-1, 1]; 1 = command_scale_n newtons upwards on body 2",
        "impact_env.residual_law": json.dumps(None if res is None else {
            k: typing.cast(dict, res.law)[k] for k in ("name", "params", "constants")}),
        "impact_env.policy_sha256": pol.sha256(),
        "impact_env.scene": json.dumps(pol.scene),
    }


def write_onnx(pol: CompiledPolicy, path) -> Path:
    """The compiled MLP ``pol`` as an ONNX model: input ``obs`` float32[N, obs size], output
    ``action`` float32[N, 1] (the command in [-1, 1])."""
    if pol.mlp is None:
        law = typing.cast(dict, pol.law)
        raise ConfigError(f"policy {pol.name!r} is a classic law ({law['name']}): only MLP policies are "
                          "exported to ONNX (a law keeps memory between calls)")
    if pol.estimator is not None:
        raise ConfigError(f"policy {pol.name!r} runs a Kalman filter before its network: ONNX would hold the "
                          "network alone, whose last inputs are the filter's estimate (the filter keeps memory "
                          "between calls); deploy it with the compiled policy file or the C export")
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    nodes, inits = [], []
    x = "obs"
    for j, ly in enumerate(pol.mlp["layers"]):
        W = np.asarray(ly["weight"], dtype=np.float32)
        b = np.asarray(ly["bias"], dtype=np.float32)
        inits += [numpy_helper.from_array(W, f"W{j}"), numpy_helper.from_array(b, f"b{j}")]
        y = f"z{j}"
        nodes.append(helper.make_node("Gemm", [x, f"W{j}", f"b{j}"], [y], transB=1))
        act, (a0, a1) = ly["activation"], ly["params"]
        if act != "identity":
            out = f"h{j}"
            if act == "tanh":
                nodes.append(helper.make_node("Tanh", [y], [out]))
            elif act == "relu":
                nodes.append(helper.make_node("Relu", [y], [out]))
            elif act == "hardtanh":
                inits += [numpy_helper.from_array(np.array(a0, np.float32), f"lo{j}"),
                          numpy_helper.from_array(np.array(a1, np.float32), f"hi{j}")]
                nodes.append(helper.make_node("Clip", [y, f"lo{j}", f"hi{j}"], [out]))
            elif act == "leaky_relu":
                nodes.append(helper.make_node("LeakyRelu", [y], [out], alpha=float(a0)))
            elif act == "elu":
                nodes.append(helper.make_node("Elu", [y], [out], alpha=float(a0)))
            y = out
        x = y
    low, high = pol.mlp["low"], pol.mlp["high"]
    inits += [numpy_helper.from_array(np.array(low, np.float32), "low"),
              numpy_helper.from_array(np.array(high, np.float32), "high")]
    if pol.mlp["output"] == "clip":
        nodes.append(helper.make_node("Clip", [x, "low", "high"], ["action"]))
    else:  # low + 0.5 (a + 1) (high - low), after a tanh for "squash"
        if pol.mlp["output"] == "squash":
            nodes.append(helper.make_node("Tanh", [x], ["sq"]))
            x = "sq"
        inits += [numpy_helper.from_array(np.array(1.0, np.float32), "one"),
                  numpy_helper.from_array(np.array(0.5 * (high - low), np.float32), "half_span")]
        nodes += [helper.make_node("Add", [x, "one"], ["a1"]),
                  helper.make_node("Mul", ["a1", "half_span"], ["a2"]),
                  helper.make_node("Add", ["a2", "low"], ["action"])]
    n_obs = pol.layout.size
    graph = helper.make_graph(nodes, pol.name,
                              [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [None, n_obs])],
                              [helper.make_tensor_value_info("action", TensorProto.FLOAT, [None, 1])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="impact_env")
    model.ir_version = 8
    helper.set_model_props(model, onnx_metadata(pol))
    onnx.checker.check_model(model)
    path = Path(path)
    onnx.save(model, str(path))
    return path
