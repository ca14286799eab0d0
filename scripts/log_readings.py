"""Write a rig episode log's raw readings as the C runtime's replay driver reads them.

    python scripts/log_readings.py rig_logs/episode_XXXXXXXX_000000.h5 readings.f64

``readings.f64``: little-endian float64, 4 per tick (accelerometer m/s^2, force N, potentiometer
m, NaN for the body-1 sensor), tick 0 first: the input of ``impact_rt readings.f64 commands.f64``
(docs/rig/c-runtime.md, "A real-time Linux loop").  A log with skipped ticks is refused (a replay needs
every tick's readings).
"""

from __future__ import annotations

import argparse
import sys

from impact_env.config import ConfigError
from impact_env.deploy.parity import readings_from_log
from impact_env.rig.log import read_episode


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", help="an episode's .h5 file (impact-env rig serve --log-dir)")
    ap.add_argument("out", help="the readings file to write (float64, 4 per tick)")
    args = ap.parse_args(argv)
    try:
        r = readings_from_log(read_episode(args.log))
    except (ConfigError, OSError, KeyError, ValueError) as exc:
        print(f"log_readings: {args.log}: {exc}", file=sys.stderr)
        return 1
    r.astype("<f8").tofile(args.out)
    print(f"{args.out}: {len(r)} ticks x 4 readings (float64) from {args.log}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
