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

from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.control.laws.law import Law, Param


class Reads(NamedTuple):
    """The privileged frame's true state."""

    x1: int
    v1: int
    x2: int
    v2: int


class Constants(NamedTuple):
    m1: float  # kg
    m2: float  # kg
    c: float  # N/m^1.5, the controller's Hertz law
    g: float  # m/s^2
    h01: float  # 1/s^2
    h11: float  # 1/s
    h02: float  # N/m
    h12: float  # N s/m
    dref: float  # m
    sign: float  # +1 the corrected eq 2.18, -1 the printed (unstable) sign


RD = positions(Reads)
K = positions(Constants)

PARAMS = {
    "h01": Param(3.0e6, "1/s^2", "stiffness of the penetration error dynamics (sec 3.3)", lo=0.0),
    "h11": Param(400.0, "1/s", "damping of the penetration error dynamics (sec 3.3)", lo=0.0),
    "h02": Param(-3.0e4, "N/m", "force on body 2's position x2 (sec 3.3; negative = restoring)"),
    "h12": Param(-1000.0, "N s/m", "force on body 2's velocity (sec 3.3; negative = damping)"),
    "dref": Param(None, "m", "tracked penetration; default the static penetration (eq 2.11)", lo=0.0,
                  from_scene=lambda scene: scene.plant.static_penetration),
    "free_law": Param("corrected", "", "out-of-contact law: corrected eq 2.18, or the printed "
                      "(unstable) sign", choices=("corrected", "printed")),
}


def constants_of(scene, P: dict) -> dict:
    p = scene.plant
    return {"m1": p.m1, "m2": p.m2, "c": p.c, "g": p.gravity, "h01": P["h01"], "h11": P["h11"],
            "h02": P["h02"], "h12": P["h12"], "dref": P["dref"],
            "sign": 1.0 if P["free_law"] == "corrected" else -1.0}


@jit(inline="always")
def force(slots, k, v, mem):
    m1, m2, c, g = k[K.m1], k[K.m2], k[K.c], k[K.g]
    h01, h11, h02, h12, dref, sign = k[K.h01], k[K.h11], k[K.h02], k[K.h12], k[K.dref], k[K.sign]
    x1 = v[slots[RD.x1]]
    v1 = v[slots[RD.v1]]
    x2 = v[slots[RD.x2]]
    v2 = v[slots[RD.v2]]
    y1 = x1 - x2
    e = y1 - dref
    de = v1 - v2
    if y1 > 0.0:
        phi = c * y1 * np.sqrt(y1)
        f = m2 * (phi * (m1 + m2) / (m1 * m2) - g - h11 * de - h01 * e)
    else:
        f = m2 * (-g - sign * (h11 * de + h01 * e))
    return f - h12 * v2 - h02 * x2


LAW = Law("thesis-ideal", "privileged", "eq 2.17 in contact, the **corrected** eq 2.18 out of contact (the "
          "printed sign diverges: tested); sec 3.3 gains h01 = 3e6, h11 = 400, h02 = -3e4, h12 = -1000",
          Reads, Constants, constants_of, params=PARAMS)
