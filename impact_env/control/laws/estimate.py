"""What the rig's sensors say about the contact (thesis sec 4.2), shared by the sensor-fed laws.

By Newton for the part of body 2 above the force transducer (mass m2'), the contact force is
``Phi = m2' a2 + T`` (eq 4.4's left side), from the accelerometer a2 (m/s^2, down positive) and
the transducer T (N, compression positive).  The penetration follows from the pad's Hertz law,
``d = (Phi_+ / c)^(2/3)`` (m), as the thesis inferred it ("penetration through c"), and its rate
from successive samples, ``(d[n] - d[n-1]) / T_s`` (m/s, T_s the control period), since no
sensor measures it.  Body 2's speed is likewise the backward difference of the potentiometer.
All of these see the readings after the scene's noise, filters and delays: the band-pass of
the rig removes the static load, so at rest the estimate reads zero, as on the rig (sec 4.2).
Without the detector's bit in the observation, eq 4.4 (level mode, the scene's threshold) is
applied here.  The kernel (:func:`estimate`) and its C text (:func:`c_estimate`) sit together.
"""

from __future__ import annotations

from typing import NamedTuple

from impact_env._jit import jit
from impact_env._packed import positions


class Memory(NamedTuple):
    """A sensor-fed law's memory row (starts at 0)."""

    prev_d: float  # the previous penetration estimate, m
    prev_x2: float  # the previous potentiometer reading, m


MEM = positions(Memory)
MEMORY = len(MEM)


class SensorReads(NamedTuple):
    """The observation entries a sensor-fed law reads (its slots, in this order)."""

    accelerometer: int
    force: int
    potentiometer: int
    contact_detected: int = -1  # absent: eq 4.4 is applied here


SR = positions(SensorReads)


@jit(inline="always")
def estimate(v, slots, top, c, rate, threshold, mem):
    """(phi N, d m, d' m/s, x2 m, v2 m/s, detected) from the frame values ``v`` (SI) read at
    ``slots`` (:class:`SensorReads`); updates ``mem`` (:class:`Memory`)."""
    a2 = v[slots[SR.accelerometer]]
    t = v[slots[SR.force]]
    x2 = v[slots[SR.potentiometer]]
    s = top * a2 + t
    phi = s if s > 0.0 else 0.0
    d = (phi / c) ** (2.0 / 3.0)
    d_rate = (d - mem[MEM.prev_d]) * rate
    v2 = (x2 - mem[MEM.prev_x2]) * rate
    if slots[SR.contact_detected] >= 0:
        detected = v[slots[SR.contact_detected]] > 0.5
    else:
        detected = top * a2 + t > threshold
    mem[MEM.prev_d] = d
    mem[MEM.prev_x2] = x2
    return phi, d, d_rate, x2, v2, detected


def c_estimate(P: str, sl: dict[str, int]) -> str:
    """:func:`estimate` in C (the law's constants ``{P}_TOP_MASS``, ``{P}_C``, ``{P}_RATE``,
    ``{P}_THRESHOLD``; ``sl``: each read's slot in the frame ``v``)."""
    top, c, rate, thr = (f"{P}_TOP_MASS", f"{P}_C", f"{P}_RATE", f"{P}_THRESHOLD")
    det = (f"v[{sl['contact_detected']}] > 0.5" if sl["contact_detected"] >= 0
           else f"{top} * a2 + t > {thr}")
    return f"""
    /* the contact force by thesis eq 4.4, the penetration by Hertz (Phi = c d^1.5), their rates */
    impact_real a2 = v[{sl['accelerometer']}], t = v[{sl['force']}], x2 = v[{sl['potentiometer']}];
    impact_real sig = {top} * a2 + t;
    impact_real phi = sig > 0.0 ? sig : 0.0;
    impact_real d = R_POW(phi / {c}, (impact_real)(2.0 / 3.0));
    impact_real d_rate = (d - mem[{MEM.prev_d}]) * {rate};
    impact_real v2 = (x2 - mem[{MEM.prev_x2}]) * {rate};
    int detected = {det};
    mem[{MEM.prev_d}] = d;
    mem[{MEM.prev_x2}] = x2;"""


def top_mass_of(scene) -> float:
    """The default m2': the scene's force transducer's."""
    return float(scene.effects.sensors.force.top_mass)
