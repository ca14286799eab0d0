"""Drivers for the tests of the physical rig's path (``impact-env rig serve --driver
tests.rig_drivers:BlindRig``): no physical rig is on our machines, so the physical path is
exercised with the virtual rig's physics seen only through the DAQ card's boundary."""

from __future__ import annotations

import numpy as np

from impact_env.rig.driver import RigDriver, VirtualRig


class BlindRig(RigDriver):
    """The virtual rig as the target would see a physical one: ``virtual = False``, no truth, only
    ``read`` and ``apply``.  The target's loop then calls them through callbacks, the host gets no
    reward, and the episode's metrics come from the log's estimate (thesis eq 4.5)."""

    virtual = False

    def __init__(self, scene="rig"):
        self._rig = VirtualRig(scene)
        self.scene = self._rig.scene
        self.calls = {"read": 0, "apply": 0, "idle": 0}

    def initialise(self) -> None:
        self._rig.initialise()

    def arm(self, seed: int) -> None:
        self._rig.arm(seed)

    def release(self) -> None:
        self._rig.release()

    def read(self) -> np.ndarray:
        self.calls["read"] += 1
        return self._rig.read().copy()

    def apply(self, command: float, ticks: int = 1) -> float:
        self.calls["apply"] += 1
        return self._rig.apply(command, ticks)

    def idle(self) -> None:
        self.calls["idle"] += 1
        self._rig.idle()

    def shutdown(self) -> None:
        self._rig.shutdown()

    def error(self) -> str | None:
        return self._rig.error()


class NotADriver:
    """For the CLI's error: a class that is not a RigDriver."""

    def __init__(self, scene):
        self.scene = scene
