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
allocates nothing.  W is packed transposed (in x out); the kernel sums eight outputs at a time
in registers, each in input order (``b + W[:, 0] x0 + ...``), so nothing is reassociated.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.config import ConfigError

ACTIVATIONS = ("identity", "tanh", "relu", "hardtanh", "leaky_relu", "elu")
ACT = {name: k for k, name in enumerate(ACTIVATIONS)}
OUTPUTS = ("clip", "squash")
OUT = {name: k for k, name in enumerate(OUTPUTS)}


class LayerInts(NamedTuple):
    """A row of the layer table (int64[n_layers, N_LAYER_INTS]): sizes, the activation's code and
    where the layer's floats start in the weights vector."""

    n_in: int
    n_out: int
    activation: int  # ACT[name]
    weight: int  # offset of W^T (n_in x n_out, row-major)
    bias: int  # offset of b
    a0: int  # offset of the activation's first parameter
    a1: int  # ... and of its second


LI = positions(LayerInts)
N_LAYER_INTS = len(LI)


def pack_mlp(layers: list[dict]) -> tuple[np.ndarray, np.ndarray, int]:
    """(int64[n_layers, N_LAYER_INTS], float64 weights, widest layer) from ``[{"weight": [[...]], "bias":
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
        ints[j] = LayerInts(n_in=W.shape[1], n_out=W.shape[0], activation=ACT[act], weight=off,
                            bias=off + W.size, a0=off + W.size + b.size, a1=off + W.size + b.size + 1)
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
    n0 = layers[0, LI.n_in]
    for i in range(n0):
        x[i] = obs[i]
    for j in range(layers.shape[0]):
        n_in = layers[j, LI.n_in]
        n_out = layers[j, LI.n_out]
        ow = layers[j, LI.weight]
        ob = layers[j, LI.bias]
        code = layers[j, LI.activation]
        a0 = w[layers[j, LI.a0]]
        a1 = w[layers[j, LI.a1]]
        # eight outputs at a time in locals: eight independent add chains in registers, where
        # y[o] += ... in memory made every step a load and a store (y may alias w for LLVM).
        # Each output is still summed b + W[:, 0] x0 + W[:, 1] x1 + ...: bitwise the same.
        o = 0
        while o + 8 <= n_out:
            c0, c1, c2, c3 = w[ob + o], w[ob + o + 1], w[ob + o + 2], w[ob + o + 3]
            c4, c5, c6, c7 = w[ob + o + 4], w[ob + o + 5], w[ob + o + 6], w[ob + o + 7]
            col = ow + o
            for i in range(n_in):
                xi = x[i]
                c0 += w[col] * xi
                c1 += w[col + 1] * xi
                c2 += w[col + 2] * xi
                c3 += w[col + 3] * xi
                c4 += w[col + 4] * xi
                c5 += w[col + 5] * xi
                c6 += w[col + 6] * xi
                c7 += w[col + 7] * xi
                col += n_out
            y[o], y[o + 1], y[o + 2], y[o + 3] = c0, c1, c2, c3
            y[o + 4], y[o + 5], y[o + 6], y[o + 7] = c4, c5, c6, c7
            o += 8
        while o < n_out:
            c = w[ob + o]
            col = ow + o
            for i in range(n_in):
                c += w[col] * x[i]
                col += n_out
            y[o] = c
            o += 1
        for o in range(n_out):
            x[o] = _activate(code, y[o], a0, a1)
    return x[:layers[layers.shape[0] - 1, LI.n_out]]


@jit(inline="always")
def output_transform(mode, a, low, high):
    """SB3's deterministic action from the network's output ``a`` (see the module doc)."""
    if mode == 1:
        return low + (0.5 * (np.tanh(a) + 1.0) * (high - low))
    return low if a < low else (high if a > high else a)
