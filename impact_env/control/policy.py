"""Compiled policies: one file holds everything a policy needs to act without Python, and one
numba kernel, :func:`act`, runs it.

A policy file (JSON, ``*.policy.json``; :data:`FORMAT`, version :data:`VERSION`) holds:

* ``observation``: the layout the policy reads (kind, history, entry names, units, reference
  scales, sensor channels, detector bit, privileged part; :mod:`impact_env.control.observation`),
  so the front end on the target builds exactly the observation the policy was made for;
* ``command_scale_N`` (the force that command 1 demands), ``control_rate_Hz``, ``hold_ticks``;
* either ``law`` (a classic law by name with its gains and the scene constants it uses,
  :mod:`impact_env.control.laws`) or ``mlp`` (the actor network's layers and SB3's output
  transform, :mod:`impact_env.control.mlp`);
* optionally ``estimator`` (with ``mlp`` only): the constants of the extended Kalman filter
  that runs before the network every tick, on the frame's accelerometer, transducer and
  potentiometer, told the command the policy returns, and of the law that takes over when the
  filter shows its model wrong; the network reads the observation row and then the filter's
  scaled estimate (:mod:`impact_env.control.behind_filter`);
* optionally ``residual``: a whole law policy (as its own file would hold it) that runs every
  tick under the network, the command of a tick being ``clip(network + law, -1, 1)``, the
  network's output held for ``hold_ticks`` ticks (the env's ``residual`` option);
* ``scene`` (name and sha256 of its TOML) and ``source`` (what it was exported from).

Floats are written with ``repr`` (JSON round-trips them exactly), so a file acts bitwise like
the object it was saved from.  :func:`act` takes the packed arrays of :meth:`CompiledPolicy.arrays`
(int64 ``pi``, float64 ``pf``), one observation row and the policy's memory row, and returns the
command in [-1, 1] (1 = ``command_scale_N`` newtons upwards).  It allocates nothing.
"""

from __future__ import annotations

import hashlib
import json
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.config import ConfigError, check_hold_ticks
from impact_env.control import behind_filter, laws
from impact_env.control import mlp as MLP
from impact_env.control.estimation import features as estimate
from impact_env.control.laws.estimate import SensorReads
from impact_env.control.observation import OBSERVATIONS, ObservationLayout, References, make_layout

FORMAT = "impact-env-policy"
VERSION = 1
# a packed policy's kind: a classic law's code (its place in impact_env.control.laws.REGISTRY,
# >= 0), or one of these (below 0, so that adding a law moves neither)
KIND_MLP = -1
# an open-loop command sequence (an identification excitation, impact_env.rig.excitation): the
# observation is not read; pf's body holds the commands, memory[0] counts the calls
KIND_SEQUENCE = -2
# an MLP behind the extended Kalman filter (impact_env.control.behind_filter): pi's slots hold the
# frame positions of the sensors its filter and fallback law read, and after the layer table where
# the weights end in pf's body (the constants follow them)
KIND_MLP_ESTIMATE = -3



class IntsHead(NamedTuple):
    """pi's header (int64); the law's slots follow, then the MLP's layer table."""

    kind: int  # a law's code, KIND_MLP or KIND_SEQUENCE
    obs_size: int  # the observation row's length
    frame: int  # the frame's length (the law reads the first frame)
    memory: int  # the memory row's length
    n_layers: int  # the MLP's layers
    output: int  # the MLP's output transform (impact_env.control.mlp.OUT)


class FloatsHead(NamedTuple):
    """pf's header (float64); the frame's scales follow, then the law's constants or the MLP's
    weights."""

    command_scale: float  # N per unit command
    low: float  # the MLP's output range
    high: float


PI = positions(IntsHead)
PF = positions(FloatsHead)
PI_SLOTS = len(PI)  # where the law's slots start in pi
PI_LAYERS = PI_SLOTS + laws.N_SLOTS  # ... and the layer table
PF_SCALES = len(PF)  # where the frame's scales start in pf


