"""Episode logs: every tick in preallocated arrays on the target, one HDF5 file per episode.

In memory (:class:`TickLog`), filled by compiled code: ``rows`` (float64[capacity, n_columns],
one row per tick, columns at the fixed indices below, then any ``extra`` columns), ``obs``
(float64[capacity, obs_size], the front end's observation at that tick) and ``count``
(int64[1], rows filled).  A kernel claims a row with :func:`claim_row` and writes
``rows[i, COL]``; integer columns are stored exactly in float64 (below 2^53).

On disk (:func:`write_episode`): ``<log-dir>/episode_<session>_<episode>.h5``, written under a
hidden temporary name in the same directory, flushed and fsynced, then renamed with
``os.replace`` (atomic on POSIX), so a crash at any moment leaves every finished episode intact
and at most a ``.*.tmp`` file that :func:`list_episodes` ignores.

Datasets (one value per tick, in tick order; ``unit`` attribute on each):

======================  ========  =======  ==========================================================
dataset                 dtype     unit     meaning
======================  ========  =======  ==========================================================
``tick``                int64              the target's tick counter (gaps: ticks missed by overruns)
``t_s``                 float64   s        time since the episode's tick 0 (tick / rate)
``accelerometer_mps2``  float64   m/s^2    raw accelerometer reading (body 2, down positive)
``force_N``             float64   N        raw force transducer reading (compression positive)
``potentiometer_m``     float64   m        raw potentiometer reading (body 2's travel, down positive)
``action``              float64            the command in use before safety (1 = command_scale N; 0
                                           with status NO_COMMAND: none yet)
``force_demand_N``      float64   N        action * command_scale
``force_applied_N``     float64   N        the force the driver applied (after the safety layer)
``command_age_ticks``   int64     ticks    ticks since the command in use first acted (-1: none)
``status``              uint32             status bits (:mod:`impact_env.rig.safety`)
``step``                int64              policy step (tick // hold_ticks)
``contact_detected``    uint8              the front end's contact detector (0/1)
``lateness_ns``         int64     ns       tick start minus its deadline (:mod:`impact_env.rig.rtloop`)
``compute_ns``          int64     ns       time the tick's work took
``command_step``        int64              host mode: the policy step of the command that acted (-1:
                                           none; onboard: the row's own step)
``skipped_ticks``       int64     ticks    ticks skipped (not run: an overrun) just before this row;
                                           > 0 only on rows with the OVERRUN bit
``observation``         float64            [n_ticks, obs_size]: the front end's observation (names in
                                           its ``names`` attribute)
(extra)                 float64   (attr)   columns named at construction, e.g. a virtual rig's truth
======================  ========  =======  ==========================================================

Attributes of the file: ``format`` ("impact_env.rig.episode"), ``format_version`` (3), and the
:class:`EpisodeMeta` fields: ``scene_toml`` (``scene.to_toml()``), ``mode``, ``hold_ticks``,
``seed``, ``control_rate_hz``, ``episode``, ``session``, ``policy``, ``policy_sha256`` (hex; empty
in host mode), ``observation``, ``history``, ``end_reason``, ``created_utc``, ``kind`` (drop,
ident_drop, shaker, quiet), ``excitation`` (the identification signal's JSON, or ""),
``physics_toml`` (a virtual rig's hardware when it differs from ``scene_toml``, or ""); groups ``versions``
(package, python, numpy, numba, h5py) and ``counters`` (plain ints, all of this episode only,
from its ARM to its end: datagrams received, accepted and dropped by reason, commands late,
watchdog trips, overruns (rows flagged OVERRUN), skipped_ticks, ...).
"""

from __future__ import annotations

import datetime
import os
import platform
import re
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.scene import scene_from_dict

FORMAT = "impact_env.rig.episode"
FORMAT_VERSION = 3  # 2: command_step and skipped_ticks columns; per-episode counters; 3: kind, excitation
KINDS = ("drop", "ident_drop", "shaker", "quiet")  # impact_env.rig.protocol.EpisodeKind's names
# attributes a file of an older format lacks, with the value they mean there
_SINCE_3 = {"kind": "drop", "excitation": "", "physics_toml": ""}



