"""``thesis-rig``: the law that ran on the rig (thesis sec 4.2, eq 4.3), fed by its sensors only.

    f2 = m2 (Phi (m1+m2)/(m1 m2) - g - h11 d' - h01 (d - dref)) - h12 v2 - h02 x2   while contact is detected
    f2 = 0                                                                           otherwise

with Phi, the penetration d and its rate d' estimated from body 2's accelerometer and force
transducer (:mod:`baselines.estimate`), x2 from the potentiometer and v2 its difference.

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

import numpy as np

from baselines.base import Param, Policy
from baselines.estimate import MEMORY


class ThesisRig(Policy):
    name = "thesis-rig"
    observation = "sensors"
    memory_size = MEMORY
    PARAMS = {
        "h01": Param(2.3e6, "1/s^2", "stiffness of the penetration error dynamics (sec 4.4)", lo=0.0),
        "h11": Param(18.0, "1/s", "damping of the penetration error dynamics (sec 4.4)", lo=0.0),
        "h02": Param(0.0, "N/m", "force on body 2's position (0 on the rig)"),
        "h12": Param(0.0, "N s/m", "force on body 2's velocity (0 on the rig)"),
        "dref": Param(0.0, "m", "tracked penetration (0 on the rig, sec 4.2)", lo=0.0),
        "top_mass": Param(None, "kg", "m2' in Phi = m2' a2 + T; default effects.sensors.force.top_mass",
                          lo=0.0),
    }

    def __init__(self, scene, **params):
        super().__init__(scene, **params)
        p = self.scene.plant
        self.m1, self.m2, self.g = p.m1, p.m2, p.gravity
        if self.params["top_mass"] is None:
            self.params["top_mass"] = float(self.scene.effects.sensors.force.top_mass)
        for ch in ("accelerometer", "force", "potentiometer"):
            self.column(np.zeros((1, self.layout.frame_size)), ch)  # fail at construction, not mid-run

    def law_constants(self) -> dict[str, float]:
        P = self.params
        return {"m1": self.m1, "m2": self.m2, "c": self.scene.plant.c, "g": self.g, "h01": P["h01"],
                "h11": P["h11"], "h02": P["h02"], "h12": P["h12"], "dref": P["dref"],
                "top_mass": P["top_mass"], "rate": self.scene.control_rate,
                "threshold": self.scene.effects.detector.threshold_n}
