"""``pd-penetration``: a PD loop on the estimated pad compression, the first thing a control
engineer would try on this rig.

    f2 = -m2 (kp (d - dref) + kd d')     while contact is detected,  0 otherwise

with the penetration d (m) and its rate d' (m/s) estimated from body 2's accelerometer and force
transducer exactly as for ``thesis-rig`` (:mod:`impact_env.control.laws.estimate`), the same detector gate,
and no model of the contact law: compared with eq 4.3 it drops the feedforward
``Phi (m1+m2)/(m1 m2) - g`` that cancels the pad.  ``f2 < 0`` pulls body 2 down, away from
body 1: the shaker gives way while the pad is compressed (``kp``) and while the compression
grows (``kd``), i.e. it makes the pad look softer and damped to body 1.  Gains are per unit
mass of body 2 (kp in 1/s^2, kd in 1/s), like the thesis's h01 and h11.

Tuning (how the defaults were chosen): minimise ``energy_integral_ms``, the time integral of
body 1's catch-energy ratio over a 0.3 s episode (minus the env's return with its default
reward), on the ``rig`` scene with its 200 N limit, over a 14 x 14 log grid::

    impact-env sweep --scene rig --policy pd-penetration --grid kp=1e4:3e6:14 --grid kd=30:5000:14 \
        --log --t-end 0.3 --limit scene --objective energy_integral_ms --out sweep-pd

Best pair kp = 2.157e5 1/s^2, kd = 318 1/s (7.6 ms against 65 ms uncontrolled), rounded to the
defaults below; checked on 30 seeded episodes with ``impact-env compare`` (README, "Baselines and
comparison").  The fastest catch on that grid is kp = 1.34e5, kd = 1786 (body 1's energy below
1 % for good after 0.091 s, against 0.142 s with the defaults), at a higher energy integral.
"""

from __future__ import annotations

from typing import NamedTuple

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.control.laws.estimate import MEMORY, SensorReads, c_estimate, estimate, top_mass_of
from impact_env.control.laws.law import Law, Param


class Constants(NamedTuple):
    m2: float  # kg
    c: float  # N/m^1.5
    kp: float  # 1/s^2
    kd: float  # 1/s
    dref: float  # m
    top_mass: float  # kg, m2' of eq 4.4
    rate: float  # Hz, the control rate
    threshold: float  # N, eq 4.4's level when the observation has no detector bit


K = positions(Constants)

PARAMS = {
    "kp": Param(2.2e5, "1/s^2", "proportional gain on the estimated penetration, per kg of m2", lo=0.0),
    "kd": Param(320.0, "1/s", "derivative gain on the estimated penetration rate, per kg of m2", lo=0.0),
    "dref": Param(0.0, "m", "penetration the loop holds (0: the estimate reads 0 at rest)", lo=0.0),
    "top_mass": Param(None, "kg", "m2' in Phi = m2' a2 + T; default effects.sensors.force.top_mass", lo=0.0,
                      from_scene=top_mass_of),
}


def constants_of(scene, P: dict) -> dict:
    return {"m2": scene.plant.m2, "c": scene.plant.c, "kp": P["kp"], "kd": P["kd"], "dref": P["dref"],
            "top_mass": P["top_mass"], "rate": scene.control_rate,
            "threshold": scene.effects.detector.threshold_n}


@jit(inline="always")
def force(slots, k, v, mem):
    m2, c, kp, kd, dref = k[K.m2], k[K.c], k[K.kp], k[K.kd], k[K.dref]
    phi, d, d_rate, x2, v2, detected = estimate(v, slots, k[K.top_mass], c, k[K.rate], k[K.threshold], mem)
    if not detected:
        return 0.0
    return -m2 * (kp * (d - dref) + kd * d_rate)


def c_body(P: str, sl: dict[str, int]) -> str:
    return c_estimate(P, sl) + f"""
    (void)v2;
    /* PD on the penetration's error, gated by the detector */
    if (!detected) f = 0.0;
    else f = -{P}_M2 * ({P}_KP * (d - {P}_DREF) + {P}_KD * d_rate);"""


LAW = Law("pd-penetration", "sensors", "`f2 = -m2 (kp d + kd d')` on the same estimate and gate, no contact "
          "model; kp = 2.2e5 1/s^2, kd = 320 1/s, tuned with the sweep below on the nominal drop "
          "(`impact_env/control/laws/pd_penetration.py` says how)",
          SensorReads, Constants, constants_of, memory=MEMORY, params=PARAMS, c_body=c_body)