class LogRow(NamedTuple):
    """The fixed columns of a log row (float64 in memory), read by name: ``row[COL.force_N]``;
    each field: (unit, dtype on disk), the table in the module doc."""

    tick: tuple = ("", "int64")
    t_s: tuple = ("s", "float64")
    accelerometer_mps2: tuple = ("m/s^2", "float64")
    force_N: tuple = ("N", "float64")
    potentiometer_m: tuple = ("m", "float64")
    action: tuple = ("", "float64")
    force_demand_N: tuple = ("N", "float64")
    force_applied_N: tuple = ("N", "float64")
    command_age_ticks: tuple = ("ticks", "int64")
    status: tuple = ("", "uint32")
    step: tuple = ("", "int64")
    contact_detected: tuple = ("", "uint8")
    lateness_ns: tuple = ("ns", "int64")
    compute_ns: tuple = ("ns", "int64")
    command_step: tuple = ("", "int64")
    skipped_ticks: tuple = ("ticks", "int64")


COL = positions(LogRow)
# name, unit, dtype on disk, in column order
COLUMNS = tuple((name, *spec) for name, spec in zip(LogRow._fields, LogRow(), strict=True))
N_FIXED = len(COLUMNS)
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _h5py():
    try:
        import h5py
    except ImportError as exc:
        raise ImportError("rig episode logs are HDF5 files and need h5py: pip install 'impact-env[rig]' "
                          "(or pip install 'h5py>=3.8')") from exc
    return h5py


def versions() -> dict[str, str]:
    """Versions of what produced a log: the package, python, numpy, numba, h5py."""
    from importlib import metadata

    out = {"python": platform.python_version(), "numpy": np.__version__}
    for name, dist in (("impact_env", "impact-env"), ("numba", "numba"), ("h5py", "h5py")):
        try:
            out[name] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


class LogBuffers(NamedTuple):
    """A TickLog's arrays, as the compiled tick takes them."""

    rows: np.ndarray  # float64[capacity, columns]
    obs: np.ndarray  # float64[capacity, obs size]
    filled: np.ndarray  # int64[1]: rows filled (not `count`, which is tuple.count)


@jit(inline="always")
def claim_row(rows, count):
    """Index of the next free row of a TickLog (and counts it), or -1 when the log is full."""
    i = count[0]
    if i >= rows.shape[0]:
        return -1
    count[0] = i + 1
    return i


