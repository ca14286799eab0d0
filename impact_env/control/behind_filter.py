"""A network behind the scene's extended Kalman filter: what a compiled policy with an
``estimator`` runs every control period (:func:`act`).

1. The filter's measurement half on this frame's accelerometer, transducer and potentiometer
   (:mod:`impact_env.control.estimation.features`, the ``mpc`` law's filter).
2. The network on ``[observation row, the filter's scaled estimate]``, unless the filter has shown
   its model wrong: once one tick's normalised innovation squared exceeds ``nis_gate``,
   ``pd-penetration`` on the same sensors drives for the rest of the episode (latched), as the
   ``mpc`` law hands over.  A network trained on the filter's estimate has never seen the
   estimate of a plant off the filter's model; ``pd-penetration`` needs no model.  It runs every
   tick, so that it takes over with its state warm.  Why 1e3, and why not the filter's windowed
   lost-track test as ``mpc`` also uses: on ``rig``'s held-out drops 1000..1019 the one-tick NIS
   of a student's filter stays below 30 (a consistent filter's 3-channel NIS exceeds 44 once in
   1e9 ticks), while on ``rig-randomized``'s it passes 1e3 at the first push on most drops; the
   windowed test (a consistency test that a modest model error trips) reported lost track on one
   ``rig`` drop 25 ms after the touch, and handing over there cost that drop three times its
   energy integral (docs/agents-distillation.md).
3. The filter's prediction with the force of the command returned.

Constants (one float64 vector): the filter's
(:func:`impact_env.control.estimation.features.estimator_constants`), then ``nis_gate``, then
``pd-penetration``'s (its ``Constants`` order).  Memory row, in order: the
network's scratch (twice its widest layer), its input, the filter's frame (3), the observation's
frame in SI, the fallback's memory, the hand-over's flag and its count of ticks, the filter's
memory: :data:`TAIL` floats after the network's input and frame.
"""

from __future__ import annotations

import numpy as np

from impact_env._jit import jit
from impact_env.config import ConfigError
from impact_env.control import mlp as MLP
from impact_env.control.estimation import features as estimate
from impact_env.control.estimation.layout import MEMORY as FILTER_MEMORY
from impact_env.control.estimation.layout import EkfConstants, EkfMemory
from impact_env.control.laws import pd_penetration
from impact_env.control.laws.estimate import MEMORY as FALLBACK_MEMORY
from impact_env.control.laws.estimate import top_mass_of

NIS_GATE = 1.0e3  # see the module doc
SCALES = ("reference_length_m", "reference_speed_m_s", "nominal_m1_kg")
FILTER_NAMES: tuple[str, ...] = EkfConstants._fields + SCALES
FALLBACK_NAMES: tuple[str, ...] = pd_penetration.Constants._fields
GATE = estimate.SIZE  # where nis_gate sits in the constants
FALLBACK = GATE + 1  # ... and where the fallback's constants start
# the memory row's end: the fallback's memory, its flag and count, the filter's memory
TAIL = FALLBACK_MEMORY + 2 + FILTER_MEMORY
FALLBACK_ON = -(FILTER_MEMORY + 2)  # positions from the row's end
FALLBACK_TICKS = -(FILTER_MEMORY + 1)


def memory_size(widest: int, n_in: int, frame_size: int) -> int:
    return 2 * widest + n_in + 3 + frame_size + TAIL


def estimator_of(scene) -> dict:
    """The ``estimator`` entry of a policy file for ``scene``: the filter's constants by name, the
    gate and the fallback law's constants (``pd-penetration``'s defaults)."""
    k = estimate.estimator_constants(scene)
    defaults = pd_penetration.PARAMS
    gains = {"kp": defaults["kp"].default, "kd": defaults["kd"].default, "dref": 0.0,
             "top_mass": top_mass_of(scene)}
    fallback = pd_penetration.constants_of(scene, gains)
    return {"filter": "ekf", "constants": dict(zip(FILTER_NAMES, (float(v) for v in k), strict=True)),
            "nis_gate": NIS_GATE,
            "fallback": {"law": "pd-penetration",
                         "constants": {n: float(fallback[n]) for n in FALLBACK_NAMES}}}


