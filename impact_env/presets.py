"""Preset scenes.  Each is documented field by field where it departs from the defaults."""

from __future__ import annotations

from impact_env.scene import Scene


def ideal() -> Scene:
    """Thesis chapter 3: ideal conditions.  Elastic Hertz pad (sec 2.1: restitution 1), no
    suspension, no effects, the control law sampled at every integration step (1 us)."""
    return Scene(name="ideal", description="Thesis ch. 3: elastic Hertz contact, no suspension, "
                 "no effects, control at every 1 us integration step.")


PRESETS = {"ideal": ideal}
