"""Reproduce the thesis's results: figures into docs/ and the claim table docs/reproduction.md.

Runs (each is also an ``impact-env`` command, printed in the table next to the numbers it gives):

1. ideal scene, ``passive`` and ``thesis-ideal`` (sec 3.3 gains), one drop, 0.1 s, started at the
   first touch as in the thesis (``initial.pre_contact_time = 0``) and with the command range
   raised to 5 kN so that the law gets the force it asks for (the thesis's simulation had no
   force limit): figs 3.1 and 3.2a-f, claims of sec 3.4.
2. rig scene as it is (200 N) on its nominal drop (0.1 kg from 50 mm: ``randomize.m1`` and
   ``randomize.drop_height`` cleared, as the thesis dropped one body), ``passive``,
   ``thesis-rig`` at h01 = 2.3e6, 1.8e6, 1.2e6 (h11 = 18)
   and ``pd-penetration``, 20 seeded drops of 0.4 s: fig 4.8, the decay-time claims.
3. rig scene without the force limit (the thesis's simulations of figs 4.6 and 4.7), one drop,
   ``thesis-rig`` at the three gains: figs 4.6 and 4.7, the bounce claims.
4. the gain sweep of fig 4.4 (``impact-env sweep``, log grid, no force limit).

    .venv/bin/python scripts/reproduce_thesis.py [--episodes 20] [--out docs] [--format png|pdf|svg]

About 2-3 minutes on two cores.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import thesis_figures as thesis_figures  # noqa: E402

from impact_env.eval.compare import compare  # noqa: E402
from impact_env.eval.sweep import parse_grid, plot, sweep, write_csv  # noqa: E402
from impact_env.figstyle import DPI, FORMATS  # noqa: E402
from impact_env.scene import load_scene  # noqa: E402

IDEAL_SET = {"initial.pre_contact_time": 0.0, "effects.command_scale": 5000.0}
IDEAL_CMD = ("impact-env compare --scene ideal --set initial.pre_contact_time=0 "
             "--set effects.command_scale=5000 "
             "--policies passive,thesis-ideal --episodes 1 --horizon 0.1 --json")
# the thesis's drop: rig's nominal body and height (rig draws m1 and the drop height per episode)
NOMINAL = {"randomize.m1": [], "randomize.drop_height": []}
NOMINAL_CMD = "--set 'randomize.m1=[]' --set 'randomize.drop_height=[]'"
RIG_POLICIES = ["passive", "thesis-rig", "thesis-rig:h01=1.8e6", "thesis-rig:h01=1.2e6", "pd-penetration"]
RIG_CMD = (f"impact-env compare --scene rig {NOMINAL_CMD} --policies {','.join(RIG_POLICIES)} "
           "--episodes {n} --json")
UNLIMITED_ACTIVE = ["shaker", "sensors", "filters", "detector"]
UNLIM_SET = {"effects.active": UNLIMITED_ACTIVE, "effects.command_scale": 1.0e5, **NOMINAL}
UNLIM_POLICIES = ["thesis-rig", "thesis-rig:h01=1.8e6", "thesis-rig:h01=1.2e6"]
UNLIM_CMD = (f"impact-env compare --scene rig {NOMINAL_CMD} "
             "--set 'effects.active=[\"shaker\",\"sensors\",\"filters\",\"detector\"]' "
             f"--set effects.command_scale=1e5 --policies {','.join(UNLIM_POLICIES)} --episodes 1 --json")
SWEEP_CMD = f"impact-env sweep --scene rig {NOMINAL_CMD} --h01 1e5:5e6:20 --h11 1:1000:20 --log --json"
SCRIPT = "python scripts/reproduce_thesis.py"


def separation_speeds(run, v0: float, k: int = 5) -> list[float]:
    """Body 1's velocity (up positive, / impact speed) at its first ``k`` separations, read at the
    first trace sample without contact (episode 0)."""
    c = run.trace0["contact_force"] > 0
    idx = np.flatnonzero(c[:-1] & ~c[1:]) + 1
    return [float(-run.trace0["v1"][i] / v0) for i in idx[:k]]


def time_below_for_good(t, x, level):
    """First time after which x stays below level (NaN if it ends above)."""
    above = np.flatnonzero(x >= level)
    if len(above) == 0:
        return float(t[0])
    return float("nan") if above[-1] == len(x) - 1 else float(t[above[-1] + 1])


def at(t_ms, x, when_ms):
    return float(x[min(np.searchsorted(t_ms, when_ms), len(x) - 1)])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episodes", type=int, default=20, help="seeded drops per policy on rig (default 20)")
    ap.add_argument("--out", default="docs", help="output folder (default docs)")
    ap.add_argument("--format", default="png", choices=FORMATS,
                    help=f"the figures' file format (default png, {DPI} dpi; impact_env.figstyle)")
    args = ap.parse_args(argv)
    fmt = args.format
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    rows: list[tuple[str, str, str, str]] = []  # claim, thesis, ours, command

    # -- 1. ideal ---------------------------------------------------------------------------------
    ideal = load_scene("ideal", IDEAL_SET)
    runs = compare(ideal, ["passive", "thesis-ideal"], episodes=1, horizon=0.1, trace_rate=1e5)
    off, on = runs["passive"], runs["thesis-ideal"]
    thesis_figures.fig_3_1(off, on, ideal, out / f"fig3_1.{fmt}")
    thesis_figures.fig_3_2(on, ideal, out / f"fig3_2.{fmt}")
    t = thesis_figures.t_ms(on)
    e = thesis_figures.body_energies(on, ideal)
    after = t >= 0
    peak_el = e["elastic"][after].max()
    el_2ms = at(t, e["elastic"], 2.0) / peak_el
    k_peak = np.argmax(np.where(after, e["elastic"], -1))
    below10 = float(t[k_peak + np.argmax(e["elastic"][k_peak:] < 0.1 * peak_el)])
    pen_7ms = at(t, on.trace0["x1"] - on.trace0["x2"], 7.0)
    ke2_peak = float(e["kinetic2"].max())
    v0 = ideal.impact_speed
    v50, v100 = (abs(at(t, on.trace0["v1"], ms)) / v0 for ms in (50, 100))
    s = on.summary
    f, amp = thesis_figures.force_spectrum(on.trace0["force_applied"], float(on.trace_t[1] - on.trace_t[0]))
    band = float(np.sum(amp[(f >= 20) & (f <= 1000)] ** 2) / np.sum(amp[1:] ** 2))
    peak_f = float(np.abs(on.trace0["force_applied"]).max())
    t_peak_f = float(t[np.argmax(np.abs(on.trace0["force_applied"]))])
    rows += [
        ("Ideal: the contact energy is cancelled (sec 3.4, fig 3.2a)", "after about 2 ms, then the bodies "
         "follow each other at the static penetration d",
         f"the pad holds {100 * el_2ms:.0f} % of its peak elastic energy ({1e3 * peak_el:.1f} mJ) at 2 ms "
         f"and first drops below 10 % at {below10:.2f} ms; the penetration is still "
         f"{1e6 * pen_7ms:.0f} um at 7 ms "
         f"(d = {1e6 * ideal.plant.static_penetration:.0f} um); body 2's kinetic energy peaks at "
         f"{1e3 * ke2_peak:.0f} mJ", SCRIPT),
        ("Ideal: body 1 still (fig 3.2b)", "after about 50 ms",
         f"|v1| = {100 * v50:.1f} % of the impact speed at 50 ms, {100 * v100:.1f} % at 100 ms; catch energy "
         f"{100 * s['residual_energy_50ms']:.2f} % at 50 ms, "
         f"{100 * s['residual_energy_100ms']:.3f} % at 100 ms",
         IDEAL_CMD),
        ("Ideal: the bodies stay in contact", "all the time",
         f"contact fraction {s['contact_fraction']:.3f} after the touch, {s['bounces']:.0f} bounces, "
         "exit speed "
         f"{s['exit_speed_ratio']:.2f}", IDEAL_CMD),
        ("Ideal: force spectrum (fig 3.2f)", "most important part in 20-1000 Hz",
         f"{100 * band:.0f} % of the force's energy over 0.1 s lies in 20-1000 Hz", SCRIPT),
        ("Ideal: peak shaker force (fig 3.2e)", "not given in the text",
         f"{peak_f:.0f} N at {t_peak_f:.2f} ms ({s['peak_force_N']:.0f} N in the table)", IDEAL_CMD),
    ]

    # -- 2. rig as it is ---------------------------------------------------------------------------
    rig = load_scene("rig", NOMINAL)
    n = args.episodes
    rr = compare(rig, RIG_POLICIES, episodes=n)
    thesis_figures.fig_4_8({"control off (passive)": rr["passive"],
                            "thesis-rig (2.3e6, 18)": rr["thesis-rig"],
               "pd-penetration": rr["pd-penetration"]}, rig, out / f"fig4_8.{fmt}")
    rig_cmd = RIG_CMD.format(n=n)
    totals = {}
    for spec in ("passive", "thesis-rig", "pd-penetration"):
        run = rr[spec]
        eb = thesis_figures.body_energies(run, rig)
        # the whole system's energy above rest (body 1's catch energy, body 2's kinetic energy, the
        # suspension's about its loaded rest) over body 1's impact energy, as drop's time_to_1pct
        tot = eb["above_rest"] / eb["catch"][0]
        totals[spec] = time_below_for_good(thesis_figures.t_ms(run) / 1e3, tot, 0.01)
    sp, st, sd = rr["passive"].summary, rr["thesis-rig"].summary, rr["pd-penetration"].summary

    def ttc(x):
        return "not within the 0.4 s episode" if not np.isfinite(x) else f"{x:.3f} s"

    def tot(x):
        return "not within 0.4 s" if np.isnan(x) else f"{x:.3f} s"

    rows += [
        ("Rig: uncontrolled decay (sec 4.4, fig 4.8a)", "energy gone in about 0.30-0.35 s",
         f"body 1's catch energy below 1 % for good after {ttc(sp['time_to_catch_median_s'])} "
         f"(median of {n}); "
         f"whole system's energy above rest (body 1 + body 2 + suspension): {tot(totals['passive'])}",
         rig_cmd),
        ("Rig: controlled decay (sec 4.4, fig 4.8a)", "about 0.1 s (total energy)",
         f"thesis-rig (2.3e6, 18): catch energy below 1 % {ttc(st['time_to_catch_median_s'])} "
         f"(caught in {100 * st['caught_fraction']:.0f} % of drops), "
         f"whole system {tot(totals['thesis-rig'])}; "
         f"pd-penetration: {ttc(sd['time_to_catch_median_s'])}, whole system {tot(totals['pd-penetration'])}",
         rig_cmd),
        ("Rig: body 1's energy with control (sec 4.4, fig 4.8b)", "most of it gone after a few ms",
         f"thesis-rig leaves {100 * st['residual_energy_10ms']:.1f} % at 10 ms (passive "
         f"{100 * sp['residual_energy_10ms']:.1f} %); first exit speed {st['exit_speed_ratio']:.2f} "
         "of the impact "
         f"speed (passive {sp['exit_speed_ratio']:.2f})", rig_cmd),
    ]

    # -- 3. rig without force limit: the bounce sequences ----------------------------------------------
    unlim = load_scene("rig", UNLIM_SET)
    ru = compare(unlim, UNLIM_POLICIES, episodes=1)
    thesis_figures.fig_bounces({"h01 = 2.3e6": ru["thesis-rig"]}, unlim, out / f"fig4_6.{fmt}",
                  "Fig 4.6 (ours): thesis-rig h01 = 2.3e6, h11 = 18, rig without force limit")
    thesis_figures.fig_bounces({"h01 = 1.2e6": ru["thesis-rig:h01=1.2e6"]}, unlim, out / f"fig4_7.{fmt}",
                  "Fig 4.7 (ours): thesis-rig h01 = 1.2e6, h11 = 18, rig without force limit")
    v0r = rig.impact_speed
    seqs = {}
    for label, runs_, spec in (("unlimited", ru, "thesis-rig"), ("unlimited", ru, "thesis-rig:h01=1.8e6"),
                               ("unlimited", ru, "thesis-rig:h01=1.2e6"), ("200 N", rr, "thesis-rig"),
                               ("200 N", rr, "thesis-rig:h01=1.8e6"), ("200 N", rr, "thesis-rig:h01=1.2e6")):
        seqs[(label, spec)] = separation_speeds(runs_[spec], v0r)

    def seq(key):
        return ", ".join(f"{x:+.2f}" for x in seqs[key][:5]) or "none"

    rows += [
        ("Rig sim: h01 = 1.2e6, h11 = 18 (fig 4.7)", "diverges: body 1 bounces higher every time",
         "body 1's velocity at successive separations / impact speed (up +): without limit "
         f"{seq(('unlimited', 'thesis-rig:h01=1.2e6'))}; "
         f"with 200 N {seq(('200 N', 'thesis-rig:h01=1.2e6'))}; catch energy at 100 ms "
         f"{100 * ru['thesis-rig:h01=1.2e6'].summary['residual_energy_100ms']:.0f} % (unlimited)", UNLIM_CMD),
        ("Rig sim: h01 = 1.8e6, h11 = 18 (sec 4.4)", "settles after a couple of bounces",
         f"without limit {seq(('unlimited', 'thesis-rig:h01=1.8e6'))}; "
         f"with 200 N {seq(('200 N', 'thesis-rig:h01=1.8e6'))}",
         UNLIM_CMD),
        ("Rig sim: h01 = 2.3e6, h11 = 18 (fig 4.6)",
         "catches at once; about 5 % of the falling speed after 2 bounces",
         f"without limit {seq(('unlimited', 'thesis-rig'))}; with 200 N {seq(('200 N', 'thesis-rig'))}",
         UNLIM_CMD),
    ]

    # -- 4. fig 4.4: the gain sweep -----------------------------------------------------------------------
    axes = (("h01", parse_grid("h01", "1e5:5e6:20", True)), ("h11", parse_grid("h11", "1:1000:20", True)))
    sw = sweep(rig, "thesis-rig", axes, t_end=0.02)
    plot(sw, out / f"fig4_4.{fmt}", log=True,
         title="Fig 4.4 (ours): thesis-rig gain sweep, rig without force limit")
    (out / "results").mkdir(parents=True, exist_ok=True)  # the records; the figures and page in out
    write_csv(sw, out / "results" / "fig4_4_sweep.csv")
    m = sw.metrics
    stop = m["exit_speed_ratio"] < 0.05
    b = sw.best
    rows += [
        ("Rig sim: force needed (sec 4.3, fig 4.4)",
         "many pairs stop body 1 totally, with more force than the shaker has",
         f"{int(stop.sum())} of {stop.size} pairs leave body 1 below 5 % of its speed; "
         "the least force among them is "
         f"{m['peak_force_N'][stop].min():.0f} N" if stop.any() else "no pair stops body 1", SWEEP_CMD),
        ("Rig sim: exit speed with about 200 N (sec 4.3)", "about 30 % of the impact speed",
         f"best pair within {sw.force_limit_N:.0f} N: h01 = {b['h01']:.3g}, h11 = {b['h11']:.3g}, exit speed "
         f"{b['exit_speed_ratio']:.2f} at {b['peak_force_N']:.0f} N "
         f"({int(sw.within_limit.sum())} pairs within the limit)"
         if b else "no pair within the limit", SWEEP_CMD),
    ]

    data = {"rows": rows, "seconds": time.perf_counter() - t_start,
            "ideal": {k: v.summary for k, v in runs.items()}, "rig": {k: v.summary for k, v in rr.items()},
            "rig_unlimited": {k: v.summary for k, v in ru.items()}, "sweep": sw.to_json(),
            "separations": {f"{a}|{b}": v for (a, b), v in seqs.items()}, "episodes": n}
    (out / "results" / "reproduction.json").write_text(json.dumps(data, indent=1, default=_jsonable))
    write_markdown(out / "reproduction.md", rows, n, fmt)
    print(f"wrote {out}/reproduction.md and figures in {data['seconds']:.0f} s")
    for r in rows:
        print(f"- {r[0]}: thesis {r[1]}; ours {r[2]}")
    return 0


def _jsonable(v):
    if isinstance(v, float) and not np.isfinite(v):
        return None
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return str(v)


def write_markdown(path: Path, rows, n: int, fmt: str = "png") -> None:
    notes = (Path(__file__).resolve().parent / "reproduction_notes.md").read_text()
    # the notes link the figures as figN_M.png: point them at the files this run wrote
    notes = re.sub(r"(\]\(fig[0-9_]+)\.png\)", rf"\1.{fmt})", notes)
    command = "python scripts/reproduce_thesis.py" + ("" if fmt == "png" else f" --format {fmt}")
    lines = ["# Reproducing the thesis", "",
             f"Generated by `{command}` (figures `docs/fig*.{fmt}`, raw numbers in "
             "`docs/results/reproduction.json`); do not edit by hand, edit `scripts/reproduction_notes.md` "
             "for the prose.",
             "", "| claim | thesis | ours | command |", "| --- | --- | --- | --- |"]
    for claim, thesis, ours, cmd in rows:
        cells = (x.replace("|", "\\|") for x in (claim, thesis, ours))  # a pipe would end the cell
        lines.append("| {} | {} | {} | ".format(*cells) + f"`{cmd}` |")
    lines += ["", f"Rig numbers are over {n} seeded drops (episode j seeded j) of the thesis's drop: the "
              "rig's nominal 0.1 kg body from 50 mm (the `rig` preset draws the body's mass and the drop "
              "height per episode; the reproduction clears those ranges), so the drops differ only in "
              "sensor noise.", "", notes]
    path.write_text("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
