"""scripts/bench_env_ab.py's record carries what every benchmark record carries: the command,
versions, git commit, CPU and date (``impact_env.eval.benchmark.run_meta``), beside its rounds
and medians.  No probe runs here: the record is built from given rounds."""

from __future__ import annotations

import json
from pathlib import Path

import bench_env_ab

from impact_env.eval.benchmark import run_meta


def test_the_record_has_the_run_meta_of_every_other_record():
    rows = {"this": [{"step_us": 3.0, "vec_1024": 9.0, "compare10_s": 1.0},
                     {"step_us": 5.0, "vec_1024": 7.0, "compare10_s": 2.0},
                     {"step_us": 4.0, "vec_1024": 8.0, "compare10_s": 3.0}],
            "other": [{"step_us": 6.0, "vec_1024": 5.0, "compare10_s": 4.0}] * 3}
    out = bench_env_ab.record(["--quick", "--other", "/tmp/x"], Path("/tmp/x"), 1, True, rows, 12.5)
    json.dumps(out)  # (a JSON record)
    meta = out["meta"]
    assert set(meta) == set(run_meta(None, 0.0, 0, 0.0))
    assert meta["command"] == "python scripts/bench_env_ab.py --quick --other /tmp/x"
    assert meta["wall_time_s"] == 12.5 and meta["versions"]["numba"] and meta["date"]
    assert out["median"]["this"] == {"compare10_s": 2.0, "vec_1024": 8.0, "step_us": 4.0}
    assert out["rounds"] is rows and out["quick"] is True and out["other"] == "/tmp/x"
