"""The classic laws, compiled: each law exists once, in its module here (its docs, gains, the
scene's constants it needs, the observation entries it reads, its kernel and its C text), and
:data:`REGISTRY` lists them.  The policies by name (:mod:`impact_env.policy.laws`, and the
``baselines`` package's classes), the kind codes, the docs' table (:func:`markdown_table`) and the
tests' lists of laws are derived from it; the real-time target and the simulator's compiled loops
run :func:`law_force`, the baselines :func:`law_forces`, with no Python per call.

Every law computes a force demand f (N, upwards); the policy's command is ``clip(f /
command_scale, -1, 1)`` (:mod:`impact_env.control.policy`).  :func:`pack_law` turns a law's
constants (a dict by name) into the vector its kernel reads, and finds the slots of the
observation entries it reads (by name, so that any layout that has them works).

Adding a law: its module (``LAW = Law(...)``, ``force``, ``c_body``), its line in
:data:`REGISTRY` and its branch in :func:`law_force`, its test.
"""

from __future__ import annotations

import math

import numpy as np

from impact_env._jit import jit
from impact_env.config import ConfigError
from impact_env.control.laws import mpc, mpc_state, passive, pd_penetration, thesis_ideal, thesis_rig
from impact_env.control.laws.law import Law, Param

__all__ = ["BY_NAME", "CONSTANTS", "KIND", "LAWS", "MEMORY", "N_SLOTS", "READS", "REGISTRY", "Law", "Param",
           "constants_rows", "law_force", "law_forces", "law_slots", "markdown_table", "pack_law"]

#: every classic law; a law's place here is its kind code
REGISTRY: tuple[Law, ...] = (passive.LAW, thesis_ideal.LAW, thesis_rig.LAW, pd_penetration.LAW, mpc_state.LAW,
                             mpc.LAW)
BY_NAME = {law.name: law for law in REGISTRY}
LAWS = tuple(BY_NAME)
KIND = {name: k for k, name in enumerate(LAWS)}
CONSTANTS = {law.name: tuple(law.constants._fields) for law in REGISTRY}
#: the observation entries each law reads (an optional one may be absent)
READS = {law.name: tuple(law.reads._fields) for law in REGISTRY}
#: the slot table's length in a packed policy (the most entries a law reads)
N_SLOTS = max(len(r) for r in READS.values())
#: the memory row every packed law gets (the most a law keeps)
MEMORY = max(law.memory for law in REGISTRY)

_THESIS_IDEAL = KIND[thesis_ideal.LAW.name]
_THESIS_RIG = KIND[thesis_rig.LAW.name]
_PD_PENETRATION = KIND[pd_penetration.LAW.name]
_MPC_STATE = KIND[mpc_state.LAW.name]
_MPC = KIND[mpc.LAW.name]


@jit(inline="always")
def law_force(kind, slots, k, v, mem):
    """The force demand (N, upwards) of law ``kind`` with constants ``k`` on the frame values
    ``v`` (float64, SI units) read at ``slots``; ``mem`` is its memory row.  Passive: 0."""
    if kind == _THESIS_IDEAL:
        return thesis_ideal.force(slots, k, v, mem)
    if kind == _THESIS_RIG:
        return thesis_rig.force(slots, k, v, mem)
    if kind == _PD_PENETRATION:
        return pd_penetration.force(slots, k, v, mem)
    if kind == _MPC_STATE:
        return mpc_state.force(slots, k, v, mem)
    if kind == _MPC:
        return mpc.force(slots, k, v, mem)
    return 0.0


@jit
def law_forces(kind, slots, constants, values, mem, out):
    """:func:`law_force` for every row i (constants ``constants[i]``, frame values ``values[i]`` in
    SI units, memory ``mem[i]`` of at least the law's ``memory`` floats) into ``out[i]``: the
    Python policies' (:mod:`impact_env.policy.laws`) face of the same kernel."""
    for i in range(values.shape[0]):
        out[i] = law_force(kind, slots, constants[i], values[i], mem[i])
    return out


def _law(name: str) -> Law:
    if name not in BY_NAME:
        raise ConfigError(f"compiled law {name!r} is not one of {', '.join(LAWS)}")
    return BY_NAME[name]


def law_slots(name: str, names: tuple[str, ...]) -> np.ndarray:
    """int64[N_SLOTS]: where law ``name`` finds each entry it reads (:data:`READS`, in order) in an
    observation frame whose entries are ``names``; -1 where an optional entry is absent (and
    after its reads); ConfigError naming what is missing."""
    law = _law(name)
    missing = [r for r in law.required() if r not in names]
    if missing:
        raise ConfigError(f"law {name!r} reads {', '.join(missing)}, which the observation "
                          f"({', '.join(names)}) does not hold")
    slots = np.full(N_SLOTS, -1, dtype=np.int64)
    for j, entry in enumerate(READS[name]):
        slots[j] = names.index(entry) if entry in names else -1
    return slots


def constants_rows(name: str, constants: dict, n: int) -> np.ndarray:
    """float64[n, k]: law ``name``'s constants vector for each of n envs (a constant may be a
    number or an array over the envs, as the policies' gains are)."""
    keys = CONSTANTS[name]
    out = np.empty((n, len(keys)))
    for j, key in enumerate(keys):
        if key not in constants:
            raise ConfigError(f"law {name!r} needs the constant {key!r}")
        v = constants[key]
        if isinstance(v, (float, int)):  # the usual case: predict() is called per step
            out[:, j] = v
        else:
            out[:, j] = np.broadcast_to(np.asarray(v, dtype=np.float64), (n,))
    return out


def pack_law(name: str, constants: dict[str, float],
             names: tuple[str, ...]) -> tuple[int, np.ndarray, np.ndarray]:
    """(kind code, int64 slots, float64 constants) of law ``name`` for an observation frame whose
    entries are ``names``; ConfigError naming what is missing or not finite."""
    slots = law_slots(name, names)
    vals = []
    for key in CONSTANTS[name]:
        if key not in constants:
            raise ConfigError(f"law {name!r} needs the constant {key!r}")
        v = float(constants[key])
        if not math.isfinite(v):
            raise ConfigError(f"law {name!r}: constant {key} = {v!r} must be finite")
        vals.append(v)
    return KIND[name], slots, np.array(vals, dtype=np.float64)


def markdown_table() -> str:
    """The docs' table of laws (docs/baselines.md, between its ``laws-table`` markers)."""
    obs = {"sensors": "sensors", "privileged": "privileged (true state)"}
    rows = ["| name | observation | law |", "| --- | --- | --- |"]
    rows += [f"| `{law.name}` | {obs[law.observation]} | {law.doc} |" for law in REGISTRY]
    return "\n".join(rows)
