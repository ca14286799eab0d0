"""``python -m agents.train --quick --teacher law:NAME`` measured: its wall and CPU time, its student's
energy integral on the held-out drops against the oracle's, what limits it, and whether it ships.

    python scripts/quick_teacher.py [--teacher law:mpc-state] [--out runs/quick_teacher] \\
        [--record docs/results/agents/quick_teacher.json] [--workers 1] [--episodes 100] \\
        [--scenes rig,rig-randomized] [--oracle kept|run]
    python scripts/quick_teacher.py --docs [--record ...]  # its block in docs/agents-distillation.md

What it runs and records (JSON: figures, commands, versions, CPU, date, load):

* **the quick run**: ``python -m agents.train --quick --teacher T --out OUT/sensors``, as a user
  types it, in a child process: its wall time and its CPU time (user + system, from
  ``resource.getrusage(RUSAGE_CHILDREN)``) with the machine's 1-minute load average at its start
  and end (a loaded machine stretches the wall time, not the CPU time), and whether it compiled
  numba kernels (a first run in a checkout does, and its wall time holds that compile);
* **the information**: the same DAgger budget (:data:`agents.train.QUICK_DAGGER`) with a student
  that reads the true state too (``agents.distill --student-observation both``): what the sensors
  cost, learning apart;
* **the learning**: the same student with a longer budget (:data:`LONGER` over the quick one);
* **the drops**: ``compare`` on drops 1000..1000 + episodes - 1 of ``rig`` and ``rig-randomized``
  (the held-out drops of docs/agents-results.md): ``pd-penetration``, the teacher, the privileged
  student and the sensor student; with ``--oracle kept`` the oracle's per-drop energy integrals
  are the ones kept in ``docs/results/agents/SCENE.npz`` (``scripts/agents_report.py``'s
  ``oracle:warm=given``), and the ``pd-penetration`` row here must equal the one kept there drop by
  drop (the same drops and simulator, checked); with ``--oracle run`` the oracle
  (``oracle:warm=given``, warm-started from the other rows' commands, as there) runs in the same
  comparison (seconds of CPU per drop: ``--episodes 20`` on a loaded machine); the ratio is the
  mean energy integral over the oracle's, as docs/agents-results.md gives it;
* **shipping**: the sensor student's compiled policy in the C export's float32 build against the
  double target on drops 0..9 of each scene (``scripts/agents_report.py``'s check, the bound of
  docs/rig.md).

Re-measure on a quiet machine with the command in the record's ``command`` field.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BEGIN, END = "<!-- quick_teacher:begin -->", "<!-- quick_teacher:end -->"
DEFAULT_RECORD = ROOT / "docs" / "results" / "agents" / "quick_teacher.json"
SCENES = ("rig", "rig-randomized")
TEST_SEED, EPISODES = 1000, 100
ORACLE = "oracle:warm=given"  # scripts/agents_report.py's
# the longer budget, over the quick one: 8 iterations of 128 envs of 0.1 s episodes, fitted on
# 2.4 M samples each (about a minute and a half of training on two cores)
LONGER = {"iterations": 8, "envs": 128, "train_horizon": 0.1, "fit_samples": 2_400_000}


def _child_run(cmd: list[str], log: Path) -> dict:
    """Run ``cmd`` (stdout and stderr to ``log``); its wall time, CPU time and the load around it."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    with log.open("w") as f:
        rc = subprocess.run(cmd, cwd=ROOT, stdout=f, stderr=subprocess.STDOUT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}).returncode
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if rc != 0:
        raise SystemExit(f"quick_teacher: {' '.join(cmd)} exited {rc}; see {log}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    text = log.read_text()
    return {"command": " ".join(cmd), "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
            "user_s": round(after.ru_utime - before.ru_utime, 1),
            "load_average": [round(load0, 2), round(os.getloadavg()[0], 2)],
            "compiled": "impact_env: compiled" in text,  # numba kernels: the wall time holds their compile
            "last_lines": text.strip().splitlines()[-3:]}


def _evaluate(scene: str, specs: dict[str, str], workers: int, episodes: int, oracle_source: str) -> dict:
    """Per-drop energy integrals of every spec on the held-out drops, with the oracle's (the kept
    record's, or run here)."""
    from impact_env.eval.compare import compare

    extra = [ORACLE] if oracle_source == "run" else []
    runs = compare(scene, ["pd-penetration", *specs.values(), *extra], episodes=episodes, seed=TEST_SEED,
                   workers=workers, progress=False)
    pd_now = np.asarray(runs["pd-penetration"].metrics["energy_integral_ms"])
    if oracle_source == "run":
        oracle = np.asarray(runs[ORACLE].metrics["energy_integral_ms"])
    else:
        kept = np.load(ROOT / "docs" / "results" / "agents" / f"{scene}.npz", allow_pickle=True)
        pd_kept = kept["pd-penetration|energy_integral_ms"][:episodes]
        if not np.allclose(pd_now, pd_kept, rtol=1e-9, atol=0):
            raise SystemExit(f"quick_teacher: pd-penetration on {scene}'s drops {TEST_SEED}.. differs from "
                             "the kept record: the drops (or the simulator) changed; rerun "
                             "scripts/agents_report.py, or use --oracle run")
        oracle = kept["oracle|energy_integral_ms"][:episodes]
    rows = {"pd-penetration": pd_now, **{name: np.asarray(runs[spec].metrics["energy_integral_ms"])
                                         for name, spec in specs.items()}}
    out = {"oracle_mean_ms": round(float(oracle.mean()), 4)}
    for name, e in rows.items():
        out[name] = {"mean_ms": round(float(e.mean()), 4),
                     "ratio_to_oracle": round(float(e.mean() / oracle.mean()), 4),
                     "worst_drop_ms": round(float(e.max()), 3)}
    return out


def c_builds_check(model: Path, scenes: list[str], drops: int = 10, ticks: int = 2000) -> dict | None:
    """The student's C export against the double target (the numba kernels) on drops ``0 .. drops -
    1`` of each scene (:func:`impact_env.deploy.parity.check`, the bounds of docs/rig/c-export.md):
    the double build's drops that are not bitwise, and the float32 build's failures or the reason
    it has none; None without a C compiler."""
    import tempfile

    from impact_env.config import ConfigError
    from impact_env.deploy import parity
    from impact_env.deploy.c_export import float32_refusal, write_c
    from impact_env.policy.export import export_policy
    from impact_env.scene import load_scene

    try:
        parity.find_cc()
    except ConfigError:
        return None
    out: dict = {"bound": parity.F32_BOUND, "drops": 0, "double_failed": [], "failed": [], "max_same": 0.0,
                 "float32_refused": ""}
    for name in scenes:
        scene = load_scene(name)
        pol = export_policy(f"ppo:{model}", scene)
        out["float32_refused"] = float32_refusal(pol)
        with tempfile.TemporaryDirectory(prefix="quick-teacher-c-") as tmp:
            write_c(pol, scene, Path(tmp), force=True)
            builds = (False,) if out["float32_refused"] else (False, True)
            for float32 in builds:
                reports = parity.check(pol, scene, Path(tmp), seeds=range(drops), ticks=ticks, float32=float32)
                for seed, r in enumerate(reports):
                    if not r.verdict(float32)[0]:
                        out["failed" if float32 else "double_failed"].append(f"{name}:{seed}")
                    if float32:
                        out["max_same"] = max(out["max_same"], r.max_abs_same)
        out["drops"] += drops
    return out


def measure(args) -> dict:
    from agents.train import QUICK_DAGGER, QUICK_SCENE, _versions

    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise SystemExit(f"quick_teacher: --out {out} is not empty; choose another folder")
    out.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    quick = _child_run([py, "-m", "agents.train", "--quick", "--teacher", args.teacher, "--out",
                        str(out / "sensors")], out / "sensors.log")
    priv_cmd = [py, "-m", "agents.distill", "--teacher", args.teacher, "--out", str(out / "privileged"),
                "--student-observation", "both", "--scene", QUICK_SCENE]
    for key, value in QUICK_DAGGER.items():
        if key == "student_observation":
            continue
        for one in (value if isinstance(value, tuple) else (value,)):  # a tuple: the option repeated
            priv_cmd += [f"--{key.replace('_', '-')}", str(one)]
    privileged = _child_run(priv_cmd, out / "privileged.log")
    # the same student with a longer budget (the learning the quick budget leaves out)
    longer_cmd = [py, "-m", "agents.distill", "--teacher", args.teacher, "--out", str(out / "longer"),
                  "--scene", QUICK_SCENE]
    for key, value in {**QUICK_DAGGER, **LONGER}.items():
        for one in (value if isinstance(value, tuple) else (value,)):
            longer_cmd += [f"--{key.replace('_', '-')}", str(one)]
    longer = _child_run(longer_cmd, out / "longer.log")
    law = args.teacher.split(":", 1)[1]
    sensors_model = out / "sensors" / "best_model.zip"
    specs = {"teacher": law, "privileged student": f"ppo:{out / 'privileged' / 'best_model.zip'}",
             "sensor student": f"ppo:{sensors_model}",
             "sensor student, longer budget": f"ppo:{out / 'longer' / 'best_model.zip'}"}
    scene_names = args.scenes.split(",")
    scenes = {scene: _evaluate(scene, specs, args.workers, args.episodes, args.oracle)
              for scene in scene_names}
    meta = json.loads((out / "sensors" / "model.json").read_text())
    priv_meta = json.loads((out / "privileged" / "model.json").read_text())
    c_check = c_builds_check(sensors_model, scene_names)
    options = "" if (args.episodes, args.scenes, args.oracle) == (EPISODES, ",".join(SCENES), "kept") else (
        f" --episodes {args.episodes} --scenes {args.scenes} --oracle {args.oracle}")
    return {
        "teacher": args.teacher,
        "command": f"python scripts/quick_teacher.py --teacher {args.teacher} --out {args.out}{options}",
        "episodes": args.episodes, "oracle_source": args.oracle,
        "quick": quick, "privileged_run": privileged, "longer_run": longer, "longer_budget": LONGER,
        "budget": QUICK_DAGGER, "scene_trained": meta["scene"],
        "training_wall_s": meta["wall_time_s"], "training_cpu_s": meta["cpu_time_s"],
        "validation": {"sensor student": meta["validation"]["best"],
                       "privileged student": priv_meta["validation"]["best"]},
        "imitation_error": {"sensor student": meta["imitation_error"],
                            "privileged student": priv_meta["imitation_error"]},
        "held_out": scenes, "c_float32": c_check,
        "versions": _versions(), "cpu": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(), "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
    }


def block(rec: dict) -> str:
    """The generated block of docs/agents-distillation.md (no dates, loads or CPU models: those stay in
    the record)."""
    scenes = list(rec["held_out"])
    rows = [f"| policy | reads | {scenes[0]}: energy integral ms, / oracle's |"
            + "".join(f" {s}: ms, / oracle's |" for s in scenes[1:]),
            "| --- | --- |" + " --- |" * len(scenes)]
    estimate = rec["budget"].get("student_observation") == "estimate"
    reads = {"pd-penetration": "the sensors (classic law)", "teacher": "the true state (the teacher)",
             "privileged student": "the sensors and the true state",
             "sensor student": ("the sensors and the filter's estimate from them" if estimate
                                else "the sensors (what ships)")}
    reads["sensor student, longer budget"] = reads["sensor student"]
    for name in ("pd-penetration", "teacher", "privileged student", "sensor student",
                 "sensor student, longer budget"):
        if name not in rec["held_out"][scenes[0]]:
            continue
        cells = [f"{rec['held_out'][s][name]['mean_ms']:.2f}, "
                 f"x{rec['held_out'][s][name]['ratio_to_oracle']:.2f}" for s in scenes]
        rows.append(f"| {name} | {reads[name]} | " + " | ".join(cells) + " |")
    oracle = ", ".join(f"{s} {rec['held_out'][s]['oracle_mean_ms']:.2f} ms" for s in scenes)
    episodes = rec.get("episodes", EPISODES)
    drops = f"Held-out drops {TEST_SEED}..{TEST_SEED + episodes - 1}"
    oracle_text = ("the oracle (`oracle:warm=given`) run in the same comparison"
                   if rec.get("oracle_source") == "run" else "the oracle's kept per-drop results")
    c = rec["c_float32"]
    if c is None:
        ships = "not checked (no C compiler)"
    elif "double_failed" not in c:  # a record of the float32 check alone
        ships = (f"{'yes' if not c['failed'] else 'no'}: the float32 C build within {c['bound']:.0e} of full "
                 f"scale on {c['drops'] - len(c['failed'])} of {c['drops']} drops (largest difference "
                 f"{c['max_same']:.2e})")
    else:
        double = (f"the double C build bitwise the simulator's kernels on {c['drops'] - len(c['double_failed'])} "
                  f"of {c['drops']} drops")
        if c["float32_refused"]:
            ships = f"in double only: {double}; no float32 build ({c['float32_refused']})"
        else:
            ships = (f"{'yes' if not c['failed'] and not c['double_failed'] else 'no'}: {double}; the float32 "
                     f"build within {c['bound']:.0e} of full scale on {c['drops'] - len(c['failed'])} of "
                     f"{c['drops']} drops (largest difference {c['max_same']:.2e})")
    q = rec["quick"]
    compiled = " (a first run: that includes compiling the numba kernels)" if q.get("compiled") else ""
    budget = rec["budget"]
    noise = (f", the teacher's applied command perturbed by {budget['teacher_noise']} of full scale"
             if budget.get("teacher_noise") else "")
    ignored = f" without the {', '.join(budget['ignore'])}" if budget.get("ignore") else ""
    return "\n".join([
        BEGIN,
        f"*Written by `python scripts/quick_teacher.py --docs` from `docs/results/agents/quick_teacher.json` "
        f"(made by `{rec['command']}`); do not edit by hand.*",
        "",
        f"`python -m agents.train --quick --teacher {rec['teacher']}`: DAgger, {rec['budget']['iterations']} "
        f"iterations of {rec['budget']['envs']} envs of `{rec['scene_trained']}`, "
        f"{budget['train_horizon']} s episodes{noise}, a student on "
        + (f"its sensor frame{ignored} and the filter's estimate" if estimate else
           f"the last {budget['history']} sensor frames{ignored}")
        + f" acting every control period: {q['wall_s']:.0f} s of wall time for the whole "
        f"command"
        f"{compiled} ({q['cpu_s']:.0f} s of CPU; the training alone {rec['training_wall_s']:.0f} s, "
        f"{rec['training_cpu_s']:.0f} s of CPU), on a machine whose load the record keeps.  {drops}; "
        f"{oracle_text}, its mean: {oracle}.",
        "",
        *rows,
        *(["", f"The longer budget: `python -m {rec['longer_run']['command'].split(' -m ', 1)[1]}` "
           f"({rec['longer_run']['wall_s']:.0f} s of wall time for the whole command)."]
          if "longer_run" in rec else []),
        "",
        f"Ships: {ships}.",
        END,
    ])


def write_docs(rec: dict, doc: Path) -> None:
    text = doc.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"quick_teacher: {doc} has no {BEGIN} ... {END} markers")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    doc.write_text(head + block(rec) + tail)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--teacher", default="law:mpc-state")
    p.add_argument("--out", default="runs/quick_teacher")
    p.add_argument("--record", default=str(DEFAULT_RECORD))
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--episodes", type=int, default=EPISODES,
                   help=f"held-out drops per scene (default {EPISODES})")
    p.add_argument("--scenes", default=",".join(SCENES), help="the scenes of the held-out drops")
    p.add_argument("--oracle", choices=("kept", "run"), default="kept",
                   help="the oracle's per-drop results: kept (docs/results/agents/SCENE.npz, checked to be "
                        "for the same drops) or run (in the comparison; seconds of CPU per drop)")
    p.add_argument("--docs", action="store_true",
                   help="only write the record's block into docs/agents-distillation.md")
    p.add_argument("--doc", default=str(ROOT / "docs" / "agents-distillation.md"))
    args = p.parse_args(argv)
    record = Path(args.record)
    if not args.docs:
        rec = measure(args)
        record.parent.mkdir(parents=True, exist_ok=True)
        record.write_text(json.dumps(rec, indent=2, default=str) + "\n")
        print(json.dumps({k: rec[k] for k in ("quick", "held_out", "c_float32")}, indent=2, default=str))
    write_docs(json.loads(record.read_text()), Path(args.doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
