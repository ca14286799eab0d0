"""Virtual rigs nobody tuned for: a scene's hardware moved away from its description, from a seed.

:func:`perturbed_physics` gives the physics of a virtual rig (``rig serve --virtual --physics``)
whose every identifiable hardware number is the base's times a factor drawn log-uniformly in
``[1/(1 + spread), 1 + spread]`` (``spread`` 0.4: +-40 %), the sensors' offsets drawn around 0,
and optionally whole-tick delays; its drop is fixed (the identification body from the base's
drop height).  The identification is tested and demonstrated on such rigs
(``tests/test_identify.py``, ``scripts/identify_virtual.py``).
"""

from __future__ import annotations

import math

import numpy as np

from impact_env.config import get_dotted, with_overrides
from impact_env.scene import Scene, load_scene

# the fields moved, and the largest value each may take (the restitution stays a restitution)
MOVED = ("plant.m1", "plant.m2", "plant.c", "plant.restitution", "plant.suspension_stiffness",
         "plant.suspension_damping", "effects.command_scale", "effects.shaker.highpass_hz",
         "effects.shaker.lowpass_hz", "effects.shaker.coil_inductance", "effects.sensors.force.top_mass",
         "effects.sensors.accelerometer.noise_std", "effects.sensors.force.noise_std",
         "effects.sensors.potentiometer.noise_std")
CAP = {"plant.restitution": 0.97}
# offsets drawn N(0, s) in each channel's unit: a few noise levels
OFFSET_STD = {"accelerometer": 0.3, "force": 0.2, "potentiometer": 2e-5}


def perturbed_physics(base: Scene | str = "rig", seed: int = 0, spread: float = 0.4,
                      actuator_delay_ticks: int = 0, sensor_delay_ticks: int = 0) -> tuple[Scene, dict]:
    """(the physics scene, the true values of the moved fields) for ``seed`` (module doc)."""
    base = load_scene(base)
    rng = np.random.default_rng(seed)
    lo, hi = math.log(1.0 / (1.0 + spread)), math.log(1.0 + spread)
    truth: dict = {}
    for f in MOVED:
        v = float(get_dotted(base, f)) * math.exp(rng.uniform(lo, hi))
        truth[f] = min(v, CAP.get(f, math.inf))
    for ch, s in OFFSET_STD.items():
        truth[f"effects.sensors.{ch}.offset"] = float(s * rng.standard_normal())
    ov: dict = dict(truth)
    ov["randomize"] = {}  # one body, one height: an identification drop is the same every time
    active = list(base.effects.active)
    rate = base.control_rate
    for k, eff, key in ((actuator_delay_ticks, "actuator_delay", "actuator_s"),
                        (sensor_delay_ticks, "sensor_delay", "sensor_s")):
        if k:
            truth[f"effects.delay.{key}"] = k / rate
            ov[f"effects.delay.{key}"] = k / rate
            if eff not in active:
                active.append(eff)
    ov["effects.active"] = active
    ov["name"] = f"{base.name}-perturbed-{seed}"

    return with_overrides(base, ov, parse=False), truth
