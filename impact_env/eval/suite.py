"""Benchmark suites: named, versioned sets of held-out drops (``impact-env benchmark --suite``).

A suite is a list of drop sets, each a scene (a preset with overrides) and a fixed run of
seeds: drop ``j`` of a set is seeded ``seed + j``, as ``compare --seed`` seeds its episodes.  A
suite never changes once published: a change of scene, seeds or drops is a new version
(``catch-v2``), so a record of ``catch-v1`` stays comparable with every other.

Held-out seeds.  Every seed of a suite lies in :data:`HELD_OUT`, above every seed that the
agents of ``agents/`` train on (below 1000: ``agents.train``), validate on (900 000 - 900 015)
or are tested on (1000 - 1099, the agents' report), and apart from ``compare``'s old default
(0 - 99) and README's main job (:data:`README_SEED`); ``tests/test_benchmark.py`` checks it
against ``agents/``'s own constants and the shipped models' records.

``catch-v1`` (:data:`SUITES`): four sets of :data:`CATCH_V1_DROPS` (20) drops each, 80 in all.
The size is set by the oracle, which searches every drop once (about 3-4 s of CPU per drop on
an idle core, 7-10 min for the suite on two; then cached): the leaderboard itself (the classic
laws, the shipped agents and the replayed oracle) then runs in a few minutes on a 2-core
machine (the record says how long); the overall figures pool the 80 drops (stratified), and
every figure carries its interval, which says what 20 drops per set resolve:

* ``rig``: the thesis rig (ch. 4), drops of 0.08-0.12 kg from 30-70 mm, sensor noise;
* ``rig-randomized``: the rig with its hardware uncertain too (``rig-randomized``'s ranges);
* ``hard``: ``rig-randomized`` with light and heavy bodies and high drops: 0.04-0.25 kg from
  70-150 mm (the force limit and the pad are the rig's);
* ``ideal``: thesis ch. 3's plant (elastic contact, no suspension, no effects), drops of
  0.08-0.12 kg from 30-70 mm so that the drops differ, controlled at 10 kHz and integrated with
  the project's default method (``split``: exact free flight, dopri5 in contact) instead of the
  preset's RK4 at 1 us with control at every step, which costs about 100 times more per drop.
  It has no contact detector, so the policies that read one (the shipped agents) are left out
  of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from impact_env.config import ConfigError
from impact_env.scene import Scene, load_scene

HELD_OUT = range(7_000_000, 8_000_000)  # every suite's seeds lie here (module doc)
README_SEED = 5_000_000  # README's main job: compare --seed 5000000 (100 drops), held out too
CATCH_V1_DROPS = 20


@dataclass(frozen=True)
class DropSet:
    """One set of a suite: ``drops`` drops of ``scene`` (with ``overrides``), seeded ``seed + j``."""

    name: str
    scene: str
    seed: int
    drops: int
    doc: str
    overrides: tuple[tuple[str, Any], ...] = ()

    @property
    def seeds(self) -> range:
        return range(self.seed, self.seed + self.drops)

    def build_scene(self) -> Scene:
        scene = load_scene(self.scene, dict(self.overrides))
        return scene

    def describe(self) -> dict:
        return {"name": self.name, "scene": self.scene, "overrides": dict(self.overrides), "seed": self.seed,
                "drops": self.drops, "doc": self.doc}


@dataclass(frozen=True)
class Suite:
    """A named, versioned list of drop sets, and the reference policy its records compare with."""

    name: str
    version: int
    sets: tuple[DropSet, ...]
    doc: str
    reference: str = "thesis-rig"

    def describe(self) -> dict:
        return {"name": self.name, "version": self.version, "doc": self.doc, "reference": self.reference,
                "sets": [s.describe() for s in self.sets]}


def _catch_v1() -> Suite:
    n = CATCH_V1_DROPS
    drops = (("randomize.m1", [0.08, 0.12]), ("randomize.drop_height", [0.03, 0.07]))
    return Suite("catch-v1", 1, (
        DropSet("rig", "rig", 7_010_000, n, "the thesis rig: 0.08-0.12 kg from 30-70 mm, sensor noise"),
        DropSet("rig-randomized", "rig-randomized", 7_020_000, n,
                "the rig with its hardware drawn per drop too (rig-randomized's ranges)"),
        DropSet("hard", "rig-randomized", 7_030_000, n,
                "rig-randomized with light and heavy bodies and high drops: 0.04-0.25 kg from 70-150 mm",
                (("randomize.m1", [0.04, 0.25]), ("randomize.drop_height", [0.07, 0.15]))),
        DropSet("ideal", "ideal", 7_040_000, n,
                "thesis ch. 3's plant (elastic contact, no suspension, no effects), controlled at 10 kHz; "
                "0.08-0.12 kg from 30-70 mm",
                (*drops, ("control.rate", 10_000.0), ("integrator.method", "split"))),
    ), "catching a dropped body: the rig, its uncertain hardware, hard drops and the ideal plant")


SUITES: dict[str, Suite] = {"catch-v1": _catch_v1()}


def get_suite(name: str) -> Suite:
    try:
        return SUITES[name]
    except KeyError:
        raise ConfigError(f"unknown suite {name!r} (valid: {', '.join(SUITES)})") from None