class PolicyArrays(NamedTuple):
    """A packed policy, as :func:`act` takes it (:meth:`CompiledPolicy.arrays`)."""

    ints: np.ndarray  # int64: header (IntsHead), the law's slots, the MLP's layer table
    floats: np.ndarray  # float64: header (FloatsHead), the frame's scales, the law's constants or the weights


@jit(inline="always")
def act(pi, pf, obs, mem):
    """The command (float64 in [-1, 1]) of the packed policy for the observation row ``obs``
    (float32 or float64[obs size]); ``mem`` (float64[memory size]) is its memory and scratch,
    zeroed by the caller at the episode start."""
    kind = pi[PI.kind]
    frame_size = pi[PI.frame]
    body = PF_SCALES + frame_size
    if kind == KIND_SEQUENCE:
        k = int(mem[0])
        mem[0] = k + 1.0
        return pf[body + k] if body + k < pf.shape[0] else 0.0
    if kind == KIND_MLP_ESTIMATE:
        return _act_behind_filter(pi, pf, obs, mem)
    if kind == KIND_MLP:
        nl = pi[PI.n_layers]
        layers = pi[PI_LAYERS:PI_LAYERS + nl * MLP.N_LAYER_INTS].reshape((nl, MLP.N_LAYER_INTS))
        out = MLP.mlp_forward(layers, pf[body:], obs, mem)
        return MLP.output_transform(pi[PI.output], out[0], pf[PF.low], pf[PF.high])
    v = mem[laws.MEMORY:laws.MEMORY + frame_size]
    for j in range(frame_size):
        v[j] = float(obs[j]) * pf[PF_SCALES + j]
    f = laws.law_force(kind, pi[PI_SLOTS:PI_LAYERS], pf[body:], v, mem[:laws.MEMORY])
    u = f / pf[PF.command_scale]
    if u < -1.0:
        return -1.0
    if u > 1.0:
        return 1.0
    return u


@jit(inline="always")
def _act_behind_filter(pi, pf, obs, mem):
    frame_size = pi[PI.frame]
    body = PF_SCALES + frame_size
    nl = pi[PI.n_layers]
    table_end = PI_LAYERS + nl * MLP.N_LAYER_INTS
    layers = pi[PI_LAYERS:table_end].reshape((nl, MLP.N_LAYER_INTS))
    weights_end = body + pi[table_end]
    return behind_filter.act(layers, pf[body:weights_end], pf[weights_end:], pi[PI.output], pf[PF.low],
                             pf[PF.high], pf[PF.command_scale], pi[PI_SLOTS:PI_LAYERS],
                             pf[PF_SCALES:body], obs[:pi[PI.obs_size]], mem[:pi[PI.memory]])


@jit
def act_batch(pi, pf, obs, mem, out):
    """:func:`act` for every row of ``obs`` (float[N, size]) into ``out`` (float64[N])."""
    for i in range(obs.shape[0]):
        out[i] = act(pi, pf, obs[i], mem[i])
    return out


def sequence_arrays(commands: np.ndarray, obs_size: int, command_scale: float) -> tuple[np.ndarray,
                                                                                        np.ndarray, int]:
    """(pi, pf, memory size) for :func:`act` of an open-loop sequence: call k returns
    ``commands[k]`` (dimensionless, 1 = ``command_scale`` N up), then 0 once they run out."""
    c = np.asarray(commands, dtype=np.float64).ravel()
    if not np.all(np.isfinite(c)) or np.any(np.abs(c) > 1.0):
        raise ConfigError("an open-loop command sequence must be finite and within [-1, 1]")
    head = IntsHead(kind=KIND_SEQUENCE, obs_size=int(obs_size), frame=0, memory=1, n_layers=0, output=0)
    pi = np.concatenate([np.array(head, dtype=np.int64), np.full(laws.N_SLOTS, -1, dtype=np.int64)])
    return pi, np.concatenate([FloatsHead(float(command_scale), -1.0, 1.0), c]), 1


