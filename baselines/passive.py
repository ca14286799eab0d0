"""``passive``: no shaker force at all (the uncontrolled drop, thesis fig 4.8 'control off')."""

from __future__ import annotations

from baselines.base import Policy


class Passive(Policy):
    """Demands 0 N always.  Reads the sensor observation only to know the batch size."""

    name = "passive"
    observation = "sensors"
