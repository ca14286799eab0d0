"""Episode logs read back as identification experiments, or refused with their cause.

An :class:`Experiment` is what a fit replays: the command the DAC held over each tick (the log's
``command`` column, held through ticks the target skipped), the raw readings of each tick that
ran (row m: read at tick m), which rows are usable, and the episode's kind.  :func:`load` reads
a set of logs and refuses, before any fitting, naming the file and the cause:

* a file that is not a readable episode log (corrupt HDF5, another format);
* a log of the wrong kind (a benchmark ``drop`` draws its body and height per episode, a host-mode
  episode acts on a policy the fit cannot replay: identification needs ``quiet``, ``shaker`` and
  ``ident_drop`` episodes, :class:`impact_env.rig.protocol.EpisodeKind`);
* logs recorded on another scene's sensors (their ``effects.sensors`` or control rate differ from
  the first log's: the readings would not mean the same);
* a channel of a fitted sensor with non-finite readings, or an episode ended by a fault;
* too few logs of a kind for the stage that needs them (:data:`MINIMUM`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tomllib

from impact_env.config import ConfigError
from impact_env.effects.sensors import CHANNELS
from impact_env.rig.log import list_episodes, read_episode
from impact_env.scene import Scene, scene_from_dict

KINDS = ("quiet", "shaker", "ident_drop")
# the fewest logs of each kind a fit takes, and what it takes them for
MINIMUM = {"quiet": (1, "the sensors' offsets and noise (the residuals' weights)"),
           "shaker": (1, "the shaker, amplifier, suspension and force transducer"),
           "ident_drop": (2, "the pad, m1, m2 and the sensor delay (two, so that the drops' "
                             "scatter is seen)")}
USABLE_ENDS = ("HORIZON",)


class ExperimentError(ConfigError):
    """A log that cannot serve the fit (the message names the file and the cause)."""


@dataclass
class Experiment:
    """One identification episode (SI units).

    ``commands`` float64[n]: the dimensionless command held over tick m (1 = the scene's
    ``effects.command_scale`` N up); ``readings`` float64[n, 4]: raw readings at tick m
    (accelerometer m/s^2, force N, potentiometer m, body-1 sensor m; NaN where the tick was
    skipped); ``usable`` bool[n]: rows the fit compares (read, finite, not at an ADC limit)."""

    path: str
    kind: str
    scene: Scene
    scene_toml: str
    commands: np.ndarray
    readings: np.ndarray
    usable: np.ndarray
    excitation: str
    seed: int
    physics_toml: str = ""
    fit_mask: np.ndarray | None = None  # the rows a fit compares, if fewer than ``usable`` (set by the fit)

    @property
    def n(self) -> int:
        return len(self.commands)

    @property
    def rate(self) -> float:
        return float(self.scene.control_rate)


def from_log(log, path: str | None = None) -> Experiment:
    """The experiment in an :class:`impact_env.rig.log.EpisodeLog` (ExperimentError if it cannot serve)."""
    where = str(path or log.path or "a log")
    meta = log.meta
    if meta.kind not in KINDS:
        raise ExperimentError(f"{where}: the wrong episode kind for identification: {meta.kind!r} "
                              "(a benchmark drop draws its body and height per episode; identification "
                              f"takes {', '.join(KINDS)} episodes, as impact-env rig identify runs them)")
    if meta.end_reason not in USABLE_ENDS:
        raise ExperimentError(f"{where}: the episode ended {meta.end_reason}, not at its horizon: its ticks "
                              "after the end are missing and it may hold a fault")
    try:
        scene = scene_from_dict(tomllib.loads(meta.scene_toml))
    except (tomllib.TOMLDecodeError, ConfigError) as exc:
        raise ExperimentError(f"{where}: its scene_toml does not load: {exc}") from None
    if "command" not in log.columns:
        raise ExperimentError(f"{where}: no 'command' column (the command the driver was given): a log of "
                              "impact-env 0.2 or later holds it")
    tick = np.asarray(log["tick"], dtype=np.int64)
    if len(tick) < 3 or tick[0] != 0 or np.any(np.diff(tick) < 1):
        raise ExperimentError(f"{where}: its tick column is not an increasing count from 0")
    n = int(tick[-1]) + 1
    cmd_rows = np.asarray(log["command"], dtype=np.float64)
    commands = np.zeros(n)
    # the DAC holds a command over the ticks after it that did not run (skipped by an overrun)
    idx = np.searchsorted(tick, np.arange(n), side="right") - 1
    commands[:] = cmd_rows[idx]
    commands[-1] = 0.0  # the final row (tick = horizon) sends no command
    if not np.all(np.isfinite(commands[:-1])):
        raise ExperimentError(f"{where}: its command column holds non-finite values")
    readings = np.full((n, 4), np.nan)
    for c, name in enumerate(("accelerometer_mps2", "force_N", "potentiometer_m")):
        readings[tick, c] = np.asarray(log[name], dtype=np.float64)
    usable = np.zeros(n, dtype=bool)
    usable[tick] = True
    usable[0] = False  # the readings at the release, before any sensor stage ran
    fx = scene.effects.sensors
    for c, name in enumerate(CHANNELS[:3]):
        ch = getattr(fx, name)
        if not ch.enabled:
            continue
        col = readings[tick, c]
        bad = ~np.isfinite(col)
        if bad.any():
            raise ExperimentError(f"{where}: channel {name} has {int(bad.sum())} non-finite readings of "
                                  f"{len(col)}: a broken sensor or cable; fix it or leave the episode out")
        if ch.adc_bits:
            q = ch.quantum
            at_limit = ((readings[:, c] <= -ch.adc_range + 0.5 * q)
                        | (readings[:, c] >= ch.adc_range - 1.5 * q))
            usable &= ~at_limit
    return Experiment(where, meta.kind, scene, meta.scene_toml, commands, readings, usable, meta.excitation,
                      int(meta.seed), getattr(meta, "physics_toml", ""))


def load(paths, minimum: dict | None = None) -> list[Experiment]:
    """The experiments in the log files (and folders of them) ``paths``; ExperimentError naming
    the file and the cause for any that cannot serve, and for too few of a kind."""

    files: list[Path] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            files.extend(list_episodes(p))
        elif p.is_file():
            files.append(p)
        else:
            raise ExperimentError(f"{p}: no such log file or folder")
    if not files:
        raise ExperimentError(f"no episode logs (*.h5) in {', '.join(str(p) for p in paths)}")
    out = []
    for f in files:
        try:
            log = read_episode(f)
        except ExperimentError:
            raise
        except Exception as exc:  # noqa: BLE001 (h5py raises many kinds for a damaged file)
            raise ExperimentError(f"{f}: not a readable rig episode log "
                                  f"({type(exc).__name__}: {exc})") from None
        out.append(from_log(log, str(f)))
    _same_sensors(out)
    need = MINIMUM if minimum is None else minimum
    have = {k: sum(e.kind == k for e in out) for k in KINDS}
    short = [f"{have[k]} {k} episode(s) (need >= {need[k][0]}: {need[k][1]})" for k in KINDS
             if k in need and have[k] < need[k][0]]
    if short:
        raise ExperimentError(f"too few logs to identify the rig: {'; '.join(short)}; record them with "
                              "impact-env rig identify")
    return out


def _same_sensors(exps: list[Experiment]) -> None:
    first = exps[0]
    ref = first.scene.effects.sensors
    for e in exps[1:]:
        if abs(e.rate - first.rate) > 1e-9 * first.rate:
            raise ExperimentError(f"{e.path} was recorded at control.rate = {e.rate:g} Hz, {first.path} at "
                                  f"{first.rate:g} Hz: logs of one rig setting only")
        if (e.scene.effects.sensors != ref
                or e.scene.effects.command_scale != first.scene.effects.command_scale):
            diff = [f"effects.sensors.{name}" for name in CHANNELS
                    if getattr(e.scene.effects.sensors, name) != getattr(ref, name)]
            if e.scene.effects.command_scale != first.scene.effects.command_scale:
                diff.append("effects.command_scale")
            raise ExperimentError(f"{e.path} was recorded with other sensors than {first.path} "
                                  f"({', '.join(diff) or 'effects.sensors'} differ): the readings would not "
                                  "mean the same; identify one sensor setting at a time")
