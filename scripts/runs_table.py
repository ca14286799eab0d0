"""One line per training run folder of ``agents.train``: settings, budget, speed, training and
validation returns and, when ``agents.evaluate --json DIR/test.json`` was run, the held-out
test metrics next to pd-penetration's on the same drops.

    python scripts/runs_table.py runs/e1b runs/e4 ... [--markdown]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _row(d: Path) -> dict:
    meta = json.loads((d / "model.json").read_text())
    ev = d / "eval" / "evaluations.npz"
    curve = ""
    if ev.is_file():
        z = np.load(ev)
        curve = " ".join(f"{x:.1f}" for x in z["results"].mean(axis=1))
    kw = meta.get("env_kwargs", {})
    opts = {**meta.get("learnability", {}), **kw}  # "learnability": model.json of the first experiments
    settings = [f"{meta['algo']}", f"{meta.get('scene', '?')}", f"hold {opts.get('hold_ticks', 1)}"]
    if opts.get("residual"):
        settings.append(f"res {opts['residual']}")
    if opts.get("chatter_weight"):
        settings.append(f"chatter {opts['chatter_weight']}")
    for k in ("effort_weight", "history", "terminate_on_catch"):
        if k in kw:
            settings.append(f"{k} {kw[k]}")
    if meta.get("overrides"):
        settings.append(f"set {meta['overrides']}")
    st = meta.get("train_stats_last_episodes", {})
    best = (meta.get("validation") or {}).get("best") or {}
    row = {"run": d.name, "settings": ", ".join(settings), "steps": meta["steps"], "ticks": meta.get("ticks"),
           "wall_s": meta["wall_time_s"], "ticks_per_s": meta.get("ticks_per_s"),
           "train_return_first": st.get("return_first_mean"), "train_return_last": st.get("return_mean"),
           "val_best": best.get("mean_reward"), "val_best_step": best.get("step"), "val_curve": curve}
    test = d / "test.json"
    if test.is_file():
        t = json.loads(test.read_text())["policies"]
        for name, s in t.items():
            key = "pd" if name == "pd-penetration" else "agent" if name not in ("passive",) else None
            if key:
                row[f"{key}_intE"] = s["energy_integral_ms"]
                row[f"{key}_catch"] = s["time_to_catch_median_s"]
                row[f"{key}_bounces"] = s["bounces"]
                row[f"{key}_rmsN"] = s["rms_force_N"]
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+")
    a = p.parse_args(argv)
    for d in a.runs:
        r = _row(Path(d))
        print(json.dumps(r))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
