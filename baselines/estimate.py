"""What the rig's sensors say about the contact (thesis sec 4.2), shared by the sensor-fed laws.

By Newton for the part of body 2 above the force transducer (mass m2'), the contact force is
``Phi = m2' a2 + T`` (eq 4.4's left side), from the accelerometer a2 (m/s^2, down positive) and
the transducer T (N, compression positive).  The penetration follows from the pad's Hertz law,
``d = (Phi_+ / c)^(2/3)`` (m), as the thesis inferred it ("penetration through c"), and its rate
from successive samples, ``(d[n] - d[n-1]) / T_s`` (m/s, T_s the control period), since no
sensor measures it.  Body 2's speed is likewise the backward difference of the potentiometer.
All of these see the readings after the scene's noise, filters and delays: the band-pass of
the rig removes the static load, so at rest the estimate reads zero, as on the rig (sec 4.2).

The arithmetic is written once, in the compiled kernel (``_estimate`` in
:mod:`impact_env.control.laws`), which the baselines call.
"""

from __future__ import annotations

# memory columns of a sensor-fed law: previous penetration estimate (m), previous x2 (m)
from impact_env.control.laws import MEMORY, PREV_D, PREV_X2

__all__ = ["MEMORY", "PREV_D", "PREV_X2"]
