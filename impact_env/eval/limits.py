"""Requests out of proportion, refused before anything runs: ``compare``'s and ``benchmark``'s
memory and time, estimated from a measured calibration.

The estimate measures, in this process, two short rollouts of ``passive`` on the scene (1 and
:data:`CALIBRATION_EPISODES` episodes, :data:`CALIBRATION_PERIODS` control periods, the
command's trace rate): the bytes each extra episode allocates (``tracemalloc``'s peak, numpy's
arrays included) and the seconds each episode-period costs.  It then scales them to the request:

* memory: the worker processes' rollouts at once (each holds its chunk of episodes, its traces
  growing with the horizon) plus what the parent keeps of every episode of every policy (the
  metrics and the catch-energy curve at 2 kHz, :data:`impact_env.eval.compare.ENERGY_CURVE_RATE`);
  refused above the memory the system reports available (``MemAvailable``);
* time: episodes x periods x policies at the measured cost, over the workers; refused above
  :data:`MAX_SECONDS` (a day) unless the caller allows a long run (``--allow-long``).  A policy
  that runs in Python (an SB3 model) costs more per period than ``passive``: the estimate is a
  floor for those.

A small request (at most :data:`SMALL_EPISODES` episodes in all and :data:`SMALL_STEPS`
episode-periods) is not measured: it is far inside both limits on any machine that runs the
simulator at all (a few MB per thousand episodes, under an hour at 10 us per period).

Both figures are estimates (the calibration runs in a second or less and is noisy on a loaded
machine); they exist to refuse ``--episodes 100000000`` with a number, not to predict a run.
"""

from __future__ import annotations

import math
import time
import tracemalloc
from dataclasses import dataclass

from impact_env.config import ConfigError

CALIBRATION_EPISODES = 5
CALIBRATION_PERIODS = 200
MAX_SECONDS = 86_400.0  # s: a request estimated above a day is refused unless allowed
SMALL_EPISODES = 20_000  # episodes x policies at most, and
SMALL_STEPS = 200_000_000  # episode-periods at most: a request this small is not measured
ENERGY_CURVE_BYTES = 4  # float32 per sample of the kept catch-energy curve


@dataclass(frozen=True)
class Cost:
    """The estimate of a run (module doc)."""

    bytes: float
    seconds: float
    bytes_per_episode: float  # in a worker's rollout, over the whole horizon
    seconds_per_period: float  # per episode and control period

    def text(self) -> str:
        return f"about {_size(self.bytes)} of memory and {_duration(self.seconds)}"


def measure(scene, horizon: float, trace_rate: float) -> tuple[float, float]:
    """(bytes per episode over ``horizon``, seconds per episode-period): ``passive``'s short
    rollouts of 1 and :data:`CALIBRATION_EPISODES` episodes, the difference per extra episode."""
    from impact_env.eval.rollout import rollout
    from impact_env.policy.registry import make_policy

    periods = max(1, min(CALIBRATION_PERIODS, int(round(horizon / scene.control_period))))
    h = periods * scene.control_period
    peaks, times = [], []
    for n in (1, CALIBRATION_EPISODES):
        policy = make_policy("passive", scene)
        tracemalloc.start()
        try:
            t0 = time.perf_counter()
            rollout(scene, policy, list(range(n)), horizon=h, trace_rate=trace_rate)
            times.append(time.perf_counter() - t0)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    extra = CALIBRATION_EPISODES - 1
    per_episode = max(peaks[1] - peaks[0], 0) / extra * max(1.0, horizon / h)
    per_period = max(times[1] - times[0], 0.0) / extra / periods
    return per_episode, per_period


def estimate(scene, horizon: float, episodes: int, policies: int, workers: int, trace_rate: float,
             curve_rate: float, record_commands: bool = False) -> Cost:
    """The memory (bytes) and time (s) of ``policies`` x ``episodes`` episodes of ``horizon`` s
    over ``workers`` processes, each episode's catch-energy curve kept at ``curve_rate`` Hz
    (module doc)."""
    from impact_env.sim.metrics import EPISODE_METRICS

    per_episode, per_period = measure(scene, horizon, trace_rate)
    periods = horizon / scene.control_period
    parent = (len(EPISODE_METRICS) * 8 + (horizon * curve_rate + 1) * ENERGY_CURVE_BYTES
              + (periods * 8 if record_commands else 0.0))
    chunk = math.ceil(episodes / max(1, math.ceil(workers / max(policies, 1)))) if workers > 1 else episodes
    at_once = min(workers, policies * max(1, math.ceil(episodes / chunk))) * chunk
    total_bytes = at_once * per_episode + policies * episodes * parent
    seconds = policies * episodes * periods * per_period / max(1, workers)
    return Cost(total_bytes, seconds, per_episode, per_period)


def is_small(scene, horizon: float, episodes: int, policies: int) -> bool:
    """True for a request too small to need an estimate (module doc)."""
    periods = horizon / scene.control_period
    return episodes * policies <= SMALL_EPISODES and episodes * policies * periods <= SMALL_STEPS


def available_memory() -> float:
    """Bytes the system reports available (``MemAvailable`` of /proc/meminfo; inf elsewhere)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    return math.inf


def check_cost(cost: Cost, what: str, allow_long: bool = False) -> None:
    """ConfigError with the estimate when ``cost`` is out of proportion (module doc)."""
    free = available_memory()
    if cost.bytes > free:
        raise ConfigError(f"{what} would need {cost.text()} (estimated: {_size(cost.bytes_per_episode)} per "
                          f"episode in a worker, measured here), more than the {_size(free)} of memory "
                          "available: ask for fewer episodes (--episodes), or split the run over seeds "
                          "(--seed)")
    if cost.seconds > MAX_SECONDS and not allow_long:
        raise ConfigError(f"{what} would take {cost.text()} (estimated at "
                          f"{1e6 * cost.seconds_per_period:.3g} us per episode and control period, measured "
                          f"here), more than {_duration(MAX_SECONDS)}: ask for fewer episodes (--episodes) "
                          "or more workers, or pass --allow-long")


def _size(n: float) -> str:
    if not math.isfinite(n):
        return "unbounded"
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} TB"  # pragma: no cover


def _duration(s: float) -> str:
    if s < 120:
        return f"{s:.3g} s"
    if s < 7200:
        return f"{s / 60:.3g} min"
    if s < 172_800:
        return f"{s / 3600:.3g} h"
    return f"{s / 86_400:.3g} days"
