"""A classic law of the registry as DAgger's teacher (``agents.distill --teacher law:NAME``).

The teacher is a law of :data:`impact_env.control.laws.REGISTRY` (``mpc-state``, ``thesis-ideal``,
``pd-penetration``, ...), given as ``law:NAME[:KEY=VALUE,...]`` with the law's own gains
(``impact-env compare --list`` shows them).  It runs as it runs everywhere else: the compiled batch
kernel :func:`impact_env.control.laws.law_forces` on the frame of the entries it reads, with its
memory row per env zeroed at every episode start, once per control period.  DAgger reads that
frame from the newest frame of the ``"both"`` observation (the sensors and the true state), so a
privileged law sees the true state of the frames the student visits, and a sensor law the same
sensor readings as the student.  Its label is its command ``clip(f / command_scale, -1, 1)``, the
whole command: the student it teaches acts every control period with no residual law under it
(:func:`check_student_options` says so before any work starts).
"""

from __future__ import annotations

import numpy as np

from impact_env.config import ConfigError

PREFIX = "law:"


def law_names() -> tuple[str, ...]:
    """The laws a teacher may name: the compiled registry's, in its order."""
    from impact_env.control.laws import LAWS

    return LAWS


def is_law_teacher(spec) -> bool:
    return isinstance(spec, str) and spec.startswith(PREFIX)


def choices_text() -> str:
    return (f"law:NAME with NAME one of {', '.join(law_names())} (optionally law:NAME:KEY=VALUE,... with "
            "the law's gains), or the model.zip of a PPO teacher on observation 'privileged'")


def parse_teacher(spec: str) -> tuple[str, dict]:
    """(law name, gains) of ``law:NAME[:KEY=VALUE,...]``; ConfigError naming the choices."""
    from impact_env.policy.registry import parse_spec

    body = spec[len(PREFIX):]
    try:
        name, params = parse_spec(body) if body.strip() else ("", {})
    except ConfigError as exc:
        raise ConfigError(f"--teacher {spec!r}: {exc}") from None
    if name not in law_names():
        raise ConfigError(f"--teacher {spec!r}: {name!r} is not a compiled classic law; choose "
                          f"{choices_text()}")
    return name, params


def check_student_options(spec: str, hold_ticks: int, residual) -> None:
    """A law teacher acts every control period and labels the whole command: the student must too."""
    if int(hold_ticks) != 1:
        raise ConfigError(f"hold_ticks = {hold_ticks!r}: a law teacher ({spec}) runs every control period, "
                          "so its student acts every period too (hold_ticks 1)")
    if residual is not None and (not isinstance(residual, str) or residual.split(":")[0] not in law_names()):
        raise ConfigError(f"residual = {residual!r}: under a law teacher ({spec}) the residual is a compiled "
                          f"classic law, one of {', '.join(law_names())}, or None")


class LawTeacher:
    """Law ``spec`` on ``n`` envs whose observation frames are named ``frame_names`` (values divided
    by ``frame_scales``): :meth:`act` gives the commands of one control period, :meth:`start`
    clears the memory of envs whose episode starts."""

    def __init__(self, spec: str, scene, frame_names: tuple[str, ...], frame_scales: np.ndarray, n: int):
        from impact_env.control import laws
        from impact_env.policy.laws import LAW_POLICIES

        self.spec = spec
        self.name, params = parse_teacher(spec)
        policy = LAW_POLICIES[self.name](scene, **params)  # the gains checked, named in any error
        reads = policy.layout.names
        missing = [r for r in reads if r not in frame_names]
        if missing:
            raise ConfigError(f"--teacher {spec!r} reads {', '.join(missing)}, which the observation "
                              f"({', '.join(frame_names)}) does not hold")
        self.columns = np.array([frame_names.index(r) for r in reads], dtype=np.int64)
        self.scales = np.asarray(frame_scales, dtype=np.float64)[self.columns]
        self.kind = laws.KIND[self.name]
        self.slots = laws.law_slots(self.name, reads)
        self.constants = laws.constants_rows(self.name, policy.law_constants(), n)
        self.memory = np.zeros((n, laws.MEMORY))
        self.command_scale = float(scene.effects.command_scale)
        self._forces = np.empty(n)
        self._law_forces = laws.law_forces
        self._own = np.zeros(n)  # N, the demands of the last act (the ones its memory assumes applied)
        self._shaker_input = None
        if self.name == "mpc-state":  # its memory drives a model of the shaker with its own demands
            from impact_env.control.mpc.model import NZ, STATE, K
            from impact_env.control.mpc.solver import MEM
            from impact_env.control.mpc.solver import STATE as SOLVER_STATE

            row = self.constants[0]
            self._shaker_input = np.array([row[K.b0], row[K.b1], row[K.b2]])
            self._shaker_slots = SOLVER_STATE + STATE.z0 + np.arange(NZ)
            self._last_demand_slot = MEM.u_prev
            self._umax = float(row[K.umax])

    def start(self, rows: np.ndarray) -> None:
        """Episode start of envs ``rows`` (bool[n] or indices): their memory zeroed, as the
        simulator's loops and the rig's target zero it."""
        self.memory[rows] = 0.0

    def act(self, frames: np.ndarray) -> np.ndarray:
        """float64[n, 1]: the commands (fractions of the command scale, in [-1, 1]) on the newest
        frames ``frames[n, >= frame_size]`` (scaled as the env gives them)."""
        values = np.ascontiguousarray(frames[:, self.columns] * self.scales)
        f = self._law_forces(self.kind, self.slots, self.constants, values, self.memory, self._forces)
        self._own[:] = f
        return np.clip(f / self.command_scale, -1.0, 1.0)[:, None]

    def applied(self, commands: np.ndarray) -> None:
        """The commands (float[n, 1], fractions of the command scale) the envs applied after the last
        :meth:`act`.  A law whose memory models the effect of its own demands (``mpc-state``: the
        shaker's three states, driven linearly by the demand, and the slew limit's last demand)
        is moved onto the applied ones, so that its next labels are for the shaker the env has,
        not for the one its own commands would have made; other laws' memories do not depend on
        their output."""
        if self._shaker_input is None:
            return
        u = np.asarray(commands, dtype=np.float64)[:, 0] * self.command_scale
        u = np.clip(u, -self._umax, self._umax)
        self.memory[:, self._shaker_slots] += (u - self._own)[:, None] * self._shaker_input
        self.memory[:, self._last_demand_slot] = u


class ResidualLabel:
    """A law teacher over a residual law: its label is the teacher's command less the residual's
    on the same frame (clipped to [-1, 1]), so that the env's ``clip(action + residual)`` applies
    the teacher's command.  The residual's copy here runs on the observation's sensor entries
    (float32, as the env gives them), the env's own on its float64 readings: the two differ by
    that rounding only."""

    def __init__(self, teacher: LawTeacher, residual: LawTeacher):
        self.teacher, self.residual = teacher, residual

    def start(self, rows) -> None:
        self.teacher.start(rows)
        self.residual.start(rows)

    def act(self, frames: np.ndarray) -> np.ndarray:
        self._residual = self.residual.act(frames)
        return np.clip(self.teacher.act(frames) - self._residual, -1.0, 1.0)

    def applied(self, commands: np.ndarray) -> None:
        """The actions applied (over the residual law's command, as the env adds them)."""
        self.teacher.applied(np.clip(commands + self._residual, -1.0, 1.0))
        self.residual.applied(self._residual)
