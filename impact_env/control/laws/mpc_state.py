"""``mpc-state``: model-predictive control on the true state (a privileged yardstick, like
``thesis-ideal`` and the oracle).

Each tick it plans the next ``horizon`` control periods of force demand so that body 1's catch
energy, summed over the predicted ticks (the metric ``energy_integral_ms`` is its integral),
plus ``r u^2`` is least, on the scene's own model: the two bodies on the Hertz-Tsuji pad
(``plant.c``, the pad damping that gives ``plant.restitution``, the suspension), driven through
the shaker's coil model (``effects.shaker``, three augmented states), under the force limit
(the smaller of ``effects.saturation.peak_n`` and ``effects.command_scale``) and the slew limit
(``effects.saturation.slew_n_per_s``) as hard constraints.  It solves with a fixed number of
box-constrained iLQR iterations per tick, warm-started from the previous tick's plan
(:mod:`impact_env.control.mpc.solver`: the method, its fallbacks and their counters).  Before
the touch, body 1's free flight is known exactly, so the plan moves body 2 ahead of it.

The model knows the scene's nominal m1 (``rig`` draws 0.08-0.12 kg per drop; ``m1`` sets another).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.config import ConfigError
from impact_env.control.laws.law import Law, Param
from impact_env.control.mpc import model, solver
from impact_env.control.mpc.model import shaker_realisation
from impact_env.effects.shaker import discrete_emf_model
from impact_env.plant.restitution import tsuji_damping


class Reads(NamedTuple):
    """The privileged frame's true state."""

    x1: int
    v1: int
    x2: int
    v2: int


class Constants(model.Constants):
    """The solver's constants (:class:`impact_env.control.mpc.model.Constants`), as this law's."""


RD = positions(Reads)

PARAMS = {
    "horizon": Param(40.0, "periods", f"prediction horizon (a contact lasts 30-40 periods at 10 kHz; "
                     f"at most {solver.NMAX})", lo=1.0, hi=float(solver.NMAX)),
    "iterations": Param(1.0, "", "iLQR iterations per tick (fixed: the tick's budget; 1 and 2 score alike "
                        "on rig)", lo=1.0, hi=20.0),
    "line_search": Param(4.0, "", "step halvings tried per iteration", lo=1.0, hi=20.0),
    "r": Param(1e-9, "J/N^2", "input weight: cost r u^2 per period", lo=0.0),
    "w_terminal": Param(10.0, "", "weight of the last predicted state's energy (in periods)", lo=0.0),
    "w2": Param(0.0, "", "weight of body 2's energy m2 v2^2/2 + k2 x2^2/2 beside body 1's", lo=0.0),
    "substeps": Param(1.0, "", "model steps per control period", lo=1.0, hi=16.0),
    "mu": Param(1e-12, "J/N^2", "regularisation added to the input's curvature", lo=0.0),
    "m1": Param(None, "kg", "body 1's mass in the model; default plant.m1", lo=1e-6,
                from_scene=lambda scene: scene.plant.m1),
}


def solver_constants(scene, P: dict) -> dict:
    """The solver's constants (:class:`impact_env.control.mpc.model.Constants`) for ``scene`` and
    the gains ``P`` (horizon, iterations, line_search, r, w_terminal, w2, substeps, mu, m1).

    The model is the hardware the scene knows (:func:`impact_env.scene.randomize.known_hardware`:
    on a calibrated scene, the identified pad, masses and amplifier gain); the force box is the
    force that hardware applies at full command, and the law's demand is the planned force over
    the amplifier's known gain (``command_gain``, 1 unless the scene knows it)."""
    from impact_env.scene.randomize import known_command_gain, known_hardware

    gain = known_command_gain(scene)
    scene = known_hardware(scene)
    p = scene.plant
    fx = scene.effects
    for key in ("horizon", "iterations", "line_search", "substeps"):
        if float(P[key]) != int(P[key]):
            raise ConfigError(f"mpc parameter {key} = {P[key]!r} must be a whole number")
    m1 = float(P["m1"])
    b = tsuji_damping(p.restitution, m1, p.m2, p.c) if p.restitution < 1.0 else 0.0
    umax = float(fx.command_scale)
    slew = 0.0
    if fx.on("saturation"):
        umax = min(umax, float(fx.saturation.peak_n))
        if fx.saturation.slew_n_per_s > 0.0:
            slew = float(fx.saturation.slew_n_per_s) / scene.control_rate
    if fx.on("shaker"):
        if fx.shaker.model != "coil" or fx.shaker.inverse_filter:
            raise ConfigError("mpc: the prediction model holds the coil model of effects.shaker "
                              f"(order 3); model = {fx.shaker.model!r}, inverse_filter = "
                              f"{fx.shaker.inverse_filter} is not modelled")
        A, B, C, D, _ = discrete_emf_model(fx.shaker, scene.control_rate)
        shaker = shaker_realisation(A, B, C, D)
    else:  # the demand reaches body 2 as it is
        shaker = shaker_realisation([[0.0]], [0.0], [0.0], 1.0)
    out = {"m1": m1, "m2": p.m2, "c": p.c, "b": b, "g": p.gravity, "k2": p.suspension_stiffness,
           "c2": p.suspension_damping, "ds": (m1 * p.gravity / p.c) ** (2.0 / 3.0), "umax": umax,
           "slew": slew, "h": scene.control_period, "substeps": float(P["substeps"]),
           "horizon": float(P["horizon"]), "iterations": float(P["iterations"]),
           "line_search": float(P["line_search"]), "r": float(P["r"]), "w_terminal": float(P["w_terminal"]),
           "w2": float(P["w2"]), "mu": float(P["mu"]), "dmin": 1e-7, **shaker,
           "command_gain": gain}
    missing = set(Constants._fields) ^ set(out)
    assert not missing, missing
    if not all(math.isfinite(v) for v in out.values()):
        raise ConfigError("mpc: a constant of the model is not finite")
    return out


@jit
def force(slots, k, v, mem):
    f = solver.mpc_tick(v[slots[RD.x1]], v[slots[RD.v1]], v[slots[RD.x2]], v[slots[RD.v2]], k, mem)
    return f / k[model.K.command_gain]


LAW = Law("mpc-state", "privileged", "model-predictive control on the true state: box-constrained iLQR "
          "over the Hertz-Tsuji pad and the shaker's coil model, warm-started, a fixed number of "
          "iterations per tick, force and slew limits as hard constraints; cost: body 1's catch "
          "energy over the horizon",
          Reads, Constants, solver_constants, memory=solver.MEMORY, params=PARAMS)
