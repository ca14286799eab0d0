"""A multilayer perceptron, compiled: the deterministic action of a trained actor network.

Layers ``y = act(W x + b)`` (W row-major, out x in, as torch's ``Linear.weight``), activations
by code (:data:`ACTIVATIONS`), then the output transform stable-baselines3 applies in
``predict(deterministic=True)`` for a Box action space ``[low, high]``:

* ``clip``: the network's output is the action's mean, clipped to ``[low, high]`` (PPO, A2C
  without squashing);
* ``squash``: ``tanh`` of the network's last layer, then unscaled ``low + (a + 1) (high - low) / 2``
  (SAC; PPO with ``squash_output``; TD3 and DDPG, whose actor ends in that tanh).

Packing (int64 ``layers``: per layer n_in, n_out, activation, offset of W, offset of b into the
float64 ``weights``) and the kernel, which needs a scratch row of ``2 * widest`` floats and
allocates nothing.  W is packed transposed (in x out), so that the kernel adds each input's
column to all outputs at once: that loop has no reduction in it and LLVM vectorises it without
reassociating anything (each output is still summed in input order, ``b + W[:, 0] x0 + ...``).
"""

from __future__ import annotations

import numpy as np

from impact_env._jit import jit
from impact_env.config import ConfigError

ACTIVATIONS = ("identity", "tanh", "relu", "hardtanh", "leaky_relu", "elu")
ACT = {name: k for k, name in enumerate(ACTIVATIONS)}
OUTPUTS = ("clip", "squash")
OUT = {name: k for k, name in enumerate(OUTPUTS)}
L_IN, L_OUT, L_ACT, L_W, L_B, L_A0, L_A1 = range(7)  # per-layer ints; L_A0/L_A1: activation params' offsets
N_LAYER_INTS = 7


def pack_mlp(layers: list[dict]) -> tuple[np.ndarray, np.ndarray, int]:
    """(int64[n_layers, 7], float64 weights, widest layer) from ``[{"weight": [[...]], "bias":
    [...], "activation": name, "params": [a0, a1]}, ...]`` (``params``: hardtanh's min and max,
    leaky_relu's slope, elu's alpha)."""
    if not layers:
        raise ConfigError("an MLP policy needs at least one layer")
    ints = np.zeros((len(layers), N_LAYER_INTS), dtype=np.int64)
    chunks: list[np.ndarray] = []
    off = 0
    n_prev = None
    widest = 0
    for j, layer in enumerate(layers):
        W = np.asarray(layer["weight"], dtype=np.float64)
        b = np.asarray(layer["bias"], dtype=np.float64)
        act = layer.get("activation", "identity")
        if act not in ACT:
            raise ConfigError(f"MLP layer {j}: activation {act!r} is not one of {', '.join(ACTIVATIONS)}")
        if W.ndim != 2 or b.shape != (W.shape[0],):
            raise ConfigError(f"MLP layer {j}: weight must be [out, in] and bias [out], "
                              f"got {W.shape}, {b.shape}")
        if n_prev is not None and W.shape[1] != n_prev:
            raise ConfigError(f"MLP layer {j} takes {W.shape[1]} inputs but layer {j - 1} gives {n_prev}")
        if not (np.all(np.isfinite(W)) and np.all(np.isfinite(b))):
            raise ConfigError(f"MLP layer {j}: weights must be finite")
        params = np.asarray(layer.get("params", [0.0, 0.0]), dtype=np.float64).reshape(-1)
        params = np.concatenate([params, np.zeros(2)])[:2]
        ints[j] = (W.shape[1], W.shape[0], ACT[act], off, off + W.size, off + W.size + b.size,
                   off + W.size + b.size + 1)
        chunks += [W.T.ravel(), b, params]
        off += W.size + b.size + 2
        n_prev = W.shape[0]
        widest = max(widest, W.shape[0], W.shape[1])
    return ints, np.concatenate(chunks), widest


@jit(inline="always")
def _activate(code, x, a0, a1):
    if code == 1:
        return np.tanh(x)
    if code == 2:
        return x if x > 0.0 else 0.0
    if code == 3:
        return a0 if x < a0 else (a1 if x > a1 else x)
    if code == 4:
        return x if x > 0.0 else a0 * x
    if code == 5:
        return x if x > 0.0 else a0 * np.expm1(x)
    return x


@jit(inline="always")
def mlp_forward(layers, w, obs, scratch):
    """The network's output (float64[n_out] of the last layer, in ``scratch``'s first slots after
    the call: returned as a view) for the observation row ``obs``."""
    widest = scratch.shape[0] // 2
    x = scratch[:widest]
    y = scratch[widest:]
    n0 = layers[0, L_IN]
    for i in range(n0):
        x[i] = obs[i]
    for j in range(layers.shape[0]):
        n_in = layers[j, L_IN]
        n_out = layers[j, L_OUT]
        ow = layers[j, L_W]
        ob = layers[j, L_B]
        code = layers[j, L_ACT]
        a0 = w[layers[j, L_A0]]
        a1 = w[layers[j, L_A1]]
        for o in range(n_out):
            y[o] = w[ob + o]
        for i in range(n_in):
            xi = x[i]
            col = ow + i * n_out
            for o in range(n_out):
                y[o] += w[col + o] * xi
        for o in range(n_out):
            x[o] = _activate(code, y[o], a0, a1)
    return x[:layers[layers.shape[0] - 1, L_OUT]]


@jit(inline="always")
def output_transform(mode, a, low, high):
    """SB3's deterministic action from the network's output ``a`` (see the module doc)."""
    if mode == 1:
        return low + (0.5 * (np.tanh(a) + 1.0) * (high - low))
    return low if a < low else (high if a > high else a)
