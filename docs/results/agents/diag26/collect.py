"""Keep what docs/agents-results.md's diagnostic tables of issue 26 need from the run folders of the
diagnostic runs (runs/x/NAME, made by run.sh): for each run, its model.json without the bulky keys,
with the command-line options and the load average (uptime before and after) of run.sh's log.

    python docs/results/agents/diag26/collect.py runs/x          # writes docs/results/agents/diag26/NAME.json
"""

import json
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
KEEP = ("algo", "observation", "history", "scene", "env_kwargs", "hold_ticks", "residual", "steps", "ticks", "envs",
        "seed", "wall_time_s", "steps_per_s", "env_time_s", "env_share", "torch_threads", "hyperparameters",
        "policy", "validation", "interrupted", "load_average")


def main(runs: Path) -> None:
    log = (runs / "series.log").read_text() if (runs / "series.log").is_file() else ""
    starts = {m.group(1): (m.group(2), float(m.group(3)))
              for m in re.finditer(r"=== (\S+): (.*?)  \(.*?load average: ([\d.]+)", log)}
    ends = {}
    for block in log.split("=== ")[1:]:
        name = block.split(":", 1)[0]
        m = re.search(r"load after: .*?load average: ([\d.]+)", block)
        if m:
            ends[name] = float(m.group(1))
    for d in sorted(p for p in runs.iterdir() if (p / "model.json").is_file()):
        meta = json.loads((d / "model.json").read_text())
        rec = {k: meta.get(k) for k in KEEP}
        options, load0 = starts.get(d.name, (None, None))
        rec["name"] = d.name
        rec["options"] = options
        if rec.get("load_average") is None:
            rec["load_average"] = [load0, ends.get(d.name)]
        (HERE / f"{d.name}.json").write_text(json.dumps(rec, indent=1, default=str) + "\n")
        print(d.name, options)


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "runs/x"))