class TickLog:
    """Preallocated per-tick log of one episode (see the module doc for the columns).

    capacity: rows (ticks) it can hold; obs_size: entries of the observation; extra: names of
    further float64 columns (``extra_units`` gives their units).
    """

    def __init__(self, capacity: int, obs_size: int, extra: tuple[str, ...] = (),
                 extra_units: dict[str, str] | None = None):
        if isinstance(capacity, bool) or not isinstance(capacity, (int, np.integer)) or capacity < 1:
            raise ValueError(f"capacity = {capacity!r} must be an integer number of ticks >= 1")
        if isinstance(obs_size, bool) or not isinstance(obs_size, (int, np.integer)) or obs_size < 0:
            raise ValueError(f"obs_size = {obs_size!r} must be an integer >= 0")
        names = [c[0] for c in COLUMNS]
        for name in extra:
            if not _NAME.match(name) or name in names or name == "observation":
                raise ValueError(f"extra column {name!r} must be a new identifier-like name "
                                 "(not a fixed column nor 'observation')")
            names.append(name)
        self.extra = tuple(extra)
        self.extra_units = {n: (extra_units or {}).get(n, "") for n in self.extra}
        self.names = tuple(names)
        self.rows = np.zeros((int(capacity), len(names)))
        self.obs = np.zeros((int(capacity), int(obs_size)))
        self.count = np.zeros(1, dtype=np.int64)

    @property
    def buffers(self) -> LogBuffers:
        return LogBuffers(self.rows, self.obs, self.count)

    @property
    def capacity(self) -> int:
        return self.rows.shape[0]

    @property
    def n(self) -> int:
        return int(self.count[0])

    def col(self, name: str) -> int:
        """Column index of ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no column {name!r}; columns: {', '.join(self.names)}") from None

    def reset(self) -> None:
        """Empty the log for the next episode (no reallocation)."""
        self.count[0] = 0

    def record(self, obs=None, **values: float) -> int:
        """Append one row from Python (tests, slow paths): column values by name, missing ones 0.
        Returns the row index; raises OverflowError when full."""
        i = claim_row(self.rows, self.count)
        if i < 0:
            raise OverflowError(f"TickLog full ({self.capacity} ticks)")
        self.rows[i] = 0.0
        for name, v in values.items():
            self.rows[i, self.col(name)] = v
        if obs is not None:
            self.obs[i] = obs
        return i

    def columns(self) -> dict[str, np.ndarray]:
        """The filled rows as named arrays of their on-disk dtypes (copies)."""
        n = self.n
        out = {}
        for j, (name, _unit, dtype) in enumerate(COLUMNS):
            out[name] = self.rows[:n, j].astype(dtype)
        for j, name in enumerate(self.extra, start=N_FIXED):
            out[name] = self.rows[:n, j].copy()
        return out

    def to_episode(self, meta: EpisodeMeta) -> EpisodeLog:
        """The in-memory :class:`EpisodeLog` of the filled rows (what :func:`read_episode` returns
        for the file :func:`write_episode` writes)."""
        units = {c[0]: c[1] for c in COLUMNS} | self.extra_units
        return EpisodeLog(self.columns(), self.obs[:self.n].copy(), meta, units)


@dataclass
class EpisodeMeta:
    """What a log file says about its episode besides the ticks (SI units)."""

    scene_toml: str
    mode: str  # "host" or "onboard"
    hold_ticks: int
    seed: int
    control_rate_hz: float
    episode: int = 0
    session: int = 0
    policy: str = ""  # a policy spec or file name
    policy_sha256: str = ""  # hex digest of the policy file (onboard); "" in host mode
    observation: str = "sensors"
    history: int = 1
    obs_names: tuple[str, ...] = ()
    end_reason: str = ""
    created_utc: str = field(default_factory=lambda: datetime.datetime.now(datetime.timezone.utc)
                             .isoformat(timespec="seconds"))
    counters: dict[str, int] = field(default_factory=dict)
    versions: dict[str, str] = field(default_factory=versions)
    # format 3: the episode's kind (impact_env.rig.protocol.EpisodeKind, lower case), the
    # identification excitation played (its JSON, impact_env.rig.excitation; "" for none), and
    # a virtual rig's physics when it differs from the scene it was described by ("" otherwise)
    kind: str = "drop"
    excitation: str = ""
    physics_toml: str = ""

    def __post_init__(self):
        if self.mode not in ("host", "onboard"):
            raise ValueError(f"mode = {self.mode!r} must be 'host' or 'onboard'")
        for name in ("hold_ticks", "seed", "episode", "session", "history"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(f"{name} = {v!r} must be an integer >= 0")
        if not self.control_rate_hz > 0:
            raise ValueError(f"control_rate_hz = {self.control_rate_hz!r} Hz must be > 0 Hz")
        if self.kind not in KINDS:
            raise ValueError(f"kind = {self.kind!r} must be one of {', '.join(KINDS)}")
        if self.policy_sha256 and not re.fullmatch(r"[0-9a-f]{64}", self.policy_sha256):
            raise ValueError(f"policy_sha256 = {self.policy_sha256!r} must be 64 lower-case hex digits or ''")
        for k, v in self.counters.items():
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise ValueError(f"counter {k!r} = {v!r} must be an integer")
        self.obs_names = tuple(self.obs_names)


@dataclass
class EpisodeLog:
    """One episode's ticks: ``columns`` (name -> array, module doc), ``observation``
    (float64[n, obs_size]), ``meta`` and ``units`` (column -> unit)."""

    columns: dict[str, np.ndarray]
    observation: np.ndarray
    meta: EpisodeMeta
    units: dict[str, str]
    path: Path | None = None

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(f"no column {name!r}; columns: {', '.join(self.columns)}") from None

    @property
    def n_ticks(self) -> int:
        return len(self.columns["tick"])

    def scene(self):
        """The scene the episode ran on, from its TOML."""
        import tomllib

        return scene_from_dict(tomllib.loads(self.meta.scene_toml))

    def physics(self):
        """The scene of the hardware that ran: a virtual rig's physics when it differed from its
        description (``physics_toml``), else :meth:`scene`."""
        import tomllib

        if not self.meta.physics_toml:
            return self.scene()
        return scene_from_dict(tomllib.loads(self.meta.physics_toml))


def episode_filename(episode: int, session: int = 0) -> str:
    return f"episode_{int(session):08x}_{int(episode):06d}.h5"


def write_episode(log: TickLog | EpisodeLog, directory: str | os.PathLike, meta: EpisodeMeta | None = None,
                  name: str | None = None) -> Path:
    """Write one episode to ``directory/name`` (default :func:`episode_filename`) atomically
    (temporary file, fsync, ``os.replace``).  ``log``: a TickLog (with ``meta``) or an EpisodeLog."""
    h5py = _h5py()
    if isinstance(log, TickLog):
        if meta is None:  # said before anything is converted
            raise ValueError("write_episode(TickLog) needs meta")
        ep = log.to_episode(meta)
    else:
        ep = log
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    name = name or episode_filename(ep.meta.episode, ep.meta.session)
    if "/" in name or name.startswith(".") or not name.endswith(".h5"):
        raise ValueError(f"log file name {name!r} must be a plain name ending in .h5, not hidden")
    final = directory / name
    tmp = directory / f".{name}.{os.getpid()}.tmp"
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = FORMAT
            f.attrs["format_version"] = FORMAT_VERSION
            m = ep.meta
            for fd in fields(EpisodeMeta):
                if fd.name in ("counters", "versions", "obs_names"):
                    continue
                f.attrs[fd.name] = getattr(m, fd.name)
            for group, values in (("counters", m.counters), ("versions", m.versions)):
                g = f.create_group(group)
                for k, v in values.items():
                    g.attrs[k] = v
            for key, arr in ep.columns.items():
                d = f.create_dataset(key, data=arr)
                d.attrs["unit"] = ep.units.get(key, "")
            d = f.create_dataset("observation", data=ep.observation)
            d.attrs["names"] = list(m.obs_names)
            d.attrs["unit"] = "reference units (impact_env.sim.observation)"
            f.attrs["n_ticks"] = ep.n_ticks
            f.attrs["extra_columns"] = [k for k in ep.columns if k not in dict((c[0], 0) for c in COLUMNS)]
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, final)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(directory)
    return final


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # not possible on every platform; the rename is still atomic
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def read_episode(path: str | os.PathLike) -> EpisodeLog:
    """Read a file written by :func:`write_episode` (same arrays, dtypes and metadata)."""
    h5py = _h5py()
    path = Path(path)
    with h5py.File(path, "r") as f:
        if f.attrs.get("format") != FORMAT:
            raise ValueError(f"{path} is not a rig episode log (format attribute {f.attrs.get('format')!r})")
        ver = int(f.attrs["format_version"])
        if ver > FORMAT_VERSION:
            raise ValueError(f"{path} has format version {ver}; this reader knows up to {FORMAT_VERSION}")
        kw: dict[str, Any] = {}
        for fd in fields(EpisodeMeta):
            if fd.name in ("counters", "versions", "obs_names"):
                continue
            if fd.name in _SINCE_3 and fd.name not in f.attrs:
                kw[fd.name] = _SINCE_3[fd.name]
                continue
            v = f.attrs[fd.name]
            kw[fd.name] = v.item() if isinstance(v, np.generic) else v
        kw["counters"] = {k: int(v) for k, v in f["counters"].attrs.items()}
        kw["versions"] = {k: str(v) for k, v in f["versions"].attrs.items()}
        kw["obs_names"] = tuple(str(s) for s in f["observation"].attrs["names"])
        meta = EpisodeMeta(**kw)
        names = [c[0] for c in COLUMNS] + [str(s) for s in f.attrs["extra_columns"]]
        # n_ticks bounds every dataset: a streamed file (LogStream) killed while it grew its
        # datasets may have some longer than the rows its last flush made complete
        n = int(f.attrs["n_ticks"])
        columns = {k: f[k][:n] for k in names}
        units = {k: str(f[k].attrs["unit"]) for k in names}
        obs = f["observation"][:n]
    return EpisodeLog(columns, obs, meta, units, path)


def list_episodes(directory: str | os.PathLike) -> list[Path]:
    """The finished episode files in ``directory`` (temporary files of unfinished writes are
    ignored), sorted by name."""
    return sorted(p for p in Path(directory).glob("*.h5") if not p.name.startswith("."))


PARTIAL_SUFFIX = ".partial"  # a streamed log's name while its episode runs: episode_S_E.h5.partial
INCOMPLETE = "INCOMPLETE"  # the end reason of a streamed log whose episode never finished


class LogStream:
    """A log streamed to disk while its episode runs: a thread appends the rows the compiled
    loop has completed (``published[0]`` rows of ``log``) to ``path`` every ``period_s``
    (default 0.05 s) and flushes the file, so that a target killed at any moment (kill -9, power)
    leaves a log readable by :func:`read_episode` (and ``impact-env rig log``) up to its last
    flush, with ``end_reason`` INCOMPLETE.  When the episode ends, :meth:`close` writes the last
    rows; the target then writes the finished file with :func:`write_episode` and deletes this
    one.  Same datasets and attributes as a finished file; datasets are chunked and grow."""

    def __init__(self, log: TickLog, path: str | os.PathLike, meta: EpisodeMeta, published: np.ndarray,
                 period_s: float = 0.05, thread_setup=None):
        import threading

        h5py = _h5py()
        self.log, self.path, self.published = log, Path(path), published
        self.period_s = float(period_s)
        self.written = 0
        self.flushes = 0
        self._f = h5py.File(self.path, "w")
        f = self._f
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        for fd in fields(EpisodeMeta):
            if fd.name in ("counters", "versions", "obs_names"):
                continue
            f.attrs[fd.name] = getattr(meta, fd.name)
        f.attrs["end_reason"] = INCOMPLETE
        f.create_group("counters")
        g = f.create_group("versions")
        for k, v in meta.versions.items():
            g.attrs[k] = v
        units = {c[0]: c[1] for c in COLUMNS} | log.extra_units
        dtypes = {c[0]: c[2] for c in COLUMNS}
        self._cols = []
        for j, name in enumerate(log.names):
            d = f.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtypes.get(name, "float64"),
                                 chunks=(4096,))
            d.attrs["unit"] = units.get(name, "")
            self._cols.append((j, d))
        nobs = log.obs.shape[1]
        self._obs = f.create_dataset("observation", shape=(0, nobs), maxshape=(None, nobs), dtype="float64",
                                     chunks=(4096, max(1, nobs)))
        self._obs.attrs["names"] = list(meta.obs_names)
        self._obs.attrs["unit"] = "reference units (impact_env.sim.observation)"
        f.attrs["n_ticks"] = 0
        f.attrs["extra_columns"] = list(log.extra)
        f.flush()
        self._stop = threading.Event()
        # the writer thread and close() take turns on the file: close() never waits for the thread
        # to wake (it runs at nice +10, and on a loaded machine it may sleep for seconds)
        self._lock = threading.Lock()
        self._setup = thread_setup  # called first in the writer's thread (where it may run: placement)
        self._thread = threading.Thread(target=self._run, name="rig-log-stream", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        if self._setup is not None:
            self._setup()
        while not self._stop.wait(self.period_s):
            with self._lock:
                if self._f is None:
                    return
                self.flush()

    def flush(self, upto: int | None = None) -> None:
        """Append the completed rows not yet on disk and flush the file."""
        n = int(self.published[0]) if upto is None else int(upto)
        n = min(n, self.log.n)
        if n <= self.written:
            return
        a, rows = self.written, self.log.rows
        for j, d in self._cols:
            d.resize((n,))
            d[a:n] = rows[a:n, j]
        self._obs.resize((n, self._obs.shape[1]))
        self._obs[a:n] = self.log.obs[a:n]
        self._f.attrs["n_ticks"] = n  # after the data: a reader never reads past complete rows
        self._f.flush()
        self.written = n
        self.flushes += 1

    def close(self) -> None:
        """Stop the thread, write every row of the log (the final row too), close the file.  The
        thread is not waited for: once its flush in progress (if any) is done, it leaves the file
        alone and ends when it next wakes."""
        self._stop.set()
        with self._lock:
            if self._f:
                self.flush(self.log.n)
                self._f.close()
                self._f = None

    def finish(self, meta: EpisodeMeta, directory: str | os.PathLike) -> Path:
        """The streamed file as the episode's finished log, without writing the rows again (a
        target asked to stop has a second at most): every row written, ``meta``'s attributes and
        counters set, fsynced, renamed to :func:`episode_filename` in ``directory`` (atomic).
        :func:`read_episode` reads it as it reads a file of :func:`write_episode`."""
        self._stop.set()
        with self._lock:
            f = self._f
            if f is None:
                raise ValueError(f"{self.path} is closed: nothing to finish")
            self.flush(self.log.n)
            for fd in fields(EpisodeMeta):
                if fd.name not in ("counters", "versions", "obs_names"):
                    f.attrs[fd.name] = getattr(meta, fd.name)
            g = f["counters"]
            for k, v in meta.counters.items():
                g.attrs[k] = v
            f.close()
            self._f = None
        with open(self.path, "rb") as fh:
            os.fsync(fh.fileno())
        final = Path(directory) / episode_filename(meta.episode, meta.session)
        os.replace(self.path, final)
        _fsync_dir(Path(directory))
        return final

    def discard(self) -> None:
        """Close and delete the file (its episode was written as a finished file)."""
        self.close()
        self.path.unlink(missing_ok=True)
