"""The scene fuzz: random values (extreme, non-finite, wrong types, unknown choices) in random
fields of a preset, then everything a user's first call builds.

One case: a preset (``ideal``, ``rig``, ``rig-randomized`` or ``rig`` with every effect on),
one to three fields set to drawn values, then

1. the scene (``load_scene``), which either builds or raises ConfigError naming one of the
   fields set;
2. ``Simulator(scene, 1)``, a reset and one step; an ``ImpactCatchEnv`` on the scene, a reset
   and one step: these either run, with finite observations and reward, or raise ConfigError
   before simulating (the step checks of :mod:`impact_env.hardware.stability`, which name
   ``integrator.dt`` and the plant's fields).

Any other exception, a rejection that names none of the fields set, or a non-finite
observation is a failure.  :func:`outcome` classifies one case; ``tests/test_fuzz_scene.py``
draws the cases with hypothesis; ``python tests/fuzz_scene.py N`` runs N cases and prints the
figures.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import types
import typing
from collections import Counter

import numpy as np
from hypothesis import strategies as st

from impact_env.config import ConfigError
from impact_env.effects.filters import KINDS
from impact_env.scene import Scene, load_scene
from impact_env.scene.effects import EFFECTS
from impact_env.scene.scene import METHODS

PRESETS = ("ideal", "rig", "rig-randomized", "rig-all")
ALL = {"effects.active": list(EFFECTS)}
CHOICES = {"method": METHODS, "model": ("coil", "measured"), "amplifier": ("voltage", "current"),
           "kind": KINDS}
SPECIAL_FLOATS = [0.0, -0.0, -1.0, 1e-300, 1e-30, 1e-12, 1e-9, 1e-6, 1e-3, 0.5, 1.0, 2.0, 10.0, 1e3,
                  1e6, 1e9, 1e12, 1e15, 1e30, 1e100, 1e300, 1.7e308, -1e300, math.inf, -math.inf,
                  math.nan]


def leaf_fields(cls=Scene, prefix=""):
    """(dotted key, type, field name, default) of every leaf field of the scene."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        key = f"{prefix}.{f.name}" if prefix else f.name
        tp = hints[f.name]
        sub = f.default_factory if f.default_factory is not dataclasses.MISSING else None
        if sub is not None and dataclasses.is_dataclass(sub):
            yield from leaf_fields(sub, key)
        else:
            yield key, tp, f.name, f.default


FIELDS = list(leaf_fields())

floats = st.one_of(st.sampled_from(SPECIAL_FLOATS),
                   st.floats(allow_nan=True, allow_infinity=True),
                   st.floats(-1e4, 1e4), st.floats(1e-12, 1e-2))


FACTORS = [1e-9, 1e-6, 1e-3, 0.1, 0.5, 0.9, 1.1, 2.0, 10.0, 1e3, 1e6, 1e9]


def values_for(tp, name: str, default=None):
    """A strategy of values for a field of type ``tp``: extreme, non-finite and wrong-typed
    values, and (for a float with a nonzero default) the default scaled by 1e-9 .. 1e9."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in typing.get_args(tp) if a is not type(None)][0]
        return st.one_of(st.none(), values_for(inner, name, default))
    if origin is tuple:
        (inner, *_rest) = typing.get_args(tp)
        if inner is str:
            return st.lists(st.sampled_from(list(EFFECTS) + ["bogus", ""]), max_size=8)
        return st.lists(floats, max_size=4)
    if tp is float:
        near = [st.sampled_from(FACTORS).map(lambda f: f * default)] \
            if isinstance(default, float) and default != 0.0 else []
        return st.one_of(*near, *near, floats, st.integers(-3, 3), st.text(max_size=3), st.booleans())
    if tp is int:
        return st.one_of(st.integers(-5, 40), st.sampled_from([-10**9, 10**9, 10**30]), st.floats(-5, 40),
                         st.booleans())
    if tp is bool:
        return st.one_of(st.booleans(), st.integers(0, 2), st.text(max_size=3))
    if tp is str:
        choices = CHOICES.get(name, ())
        named = st.sampled_from(list(choices) + ["", "nonsense"]) if choices else st.text(max_size=8)
        return st.one_of(named, st.integers(0, 3))
    raise AssertionError(f"no strategy for {tp!r}")


def _setting(field):
    key, tp, name, default = field
    return st.tuples(st.just(key), values_for(tp, name, default))


cases = st.tuples(
    st.sampled_from(PRESETS),
    st.lists(st.sampled_from(FIELDS).flatmap(_setting), min_size=1, max_size=3, unique_by=lambda kv: kv[0]),
)


def outcome(preset: str, sets: list[tuple[str, object]]) -> tuple[str, str]:
    """Run one case; returns (kind, detail) with kind one of ``built`` (ran to the end),
    ``rejected`` (scene construction refused it, naming a field set), ``refused`` (refused
    before simulating by the step checks), or ``FAILED``."""
    from impact_env.env.catch_env import ImpactCatchEnv
    from impact_env.sim.simulator import Simulator

    keys = [k for k, _ in sets]
    ov = dict(sets)
    base = ("rig", ALL) if preset == "rig-all" else (preset, {})
    try:
        scene = load_scene(load_scene(base[0], base[1]), ov)
    except ConfigError as exc:
        if any(k in str(exc) for k in keys):
            return "rejected", str(exc)
        return "FAILED", f"ConfigError naming none of {keys}: {exc}"
    except Exception as exc:  # noqa: BLE001  (the point: no other exception)
        return "FAILED", f"{type(exc).__name__} building the scene with {ov}: {exc}"
    try:
        sim = Simulator(scene, 1)
        sim.reset([np.random.default_rng(0)])
        sim.step(np.array([0.5]))
        env = ImpactCatchEnv(scene)
        obs, _ = env.reset(seed=0)
        obs2, r, *_ = env.step(np.array([0.5], dtype=np.float32))
    except ConfigError as exc:
        msg = str(exc)
        if "integrator.dt" in msg and any(k in msg for k in keys + ["plant.", "initial.", "randomize."]):
            return "refused", msg
        if any(k in msg for k in keys):
            return "FAILED", f"late ConfigError (after the scene was built) for {ov}: {msg}"
        return "FAILED", f"late ConfigError naming none of {keys}: {msg}"
    except Exception as exc:  # noqa: BLE001
        return "FAILED", f"{type(exc).__name__} after building the scene with {ov}: {exc}"
    if not (np.all(np.isfinite(obs)) and np.all(np.isfinite(obs2)) and math.isfinite(r)):
        return "FAILED", f"non-finite observation or reward with {ov}"
    return "built", ""


def main(n: int) -> int:
    """Run n cases drawn by hypothesis and print the figures."""
    from hypothesis import HealthCheck, given, settings

    counts: Counter = Counter()
    failures: list[str] = []

    @settings(max_examples=n, deadline=None, database=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(case=cases)
    def run(case):
        kind, detail = outcome(*case)
        counts[kind] += 1
        if kind == "FAILED":
            failures.append(detail)

    run()
    total = sum(counts.values())
    print(f"cases tried: {total}; built and stepped: {counts['built']}; rejected at scene construction "
          f"naming the field: {counts['rejected']}; refused before simulating (step checks, naming "
          f"integrator.dt and the drop): {counts['refused']}; tracebacks or unnamed rejections: "
          f"{counts['FAILED']}")
    for f in failures[:20]:
        print("  " + f)
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main(int(sys.argv[1]) if len(sys.argv) > 1 else 500))
