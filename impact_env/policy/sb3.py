"""Saved stable-baselines3 models as policies, so trained agents join the same comparison.

Spec: ``PATH.zip``, ``ALGO:PATH.zip`` (``ppo``, ``sac``, ``td3``, ``a2c``, ``ddpg``), optionally
followed by ``:observation=sensors,history=4`` (or ``,observation=...``).  Without an algorithm
each one is tried in turn.  The observation the model was trained on is taken, in this order,
from the spec, from a JSON file next to the model (``PATH.json`` with keys ``observation`` and
``history``, if present), or from the size of the model's observation space, when exactly one
(observation, history) pair of the scene has that size (on ``rig`` the sensor frame and the
privileged frame both have 4 entries: then give ``observation=`` explicitly).
"""

from __future__ import annotations

import json
from pathlib import Path

from impact_env.config import ConfigError
from impact_env.control.observation import OBSERVATIONS, make_layout
from impact_env.scene import load_scene

ALGOS = ("ppo", "sac", "td3", "a2c", "ddpg")


def parse_model_spec(spec: str) -> tuple[str | None, Path, dict]:
    """``"ppo:runs/a.zip:observation=sensors"`` -> ("ppo", Path("runs/a.zip"), {"observation": "sensors"})."""
    head, sep, tail = spec.partition(".zip")
    if not sep:
        raise ConfigError(f"model spec {spec!r} must name a .zip file saved by stable-baselines3")
    algo = None
    path = head + ".zip"
    pre, colon, rest = head.partition(":")
    if colon and pre.lower() in ALGOS:
        algo, path = pre.lower(), rest + ".zip"
    opts: dict = {}
    for item in filter(None, (s.strip() for s in tail.lstrip(":,").replace(":", ",").split(","))):
        key, eq, value = item.partition("=")
        if not eq or key.strip() not in ("observation", "history"):
            raise ConfigError(f"model spec {spec!r}: option {item!r} must be observation=... or history=N")
        opts[key.strip()] = value.strip()
    if "history" in opts:
        try:
            opts["history"] = int(opts["history"])
        except ValueError:
            raise ConfigError(f"model spec {spec!r}: history must be an integer, "
                              f"got {opts['history']!r}") from None
    if "observation" in opts and opts["observation"] not in OBSERVATIONS:
        raise ConfigError(f"model spec {spec!r}: observation must be one of {', '.join(OBSERVATIONS)}")
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"model file {str(p)!r} not found (policy spec {spec!r})")
    return algo, p, opts


class ModelPolicy:
    """A loaded SB3 model with the attributes the comparison needs: ``observation``, ``history``,
    ``hold_ticks`` (control periods per action) and ``residual`` (the spec of the classic law its
    actions add to, or None), the last two from the env kwargs in its ``model.json``."""

    def __init__(self, model, observation: str, history: int, name: str, hold_ticks: int = 1,
                 residual: str | None = None):
        self.model = model
        self.observation = observation
        self.history = history
        self.name = name
        self.hold_ticks = int(hold_ticks)
        self.residual = residual

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)


def _load(algo: str | None, path: Path):
    import stable_baselines3 as sb3

    names = [algo] if algo else list(ALGOS)
    errors = []
    for name in names:
        cls = getattr(sb3, name.upper())
        try:
            return cls.load(str(path), device="cpu")
        except Exception as exc:  # wrong algorithm for this file: try the next one
            errors.append(f"{name}: {type(exc).__name__}: {exc}")
    raise ConfigError(f"could not load {str(path)!r} as a stable-baselines3 model ({'; '.join(errors)})")


def load_model_policy(spec: str, scene) -> ModelPolicy:
    scene = load_scene(scene)
    algo, path, opts = parse_model_spec(spec)
    sidecar = path.with_suffix(".json")
    env_kwargs: dict = {}
    if sidecar.is_file():
        meta = json.loads(sidecar.read_text())
        for key in ("observation", "history"):
            if key in meta and key not in opts:
                opts[key] = meta[key]
        env_kwargs = meta.get("env_kwargs") or {}
    model = _load(algo, path)
    size = int(model.observation_space.shape[0])
    obs, hist = opts.get("observation"), opts.get("history")
    cands = [(o, h) for o in ((obs,) if obs else OBSERVATIONS) for h in ((hist,) if hist else range(1, 65))
             if _size(scene, o, h) == size]
    if len(cands) != 1:
        what = "no" if not cands else f"{len(cands)}"
        listed = f" ({', '.join(map(str, cands[:6]))})" if cands else ""
        raise ConfigError(f"model {str(path)!r} takes {size} observation entries: {what} (observation, "
                          f"history) pairs of scene {scene.name!r} fit{listed}; say which with "
                          f"{spec.split('.zip')[0]}.zip:observation=sensors,history=1")
    return ModelPolicy(model, cands[0][0], cands[0][1], spec, hold_ticks=int(env_kwargs.get("hold_ticks", 1)),
                       residual=env_kwargs.get("residual"))


def _size(scene, observation, history) -> int | None:
    try:
        return make_layout(scene, observation, history).size
    except ConfigError:
        return None
