"""Drivers: what the target talks to.  :class:`RigDriver` is the interface a rig implements (a
DAQ card's analog inputs and output, the electromagnet's relay); :class:`VirtualRig` implements
it with the simulator's rig-physics stage, so the target can be proven without a rig.

The boundary is the DAQ card's: ``read()`` gives the raw readings of the current tick and
``apply(command)`` puts a drive command on the amplifier for one tick and returns the force
applied to body 2.  The command is dimensionless: 1.0 demands the scene's
``effects.command_scale`` newtons upwards, which is how the amplifier's input is calibrated (a
real driver turns it into volts with that calibration); keeping it dimensionless means a
command crosses the boundary unchanged, not divided and multiplied again.

A tick, as the target runs it (:mod:`impact_env.rig.target`): ``read`` -> controller (filters,
detector, observation, policy or the host's command, safety) -> ``apply``.  ``read`` after
``arm`` gives the readings at the release; each ``apply`` advances the rig by one control
period (``ticks`` periods when the target missed some: the command is held over them).
"""

from __future__ import annotations

import abc

import numpy as np
from gymnasium.utils import seeding

from impact_env.effects.sensors import N_CHANNELS
from impact_env.hardware import stage
from impact_env.hardware.batch import Hardware
from impact_env.rig.errors import RigError
from impact_env.scene import Scene, load_scene


class RigDriver(abc.ABC):
    """One rig.  ``scene`` describes it (control rate, command scale, the sensors' calibration:
    the target builds its front end from it); ``virtual`` is True for a simulated rig, which can
    also report the true state (:meth:`truth`).  Every method is called from the target's
    thread; none may block longer than a tick, except ``initialise``, ``arm`` and ``shutdown``."""

    scene: Scene
    virtual: bool = False

    @abc.abstractmethod
    def initialise(self) -> None:
        """Open the devices and put the output at zero."""

    @abc.abstractmethod
    def arm(self, seed: int) -> None:
        """Get a drop ready (body 1 held by the electromagnet, body 2 at rest); ``seed`` seeds a
        virtual rig's drop and noise, a physical rig may log it."""

    @abc.abstractmethod
    def release(self) -> None:
        """Drop body 1: tick 0 of the episode."""

    def hold(self) -> None:
        """This episode keeps body 1 on the electromagnet (identification episodes of kind
        shaker and quiet, :class:`impact_env.rig.protocol.EpisodeKind`): it starts with the next
        ``read`` and :meth:`release` is not called.  A physical rig needs nothing here."""

    def nominal_drop(self) -> None:
        """The coming release drops the scene's nominal body from its nominal height (an
        identification drop): a virtual rig draws no per-episode drop; on a physical rig the
        experimenter has put the identification body on the magnet (nothing to do here)."""

    @abc.abstractmethod
    def read(self) -> np.ndarray:
        """The raw readings of this tick: float64[4] = accelerometer (m/s^2, body 2, down
        positive), force transducer (N, compression positive), potentiometer (m, body 2's
        travel, down positive), body-1 sensor (m; NaN if the rig has none)."""

    @abc.abstractmethod
    def apply(self, command: float, ticks: int = 1) -> float:
        """Hold the drive ``command`` (1 = ``scene.effects.command_scale`` N up) for ``ticks``
        control periods; returns the force applied to body 2 (N), as measured or modelled."""

    @abc.abstractmethod
    def idle(self) -> None:
        """Zero the output (between episodes, on a fault, on a signal)."""

    @abc.abstractmethod
    def shutdown(self) -> None:
        """Zero the output and close the devices (idempotent)."""

    def error(self) -> str | None:
        """A fault the driver detected since the last call, or None."""
        return None

    def truth(self) -> np.ndarray | None:
        """The true state x1, v1, x2, v2 (m, m/s) of a virtual rig; None on a physical one."""
        return None


class VirtualRig(RigDriver):
    """A simulated rig: the rig-physics stage (:mod:`impact_env.hardware`) of one env of
    ``physics`` (default: ``scene``).  ``arm(seed)`` starts the drop ``ImpactCatch-v0`` reset
    with ``seed`` starts (randomised values, then sensor noise, from
    ``gymnasium.utils.seeding.np_random(seed)``).

    ``scene`` is the rig's description, what the target is told and builds its controller from;
    ``physics`` the hardware that runs, when it differs from the description (as every physical
    rig's does: identification and the mismatch map are tested on such rigs).  Both must have
    the same control rate."""

    virtual = True

    def __init__(self, scene: Scene | str = "rig", physics: Scene | str | None = None):
        self.scene = load_scene(scene)
        self.physics = self.scene if physics is None else load_scene(physics)
        if abs(self.physics.control_rate - self.scene.control_rate) > 1e-9 * self.scene.control_rate:
            raise ValueError(f"the virtual rig's physics runs at control.rate = {self.physics.control_rate:g} Hz, "
                             f"its description at {self.scene.control_rate:g} Hz: they must agree")
        self._hw_drawn = self.hw = Hardware(self.physics, 1)
        self._hw_nominal: Hardware | None = None
        self._u = np.zeros(1)
        self._armed = False
        self._fault: str | None = None
        self._seed = 0

    def initialise(self) -> None:
        """Compile (or load) the rig-physics kernels now, on a throwaway drop."""
        self._u[0] = 0.0
        self.hw.reset([seeding.np_random(0)[0]])
        self.apply(0.0)
        self._armed = False

    def arm(self, seed: int) -> None:
        self.hw = self._hw_drawn
        self._seed = int(seed)
        self.hw.reset([seeding.np_random(self._seed)[0]])
        self._armed = True

    @property
    def physics_toml(self) -> str:
        """The physics' TOML when it differs from the description (logged: a virtual rig's truth)."""
        return "" if self.physics is self.scene else self.physics.to_toml()

    def hold(self) -> None:
        self.hw.hold_body1(0)

    def nominal_drop(self) -> None:
        """The physics' nominal drop (its fixed m1 and drop; any other range is still drawn)."""
        if self._hw_nominal is None:
            rz: dict[str, list] = {k: [] for k in ("m1", "drop_height", "impact_speed")}
            self._hw_nominal = Hardware(self.physics.with_overrides({f"randomize.{k}": v for k, v in rz.items()}),
                                        1)
        self.hw = self._hw_nominal
        self.hw.reset([seeding.np_random(self._seed)[0]])

    def release(self) -> None:
        if not self._armed:
            raise RigError("release() before arm()")

    def read(self) -> np.ndarray:
        return self.hw.raw[0]

    def apply(self, command: float, ticks: int = 1) -> float:
        self._u[0] = command
        for _ in range(int(ticks)):
            self.hw.refill_noise(1)
            stage.hardware_step(self._u, self.hw.params, self.hw.state)
        if not self.hw.diverged()[0]:
            return float(self.hw.info[0, stage.INFO_F_APPLIED])
        self._fault = "the virtual rig's simulation diverged"
        return float("nan")

    def idle(self) -> None:
        self._u[0] = 0.0

    def shutdown(self) -> None:
        self._u[0] = 0.0
        self._armed = False

    def error(self) -> str | None:
        fault, self._fault = self._fault, None
        return fault

    def truth(self) -> np.ndarray:
        return self.hw.Y[0, :4]

    @property
    def last_info(self) -> np.ndarray:
        """The hardware's info row of the last tick (columns in :mod:`impact_env.hardware.stage`)."""
        return self.hw.info[0]


assert N_CHANNELS == 4  # the readings' layout the interface documents
