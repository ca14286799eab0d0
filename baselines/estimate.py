"""What the rig's sensors say about the contact (thesis sec 4.2), shared by the sensor-fed laws.

By Newton for the part of body 2 above the force transducer (mass m2'), the contact force is
``Phi = m2' a2 + T`` (eq 4.4's left side), from the accelerometer a2 (m/s^2, down positive) and
the transducer T (N, compression positive).  The penetration follows from the pad's Hertz law,
``d = (Phi_+ / c)^(2/3)`` (m), as the thesis inferred it ("penetration through c"), and its rate
from successive samples, ``(d[n] - d[n-1]) / T_s`` (m/s, T_s the control period), since no
sensor measures it.  Body 2's speed is likewise the backward difference of the potentiometer.
All of these see the readings after the scene's noise, filters and delays: the band-pass of
the rig removes the static load, so at rest the estimate reads zero, as on the rig (sec 4.2).
"""

from __future__ import annotations

import numpy as np

# memory columns of a sensor-fed law: previous penetration estimate (m), previous x2 (m)
PREV_D, PREV_X2 = 0, 1
MEMORY = 2


class ContactEstimate:
    """Per-sample estimates for a batch: ``phi`` (N), ``d`` (m), ``d_rate`` (m/s), ``x2`` (m),
    ``v2`` (m/s, down positive), ``detected`` (bool).  Updates the memory columns in place."""

    def __init__(self, policy, values: np.ndarray, memory: np.ndarray, top_mass: float):
        rate = policy.scene.control_rate
        a2 = policy.column(values, "accelerometer")
        t = policy.column(values, "force")
        self.x2 = policy.column(values, "potentiometer")
        self.phi = np.maximum(top_mass * a2 + t, 0.0)
        self.d = (self.phi / policy.scene.plant.c) ** (2.0 / 3.0)
        self.d_rate = (self.d - memory[:, PREV_D]) * rate
        self.v2 = (self.x2 - memory[:, PREV_X2]) * rate
        if "contact_detected" in policy.layout.names:
            self.detected = policy.column(values, "contact_detected") > 0.5
        else:  # no detector effect in the scene: apply eq 4.4 (level mode) here
            self.detected = top_mass * a2 + t > policy.scene.effects.detector.threshold_n
        memory[:, PREV_D] = self.d
        memory[:, PREV_X2] = self.x2
