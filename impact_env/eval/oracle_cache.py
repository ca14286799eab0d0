"""The oracle's per-drop commands, cached on disk, so that its score costs a replay, not a search.

The oracle (:mod:`impact_env.eval.oracle`) searches a command sequence per drop with CMA-ES,
about 3 s of CPU per drop on the rig.  Run without warm starts from a comparison (its own
classic bases, and every other classic law's commands in its final choice:
:func:`law_warm_starts`), its result on a drop depends on nothing but the drop: the scene, the
seed, the horizon, the budget and the code.  So ``compare --oracle`` and ``benchmark`` keep each
drop's commands in a file and replay them open loop (:func:`impact_env.eval.oracle.replay`
reproduces the bodies' motion bitwise), and the metrics of the oracle's row are always those of
the code that runs the replay.

Where: ``<root>/oracle/<scene name>-<key>/<seed>.npz``, ``key`` a hash of the scene (every
field), the horizon, the oracle's budget, the classic laws whose commands join its search with
their default parameters (a law added, or a default changed, searches again: a cached search
without it could be beaten by it), and the package version; ``root`` is ``--oracle-cache
DIR``, else ``$IMPACT_ENV_CACHE``, else ``$XDG_CACHE_HOME/impact_env`` (``~/.cache/impact_env``).
Each folder holds ``meta.json`` (what the key hashes, in words).  Deleting a folder is always
safe: its drops are searched again when asked.  The cache never lives in the repository (the
benchmark's records there hold the oracle's metrics, not its commands).

Each ``<seed>.npz`` holds ``commands`` (float64[n_steps], the sequence replayed), and the
search's ``cpu_seconds``, ``improvement_ms`` (its gain on its best warm start) and ``source``.
Files are written atomically (a temporary name, then a rename), so an interrupted search leaves
no half file.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from impact_env import __version__
from impact_env.config import ConfigError
from impact_env.eval.parallel import report, run_tasks
from impact_env.scene import Scene

CACHE_ENV = "IMPACT_ENV_CACHE"


def cache_root(path: str | Path | None = None) -> Path:
    """The cache's root folder (module doc): ``path``, ``$IMPACT_ENV_CACHE`` or the user's cache."""
    if path is not None:
        return Path(path)
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "impact_env"


def _budget_params(params: dict) -> dict:
    from impact_env.eval.oracle import Budget

    return dataclasses.asdict(Budget.from_params(**params))


@dataclass(frozen=True)
class OracleCache:
    """The cached drops of one scene, horizon and budget (``params``: the oracle's parameters,
    e.g. ``{"generations": 50}``; the defaults when empty)."""

    scene: Scene
    horizon: float
    params: tuple = ()  # (key, value) pairs of the oracle's parameters
    root: Path | None = None

    @classmethod
    def of(cls, scene: Scene, horizon: float, params: dict | None = None,
           root: str | Path | None = None) -> OracleCache:
        params = dict(params or {})
        _budget_params(params)  # bad parameters: ConfigError before anything runs
        if params.get("warm", "classic") != "classic":
            raise ConfigError("the oracle's cache holds the searches on its own classic bases: "
                              "oracle parameter warm must be 'classic'")
        return cls(scene, float(horizon), tuple(sorted(params.items())), cache_root(root))

    @property
    def what(self) -> dict:
        """What the key hashes: the scene, the horizon, the budget, the warm-start laws and the
        package version."""
        return {"scene": self.scene.to_dict(), "horizon_s": self.horizon,
                "budget": _budget_params(dict(self.params)), "warm_start_laws": _warm_start_laws(),
                "version": __version__}

    @functools.cached_property  # hashed once per cache, not once per drop's path
    def folder(self) -> Path:
        text = json.dumps(self.what, sort_keys=True, default=str)
        key = hashlib.sha256(text.encode()).hexdigest()[:16]
        return Path(self.root or cache_root()) / "oracle" / f"{self.scene.name}-{key}"

    def path(self, seed: int) -> Path:
        return self.folder / f"{int(seed)}.npz"

    def missing(self, seeds) -> list[int]:
        return [int(s) for s in seeds if not self.path(s).exists()]

    def store(self, seed: int, commands: np.ndarray, stats: dict) -> None:
        folder = self.folder
        folder.mkdir(parents=True, exist_ok=True)
        meta = folder / "meta.json"
        if not meta.exists():
            _atomic_write(meta, lambda fh: fh.write(json.dumps(self.what, indent=1, default=str).encode()))
        _atomic_write(self.path(seed), lambda fh: np.savez_compressed(fh, commands=commands, **stats))

    def load(self, seeds) -> tuple[np.ndarray, dict]:
        """The commands of the drops ``seeds`` (float64[n_steps, N]) and the searches' figures
        (name -> float[N]); ConfigError if a drop is not cached."""
        lost = self.missing(seeds)
        if lost:
            raise ConfigError(f"the oracle's cache {self.folder} lacks {len(lost)} of these drops (seeds "
                              f"{lost[:5]}{' ...' if len(lost) > 5 else ''}): compute them with --oracle")
        cols: list[np.ndarray] = []
        stats: dict[str, list[float]] = {}
        for s in seeds:
            with np.load(self.path(s)) as z:
                cols.append(z["commands"])
                for key in ("cpu_seconds", "improvement_ms"):
                    stats.setdefault(key, []).append(float(z[key]))
        return np.stack(cols, axis=1), {k: np.asarray(v) for k, v in stats.items()}

    def fill(self, seeds, workers: int = 1, progress: bool = True, cluster=None) -> int:
        """Search the drops of ``seeds`` that are not cached yet, one task per drop over
        ``workers`` processes (or a cluster), and store them; returns how many were searched."""
        todo = self.missing(seeds)
        if not todo:
            return 0
        tasks = [(self.scene, self.horizon, dict(self.params), seed) for seed in todo]
        outs = run_tasks(_search, tasks, workers, total=len(tasks),
                         desc=f"oracle: searching {len(tasks)} drops (cached afterwards)", progress=progress,
                         cluster=cluster)
        for seed, (commands, stats) in zip(todo, outs, strict=True):
            self.store(seed, commands, stats)
        return len(todo)


def _warm_start_laws() -> dict[str, dict[str, str]]:
    """Every classic law whose commands join a cached search (its own bases and
    :func:`law_warm_starts`'), with its default parameters (a default taken from the scene is
    named so: the scene is in the key already)."""
    from impact_env.control import laws

    return {law.name: {name: "from the scene" if p.from_scene is not None else repr(p.default)
                       for name, p in law.params.items()}
            for law in laws.REGISTRY}


def law_warm_starts(scene: Scene, seed: int, horizon: float) -> dict[str, np.ndarray]:
    """The commands of the classic laws other than the oracle's own bases, on the drop.  The
    oracle would roll them out itself (every classic law joins its final choice); given, they come
    before its bases among the candidates, the order every cached search has had, which decides
    a tie's source."""
    from impact_env.eval.oracle import WARM_POLICIES, classic_law_names, classic_warm_starts

    others = [name for name in classic_law_names() if name not in WARM_POLICIES]
    return classic_warm_starts(scene, [seed], horizon, others)


def _search(task) -> tuple[np.ndarray, dict]:
    """One drop's search (in a worker): the oracle, warm-started by the classic laws only."""
    from impact_env.eval.oracle import OraclePolicy

    scene, horizon, params, seed = task
    oracle = OraclePolicy(scene, **params)
    oracle.prepare(scene, [seed], horizon, law_warm_starts(scene, seed, horizon))
    st = oracle.stats
    assert oracle.open_loop is not None and st is not None
    report(1)
    return oracle.open_loop[:, 0].copy(), {"cpu_seconds": float(st["cpu_seconds"][0]),
                                           "improvement_ms": float(st["improvement_ms"][0]),
                                           "source": str(st["source"][0])}


def _atomic_write(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        write(fh)
    os.replace(tmp, path)