def estimator_vector(d: dict) -> np.ndarray:
    """float64: an ``estimator`` entry's constants in the order :func:`act` reads them."""
    consts = d.get("constants") if isinstance(d, dict) else None
    fallback = d.get("fallback") if isinstance(d, dict) else None
    fallback_consts = fallback.get("constants") if isinstance(fallback, dict) else None
    if not (isinstance(consts, dict) and isinstance(fallback_consts, dict) and d.get("filter") == "ekf"
            and set(consts) == set(FILTER_NAMES) and set(fallback_consts) == set(FALLBACK_NAMES)
            and isinstance(fallback, dict) and fallback.get("law") == "pd-penetration"):
        raise ConfigError("a policy's 'estimator' must be {'filter': 'ekf', 'constants': {...}, "
                          "'nis_gate': G, 'fallback': {'law': 'pd-penetration', 'constants': {...}}} with "
                          "every constant by name (impact_env.control.behind_filter.estimator_of)")
    gate = float(d.get("nis_gate", np.nan))
    if not gate >= 0.0:
        raise ConfigError(f"the estimator's nis_gate = {d.get('nis_gate')!r} must be a number >= 0 "
                          "(dimensionless)")
    return np.array([float(consts[n]) for n in FILTER_NAMES] + [gate]
                    + [float(fallback_consts[n]) for n in FALLBACK_NAMES], dtype=np.float64)


@jit(inline="always")
def act(layers, weights, k, output, low, high, command_scale, slots, scales, obs, mem):
    """The command in [-1, 1] for the observation row ``obs`` (see the module doc): ``layers`` and
    ``weights`` the network (:func:`impact_env.control.mlp.pack_mlp`) with SB3's ``output``
    transform to ``[low, high]``; ``k`` the constants; ``slots`` the frame positions of the
    accelerometer, transducer, potentiometer and detector bit (-1: none); ``scales`` the
    frame's reference scales; ``mem`` the memory row, zeroed at the episode start."""
    obs_size = obs.shape[0]
    frame_size = scales.shape[0]
    n_in = layers[0, MLP.LI.n_in]
    filter_mem = mem[mem.shape[0] - FILTER_MEMORY:]
    end = mem.shape[0] - TAIL
    fallback_mem = mem[end:end + FALLBACK_MEMORY]
    v = mem[end - frame_size:end]
    frame = mem[end - frame_size - 3:end - frame_size]
    x_in = mem[end - frame_size - 3 - n_in:end - frame_size - 3]
    scratch = mem[:end - frame_size - 3 - n_in]
    for j in range(frame_size):
        v[j] = float(obs[j]) * scales[j]
    for c in range(3):
        frame[c] = v[slots[c]]
    estimate.features(k, filter_mem, frame, x_in[obs_size:])
    f_fallback = pd_penetration.force(slots, k[FALLBACK:], v, fallback_mem)
    if filter_mem[EkfMemory.nis_last] > k[GATE]:
        mem[mem.shape[0] + FALLBACK_ON] = 1.0
    if mem[mem.shape[0] + FALLBACK_ON] > 0.0:
        mem[mem.shape[0] + FALLBACK_TICKS] += 1.0
        u = f_fallback / command_scale
        u = -1.0 if u < -1.0 else (1.0 if u > 1.0 else u)
    else:
        for j in range(obs_size):
            x_in[j] = obs[j]
        out = MLP.mlp_forward(layers, weights, x_in, scratch)
        u = MLP.output_transform(output, out[0], low, high)
    estimate.applied(k, filter_mem, frame, u * command_scale)
    return u