def _layout_dict(layout: ObservationLayout, kind: str) -> dict:
    r = layout.refs
    return {"kind": kind, "history": layout.history, "names": list(layout.names), "units": list(layout.units),
            "scales": [float(s) for s in layout.scales],
            "sensor_channels": [int(c) for c in layout.sensor_channels],
            "detector": bool(layout.detector), "privileged": bool(layout.privileged),
            "refs": {"length": r.length, "speed": r.speed, "force": r.force, "accel": r.accel}}


def _layout_from(d: dict) -> ObservationLayout:
    return ObservationLayout(tuple(d["names"]), tuple(d["units"]), np.array(d["scales"], dtype=np.float64),
                             np.array(d["sensor_channels"], dtype=np.int64), bool(d["detector"]),
                             bool(d["privileged"]), int(d["history"]), References(**d["refs"]))


@dataclass
class CompiledPolicy:
    """A policy that acts without Python (see the module doc).  Build it with :meth:`from_law` or
    :meth:`from_mlp`, or :meth:`load` a file; :meth:`arrays` packs it for :func:`act`; it also has
    stable-baselines3's ``predict`` (running :func:`act` row by row), ``observation`` and
    ``history``, so it joins ``impact-env compare`` like any policy."""

    name: str
    observation: str
    layout: ObservationLayout
    command_scale: float
    control_rate: float
    hold_ticks: int = 1
    law: dict | None = None
    mlp: dict | None = None
    residual: dict | None = None
    estimator: dict | None = None
    scene: dict = field(default_factory=dict)
    source: dict = field(default_factory=dict)

    def __post_init__(self):
        if (self.law is None) == (self.mlp is None):
            raise ConfigError("a compiled policy holds exactly one of a law or an MLP")
        if self.observation not in OBSERVATIONS:
            raise ConfigError(f"policy observation {self.observation!r} is not one of "
                              f"{', '.join(OBSERVATIONS)}")
        if not (self.command_scale > 0 and np.isfinite(self.command_scale)):
            raise ConfigError(f"command_scale_N = {self.command_scale!r} N must be finite and > 0")
        check_hold_ticks(self.hold_ticks)
        if self.estimator is not None and (self.mlp is None or self.hold_ticks != 1 or self.residual is not None):
            raise ConfigError(f"policy {self.name!r}: a filter before the network ('estimator') needs an MLP "
                              "that acts every control period (hold_ticks 1) with no residual law: the filter "
                              "is told the command of every tick")
        self._packed = None
        self._state = None
        self.arrays()  # validates the law or the network now, not at the first act
        self.residual_policy()

    @property
    def history(self) -> int:
        return self.layout.history

    def residual_policy(self) -> CompiledPolicy | None:
        """The law that runs every tick under this policy, if any."""
        if self.residual is None:
            return None
        base = CompiledPolicy.from_dict(self.residual, f"policy {self.name!r}'s residual law")
        if base.law is None:
            raise ConfigError(f"policy {self.name!r}: its residual must be a classic law")
        return base

    # -- construction ----------------------------------------------------------------------
    @classmethod
    def from_law(cls, name: str, params: dict, constants: dict, scene, observation: str, source=None):
        """A classic law (``name`` in :data:`impact_env.control.laws.LAWS`) with its gains
        ``params`` and kernel ``constants``, on ``scene``'s observation ``observation``."""
        layout = make_layout(scene, observation, 1)
        return cls(name=name, observation=observation, layout=layout,
                   command_scale=float(scene.effects.command_scale), control_rate=float(scene.control_rate),
                   law={"name": name, "params": dict(params),
                        "constants": {k: float(v) for k, v in constants.items()}},
                   scene=scene_stamp(scene), source=dict(source or {}))

    @classmethod
    def from_mlp(cls, name: str, layers: list[dict], output: str, low: float, high: float, scene,
                 observation: str, history: int, hold_ticks: int = 1, residual: CompiledPolicy | None = None,
                 source=None, estimator: bool = False):
        """An actor network (``layers`` as :func:`impact_env.control.mlp.pack_mlp` takes them) with
        SB3's ``output`` transform to ``[low, high]``; with ``estimator``, behind the scene's
        filter (:mod:`impact_env.control.estimation.features`)."""
        if output not in MLP.OUT:
            raise ConfigError(f"MLP output {output!r} is not one of {', '.join(MLP.OUTPUTS)}")
        layout = make_layout(scene, observation, history)
        mlp = {"layers": [{"weight": np.asarray(ly["weight"], float).tolist(),
                           "bias": np.asarray(ly["bias"], float).tolist(),
                           "activation": ly.get("activation", "identity"),
                           "params": [float(x) for x in ly.get("params", [0.0, 0.0])]} for ly in layers],
               "output": output, "low": float(low), "high": float(high)}
        return cls(name=name, observation=observation, layout=layout,
                   command_scale=float(scene.effects.command_scale), control_rate=float(scene.control_rate),
                   hold_ticks=int(hold_ticks), mlp=mlp, scene=scene_stamp(scene), source=dict(source or {}),
                   residual=None if residual is None else residual.to_dict(),
                   estimator=behind_filter.estimator_of(scene) if estimator else None)

    # -- packing ---------------------------------------------------------------------------------
    def arrays(self) -> tuple[np.ndarray, np.ndarray, int]:
        """(pi int64, pf float64, memory size) for :func:`act`."""
        if self._packed is not None:
            return self._packed
        lay = self.layout
        F = lay.frame_size
        head_f = [*FloatsHead(self.command_scale, -1.0, 1.0), *(float(s) for s in lay.scales)]
        slots = np.full(laws.N_SLOTS, -1, dtype=np.int64)
        if self.law is not None:
            kind, slots, consts = laws.pack_law(self.law["name"], self.law["constants"], lay.names)
            n_layers, out, table, body, mem = 0, 0, np.zeros(0, np.int64), consts, laws.MEMORY + F
        else:
            mlp = typing.cast(dict, self.mlp)  # exactly one of law and mlp (__post_init__)
            table2, body, widest = MLP.pack_mlp(mlp["layers"])
            n_in = lay.size + (estimate.N_FEATURES if self.estimator is not None else 0)
            if table2[0, MLP.LI.n_in] != n_in:
                extra = f" and the filter's {estimate.N_FEATURES} estimates" if self.estimator is not None else ""
                raise ConfigError(f"the network takes {table2[0, MLP.LI.n_in]} inputs but the observation "
                                  f"({self.observation}, history {lay.history}) has {lay.size}{extra}")
            if table2[-1, MLP.LI.n_out] != 1:
                raise ConfigError(f"the network gives {table2[-1, MLP.LI.n_out]} outputs; the shaker takes "
                                  "one")
            kind, n_layers, out, table, mem = KIND_MLP, table2.shape[0], MLP.OUT[mlp["output"]], \
                table2.ravel(), 2 * widest
            head_f[PF.low], head_f[PF.high] = mlp["low"], mlp["high"]
            if self.estimator is not None:
                k = behind_filter.estimator_vector(self.estimator)
                missing = [r for r in estimate.READS if r not in lay.names]
                if missing:
                    raise ConfigError(f"policy {self.name!r}: its filter reads {', '.join(missing)}, which the "
                                      f"observation ({', '.join(lay.names)}) does not hold")
                slots[:] = [lay.names.index(r) if r in lay.names else -1 for r in SensorReads._fields]
                table = np.concatenate([table, [len(body)]])
                body = np.concatenate([body, k])
                kind, mem = KIND_MLP_ESTIMATE, behind_filter.memory_size(widest, n_in, F)
        head = IntsHead(kind=kind, obs_size=lay.size, frame=F, memory=mem, n_layers=n_layers, output=out)
        pi = np.concatenate([np.array(head, dtype=np.int64), slots, table])
        pf = np.concatenate([np.array(head_f, dtype=np.float64), body])
        self._packed = (pi.astype(np.int64), pf, int(mem))
        return self._packed

    # -- files -------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = {"format": FORMAT, "version": VERSION, "name": self.name,
             "observation": _layout_dict(self.layout, self.observation),
             "command_scale_N": self.command_scale, "control_rate_Hz": self.control_rate,
             "hold_ticks": self.hold_ticks, "scene": self.scene, "source": self.source}
        if self.law is not None:
            d["law"] = self.law
        else:
            d["mlp"] = self.mlp
        if self.residual is not None:
            d["residual"] = self.residual
        if self.estimator is not None:
            d["estimator"] = self.estimator
        return d

    def save(self, path) -> Path:
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1) + "\n")
        return path

    @classmethod
    def load(cls, path) -> CompiledPolicy:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"policy file {str(path)!r} not found")
        try:
            d = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"policy file {str(path)!r} is not JSON: {exc}") from None
        return cls.from_dict(d, str(path))

    @classmethod
    def from_dict(cls, d: dict, where: str = "policy") -> CompiledPolicy:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ConfigError(f"{where} is not an {FORMAT} file (no 'format': {FORMAT!r})")
        if int(d.get("version", -1)) != VERSION:
            raise ConfigError(f"{where} has version {d.get('version')!r}; this impact_env reads version "
                              f"{VERSION}")
        try:
            obs = d["observation"]
            return cls(name=d["name"], observation=obs["kind"], layout=_layout_from(obs),
                       command_scale=float(d["command_scale_N"]), control_rate=float(d["control_rate_Hz"]),
                       hold_ticks=int(d.get("hold_ticks", 1)), law=d.get("law"), mlp=d.get("mlp"),
                       residual=d.get("residual"), estimator=d.get("estimator"), scene=d.get("scene", {}),
                       source=d.get("source", {}))
        except KeyError as exc:
            raise ConfigError(f"{where} misses the key {exc}") from None

    def sha256(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()

    # -- use ---------------------------------------------------------------------------------------
    def check_scene(self, scene) -> None:
        """ConfigError unless ``scene`` gives this policy's observation (same entries and scales)
        at its control rate."""
        res = self.residual_policy()
        if res is not None:
            res.check_scene(scene)
        lay = make_layout(scene, self.observation, self.history)
        if lay.names != self.layout.names or not np.array_equal(lay.scales, self.layout.scales):
            raise ConfigError(f"policy {self.name!r} reads {self.layout.names} with scales "
                              f"{self.layout.scales.tolist()}; scene {scene.name!r} gives {lay.names} with "
                              f"scales {lay.scales.tolist()} (a different drop or pad changes the reference "
                              "scales)")
        if abs(scene.control_rate - self.control_rate) > 1e-9 * self.control_rate:
            raise ConfigError(f"policy {self.name!r} was made for control.rate = {self.control_rate:g} Hz; "
                              f"scene {scene.name!r} runs at {scene.control_rate:g} Hz")

    def new_memory(self, n: int) -> np.ndarray:
        return np.zeros((n, self.arrays()[2]))

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        """stable-baselines3's interface: (actions [N, 1] or [1], memory); the actions are the
        float64 commands :func:`act` gives (the env takes float64 actions as they are)."""
        pi, pf, m = self.arrays()
        x = np.asarray(obs)
        single = x.ndim == 1
        x = np.atleast_2d(x)
        n = x.shape[0]
        if state is not None:
            mem = np.asarray(state)
        elif self._state is None or self._state.shape[0] != n:
            self._state = mem = self.new_memory(n)
        else:
            mem = self._state
        if episode_start is not None:
            starts = np.broadcast_to(np.asarray(episode_start, dtype=bool).reshape(-1), (n,))
            mem[starts] = 0.0
        u = act_batch(pi, pf, np.ascontiguousarray(x), mem, np.empty(n))
        a = u.reshape(n, 1)
        return (a[0] if single else a), mem


def scene_stamp(scene) -> dict:
    """The scene a policy was made on: name and the sha256 of its TOML."""
    return {"name": scene.name, "toml_sha256": hashlib.sha256(scene.to_toml().encode()).hexdigest()}
