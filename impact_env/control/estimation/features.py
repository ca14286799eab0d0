"""The filter's estimate as a network's input: an actor that reads the extended Kalman filter's
state beside its sensor frame.

A network on a window of raw frames has to find body 1's state in their noise; one that reads the
filter's estimate gets it from the scene's own model, as ``mpc`` does
(docs/agents-distillation.md measures the difference).  The filter is the ``mpc`` law's
(:mod:`impact_env.control.estimation.ekf`, with :data:`impact_env.control.estimation.model.SETTINGS`),
run on the frame's accelerometer, transducer and potentiometer entries and told the command the
policy applied.  The estimate enters the network as :data:`FEATURES`, scaled like the
observation's entries (lengths by the reference length, speeds by the reference speed) and body
1's inverse mass as ``im1 m1 - 1`` (0 at the scene's nominal mass), after the observation row:
``input = [observation row, features]``.

:func:`estimator_constants` packs what :func:`features` reads: the filter's constants, then the
three scales (reference length m, reference speed m/s, nominal m1 kg).  The filter's memory row is
:data:`impact_env.control.estimation.layout.MEMORY` floats, zeroed at the episode start.
"""

from __future__ import annotations

import numpy as np

from impact_env._jit import jit
from impact_env.control.estimation.ekf import ekf_measure, ekf_tick
from impact_env.control.estimation.layout import IM1, N_CONSTANTS, V1, V2, X1, X2, EkfConstants, EkfMemory

#: the readings the filter takes, in its order (the sensor channels' names)
READS = ("accelerometer", "force", "potentiometer")
#: the network's extra inputs, after the observation row
FEATURES = ("x1_estimate", "v1_estimate", "x2_estimate", "v2_estimate", "inverse_mass_estimate")
FEATURE_UNITS = ("m", "m/s", "m", "m/s", "1/kg")
N_FEATURES = len(FEATURES)
REFS = N_CONSTANTS  # where the three scales start in the packed constants
SIZE = N_CONSTANTS + 3


def estimator_constants(scene) -> np.ndarray:
    """float64[SIZE]: the filter's constants for ``scene``, then the reference length (m), the
    reference speed (m/s) and the nominal m1 (kg).  ConfigError for a scene the filter does not
    model (:func:`impact_env.control.estimation.model.ekf_constants` says which)."""
    from impact_env.control.estimation.model import ekf_constants
    from impact_env.control.observation import References

    k = ekf_constants(scene)
    refs = References.of(scene)
    names: tuple[str, ...] = EkfConstants._fields
    return np.array([k[name] for name in names] + [refs.length, refs.speed, scene.plant.m1],
                    dtype=np.float64)


@jit(inline="always")
def features(k, mem, frame, out):
    """The filter's measurement half on ``frame`` (float64[3]: accelerometer m/s^2, transducer N,
    potentiometer m, as the policy reads them), then its estimate, scaled, into ``out[:N_FEATURES]``.
    ``k``: :func:`estimator_constants`; ``mem``: the filter's memory row."""
    ekf_measure(k, mem, frame)
    x = mem[EkfMemory.x:]
    length = k[REFS]
    speed = k[REFS + 1]
    out[0] = x[X1] / length
    out[1] = x[V1] / speed
    out[2] = x[X2] / length
    out[3] = x[V2] / speed
    out[4] = x[IM1] * k[REFS + 2] - 1.0


@jit(inline="always")
def applied(k, mem, frame, force):
    """The filter's prediction once the policy has chosen its command: ``force`` (N) demanded."""
    ekf_tick(k, mem, frame, force)


@jit
def features_batch(k, mem, frames, out):
    """:func:`features` for every row: ``frames`` float64[N, 3], ``mem`` float64[N, MEMORY],
    ``out`` float64[N, N_FEATURES]."""
    for i in range(frames.shape[0]):
        features(k, mem[i], frames[i], out[i])


@jit
def applied_batch(k, mem, frames, forces):
    """:func:`applied` for every row (``forces`` float64[N], N)."""
    for i in range(frames.shape[0]):
        applied(k, mem[i], frames[i], forces[i])
