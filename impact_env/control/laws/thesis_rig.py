"""``thesis-rig``: the law that ran on the rig (thesis sec 4.2, eq 4.3), fed by its sensors only.

    f2 = m2 (Phi (m1+m2)/(m1 m2) - g - h11 d' - h01 (d - dref)) - h12 v2 - h02 x2   while contact is detected
    f2 = 0                                                                           otherwise

with Phi, the penetration d and its rate d' estimated from body 2's accelerometer and force
transducer (:mod:`impact_env.control.laws.estimate`), x2 from the potentiometer and v2 its difference.

* **Erratum** (thesis-notes): eq 4.3 prints ``h11 (x1 - x2)``; the derivative ``h11 (x1' - x2')``
  is meant (compare eq 2.12, and the unit of h11, 1/s).  Implemented with the derivative.
* The thesis set h12 = h02 = 0 on the rig (the suspension recentres body 2): the defaults.
* The law runs only while the eq 4.4 detector reports contact (the scene's ``detector``
  effect, the ``contact_detected`` observation; without it, eq 4.4 in level mode is applied here
  with the scene's detector threshold).
* ``dref = 0`` by default: at rest the rig's detector read "no contact" and the rest penetration
  d was set to zero (sec 4.2).
* Gains default to the pair that caught best on the rig (sec 4.4: h01 = 2.3e6 1/s^2, h11 = 18 1/s);
  the sec 4.3 text swaps the names of h01 and h11 (erratum).
"""

from __future__ import annotations

from typing import NamedTuple

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.control.laws.estimate import MEMORY, SensorReads, c_estimate, estimate, top_mass_of
from impact_env.control.laws.law import Law, Param


class Constants(NamedTuple):
    m1: float  # kg
    m2: float  # kg
    c: float  # N/m^1.5
    g: float  # m/s^2
    h01: float  # 1/s^2
    h11: float  # 1/s
    h02: float  # N/m
    h12: float  # N s/m
    dref: float  # m
    top_mass: float  # kg, m2' of eq 4.4
    rate: float  # Hz, the control rate (the estimate's differences)
    threshold: float  # N, eq 4.4's level when the observation has no detector bit


K = positions(Constants)

PARAMS = {
    "h01": Param(2.3e6, "1/s^2", "stiffness of the penetration error dynamics (sec 4.4)", lo=0.0),
    "h11": Param(18.0, "1/s", "damping of the penetration error dynamics (sec 4.4)", lo=0.0),
    "h02": Param(0.0, "N/m", "force on body 2's position (0 on the rig)"),
    "h12": Param(0.0, "N s/m", "force on body 2's velocity (0 on the rig)"),
    "dref": Param(0.0, "m", "tracked penetration (0 on the rig, sec 4.2)", lo=0.0),
    "top_mass": Param(None, "kg", "m2' in Phi = m2' a2 + T; default effects.sensors.force.top_mass", lo=0.0,
                      from_scene=top_mass_of),
}


def constants_of(scene, P: dict) -> dict:
    p = scene.plant
    return {"m1": p.m1, "m2": p.m2, "c": p.c, "g": p.gravity, "h01": P["h01"], "h11": P["h11"],
            "h02": P["h02"], "h12": P["h12"], "dref": P["dref"], "top_mass": P["top_mass"],
            "rate": scene.control_rate, "threshold": scene.effects.detector.threshold_n}


@jit(inline="always")
def force(slots, k, v, mem):
    m1, m2, c, g = k[K.m1], k[K.m2], k[K.c], k[K.g]
    h01, h11, h02, h12, dref = k[K.h01], k[K.h11], k[K.h02], k[K.h12], k[K.dref]
    phi, d, d_rate, x2, v2, detected = estimate(v, slots, k[K.top_mass], c, k[K.rate], k[K.threshold], mem)
    if not detected:
        return 0.0
    return m2 * (phi * (m1 + m2) / (m1 * m2) - g - h11 * d_rate - h01 * (d - dref)) - h12 * v2 - h02 * x2


def c_body(P: str, sl: dict[str, int]) -> str:
    return c_estimate(P, sl) + f"""
    /* thesis eq 4.3 (its derivative term corrected), gated by the detector */
    if (!detected) f = 0.0;
    else f = {P}_M2 * (phi * ({P}_M1 + {P}_M2) / ({P}_M1 * {P}_M2) - {P}_G - {P}_H11 * d_rate
                       - {P}_H01 * (d - {P}_DREF)) - {P}_H12 * v2 - {P}_H02 * x2;"""


LAW = Law("thesis-rig", "sensors", "eq 4.3 with its derivative term corrected, h12 = h02 = 0, only while the "
          "eq 4.4 detector reports contact; penetration from `Phi = m2' a2 + T` through c, its rate from "
          "successive samples; h01 = 2.3e6, h11 = 18 (sec 4.4)",
          SensorReads, Constants, constants_of, memory=MEMORY, params=PARAMS, c_body=c_body)
