"""``thesis-ideal``: the thesis's feedback-linearising law on the true state (thesis sec 2.4).

With ``y1 = x1 - x2`` (penetration, m), ``y2 = x2`` (m), the reference ``yR = d`` (the static
penetration ``(m1 g / c)^(2/3)``, eq 2.11) and ``dyR = ddyR = 0``:

* in contact (``y1 > 0``), eq 2.17::

      f2 = m2 (Phi(y1) (m1+m2)/(m1 m2) - g - h11 y1' - h01 (y1 - d)) - h12 y2' - h02 y2

* out of contact, the **corrected** eq 2.18 (eq 2.17 with Phi = 0)::

      f2 = m2 (-g - h11 y1' - h01 (y1 - d)) - h12 y2' - h02 y2

  As printed, eq 2.13/2.18 has ``h11 (yR' - y1') + h01 (yR - y1)``, which turns eq 2.10a into
  ``e'' = +h11 e' + h01 e``: unstable (thesis-notes erratum; ``free_law="printed"`` keeps the
  printed sign so that a test can show it diverge).

Both make the tracking error ``e = y1 - d`` obey ``e'' + h11 e' + h01 e = -(h12 y2' + h02 y2)/m2``
(eq 2.15 when h12 = h02 = 0; eq 2.19 prints the right side without the 1/m2).  Phi is the Hertz
law ``c y1^1.5`` of the controller's model (scene's c), also on scenes whose pad is damped.
Frame: x down, f2 up (the plant's).  Gains default to thesis sec 3.3.
"""

from __future__ import annotations

import numpy as np

from baselines.base import Param, Policy


class ThesisIdeal(Policy):
    name = "thesis-ideal"
    observation = "privileged"
    PARAMS = {
        "h01": Param(3.0e6, "1/s^2", "stiffness of the penetration error dynamics (sec 3.3)", lo=0.0),
        "h11": Param(400.0, "1/s", "damping of the penetration error dynamics (sec 3.3)", lo=0.0),
        "h02": Param(-3.0e4, "N/m", "force on body 2's position x2 (sec 3.3; negative = restoring)"),
        "h12": Param(-1000.0, "N s/m", "force on body 2's velocity (sec 3.3; negative = damping)"),
        "dref": Param(None, "m", "tracked penetration; default the static penetration (eq 2.11)", lo=0.0),
        "free_law": Param("corrected", "", "out-of-contact law: corrected eq 2.18, or the printed "
                          "(unstable) sign", choices=("corrected", "printed")),
    }

    def __init__(self, scene, **params):
        super().__init__(scene, **params)
        p = self.scene.plant
        self.m1, self.m2, self.c, self.g = p.m1, p.m2, p.c, p.gravity
        if self.params["dref"] is None:
            self.params["dref"] = p.static_penetration
        self._sign = 1.0 if self.params["free_law"] == "corrected" else -1.0

    def law_constants(self) -> dict[str, float]:
        P = self.params
        return {"m1": self.m1, "m2": self.m2, "c": self.c, "g": self.g, "h01": P["h01"], "h11": P["h11"],
                "h02": P["h02"], "h12": P["h12"], "dref": P["dref"], "sign": self._sign}

    def force_from_state(self, x1, v1, x2, v2):
        """The law on the true state (arrays or floats, SI, thesis frame) -> f2 in N (unclipped)."""
        cols = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (x1, v1, x2, v2)))
        shape = cols[0].shape
        values = np.stack([c.reshape(-1) for c in cols], axis=1)  # the privileged frame: x1, v1, x2, v2
        return self.force(values, None).reshape(shape)
