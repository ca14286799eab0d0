"""Preset scenes.  Each is documented field by field where it departs from the defaults."""

from __future__ import annotations

from impact_env.scene import Scene


def ideal() -> Scene:
    """Thesis chapter 3: ideal conditions.  Elastic Hertz pad (sec 2.1: restitution 1), no
    suspension, no effects, the control law sampled at every integration step (1 us)."""
    return Scene(name="ideal", description="Thesis ch. 3: elastic Hertz contact, no suspension, "
                 "no effects, control at every 1 us integration step.")


PRESETS = {"ideal": ideal}


def rig() -> Scene:
    """Thesis chapter 4: the physical rig, every effect on, control at 10 kHz, 200 N pulses.

    Numbers the thesis does not give (see docs in each field and the README):
    * pad restitution 0.8 and a 16 Hz, 10 %-damped suspension of body 2 (k2 = 1e4 N/m,
      c2 = 20 N s/m): chosen so that an uncontrolled 50 mm drop keeps body 1's catch energy below
      1 % from about 0.33 s on, the thesis's 0.30-0.35 s (sec 4.4; measured with
      ``impact-env drop --scene rig --json``).  The thesis calls sylomer "quite damped" but gives
      no restitution; 0.8 is what the decay time asks for with this suspension.
    * horizon 0.4 s, so that the uncontrolled decay (about 0.33 s) is seen to its end.
    * control rate 10 kHz (notes' start value; dSPACE loops of the period ran at 10-20 kHz).
    """
    from impact_env.config import with_overrides

    base = Scene(name="rig", description="Thesis ch. 4: the shaker rig: pad restitution 0.8, "
                 "suspended body 2, shaker response, 200 N saturation, noisy 16-bit sensors, "
                 "20-1000 Hz filters, contact detector; control at 10 kHz.")
    return with_overrides(base, {
        "plant.restitution": 0.8,
        "plant.suspension_stiffness": 1.0e4,
        "plant.suspension_damping": 20.0,
        "control.rate": 1.0e4,
        "episode.horizon": 0.4,
        "effects.active": ["shaker", "saturation", "sensors", "filters", "detector"],
    })


PRESETS["rig"] = rig
