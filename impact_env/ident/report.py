"""What an identification gives its user: the calibrated scene file, a report, its figures.

The scene file (``base = "..."`` and only what the logs changed) keeps the rig's *description*
apart from its *hardware*, as the target does: the fields the controller also reads (the pad's
``c`` and body 2's mass, which set the observation's reference scales; the force transducer's
top mass m2', which eq 4.4's detector uses; the command scale, which turns a law's force into a
command) stay the base's, and their identified values go to one-point ranges under
``[randomize]`` (``c = [v, v]``): the simulated hardware is the identified one, while every
policy meets the observation scales and constants it was made for, exactly as on the target
serving the base scene.  The fields only the hardware has (restitution, suspension, shaker band
and coil, sensor offsets and noise, delays) are set directly.  The identification body's m1 is
reported but not written: the base's drops (``rig``: 0.08-0.12 kg) are the benchmark's.

``--ranges K`` widens each identified field that has a ``[randomize]`` field to
``value * exp(+-K sigma)`` (sigma its relative standard uncertainty), for training on the
identified rig with its uncertainty (:func:`scene_text`).
"""

from __future__ import annotations

import datetime
import json
import math
from pathlib import Path

import numpy as np

from impact_env.figstyle import figure_path, save_figure
from impact_env.ident.fit import Fit
from impact_env.ident.model import FIELD_MAP, FIELDS, NAMES, PARAMS

# a fitted field -> how it is written: ("fixed", dotted field) or ("range", randomize field, factor of base?)
WRITE = {
    "effects.command_scale": ("range", "command_gain", True),  # the range holds value / base
    "plant.suspension_stiffness": ("fixed", "suspension_stiffness", False),
    "plant.suspension_damping": ("fixed", "suspension_damping", False),
    "effects.shaker.highpass_hz": ("fixed", None, False),
    "effects.shaker.lowpass_hz": ("fixed", "shaker_lowpass_hz", False),
    "effects.shaker.coil_inductance": ("fixed", "shaker_coil_inductance", False),
    "effects.sensors.force.top_mass": ("range", "top_mass", False),
    "plant.m2": ("range", "m2", False),
    "plant.c": ("range", "c", False),
    "plant.restitution": ("fixed", "restitution", False),
    "plant.m1": ("report", None, False),
}
UNITS = {"effects.command_scale": "N", "plant.suspension_stiffness": "N/m",
         "plant.suspension_damping": "N s/m", "effects.shaker.highpass_hz": "Hz",
         "effects.shaker.lowpass_hz": "Hz", "effects.shaker.coil_inductance": "H",
         "effects.sensors.force.top_mass": "kg", "plant.m2": "kg", "plant.c": "N/m^1.5",
         "plant.restitution": "", "plant.m1": "kg"}


def field_table(fit: Fit) -> list[dict]:
    """One row per fitted scene field: base value, identified value, relative and absolute
    standard uncertainty, status ("identified", "not identified: base", "not separated: fitted")."""
    assert fit.model is not None
    model = fit.model
    vals = model.fields(fit.x)
    cov = FIELD_MAP @ fit.cov @ FIELD_MAP.T
    rel = np.sqrt(np.maximum(np.diag(cov), 0.0))
    rows = []
    for k, f in enumerate(FIELDS):
        params = [NAMES.index(p) for p in _params_of(f)]
        unfit = [NAMES[j] for j in params if not fit.identified[j]]
        if not unfit:
            status = "identified"
        elif all(fit.fixed.get(p) == "base" for p in unfit) and len(unfit) == len(params):
            status = "not identified (base value kept)"
        else:
            status = "not separated (" + ", ".join(f"{p} {fit.fixed.get(p, '')}" for p in unfit) + ")"
        v = vals[f]
        rows.append({"field": f, "unit": UNITS[f], "base": float(model.field0[k]), "value": float(v),
                     "rel_sigma": float(rel[k]), "sigma": float(v * rel[k]), "status": status,
                     "write": WRITE[f][0]})
    return rows


def _params_of(field: str) -> list[str]:
    return list(FIELDS[field])


def to_json(fit: Fit) -> dict:
    """Everything the fit found, JSON-ready (the mismatch map reads the bands from it)."""
    rows = field_table(fit)
    return {
        "format": "impact-env-identification", "version": 1,
        "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "logs": fit.logs, "fields": rows,
        "sensors": {k: vars(v) for k, v in fit.sensors.items()},
        "delays_ticks": {"actuator": fit.k_act, "sensor": fit.k_sens}, "delay_cost": fit.delay_cost,
        "parameters": {p.name: {"value": fit.value(p.name),
                                "rel_sigma": float(math.sqrt(max(fit.cov[j, j], 0.0))),
                                "identified": bool(fit.identified[j]), "fixed": fit.fixed.get(p.name, "")}
                       for j, p in enumerate(PARAMS)},
        "correlations": _strong_correlations(fit),
        "correlation_matrix": {"names": list(NAMES), "rho": np.round(fit.correlations(), 4).tolist()},
        "chi2_red": fit.chi2_red, "n_samples": fit.n_samples,
        "residual_rms": fit.residual_rms, "stages": fit.stages, "wall_s": fit.wall_s,
        "base_toml": fit.base_toml,
    }


def _strong_correlations(fit: Fit, level: float = 0.9) -> list[dict]:
    r = fit.correlations()
    out = []
    for i in range(len(NAMES)):
        for j in range(i + 1, len(NAMES)):
            if abs(r[i, j]) >= level:
                out.append({"a": NAMES[i], "b": NAMES[j], "rho": float(r[i, j])})
    return out


def _num(v: float) -> str:
    return repr(float(v))


def _pm(row: dict) -> str:
    if row["rel_sigma"] <= 0:
        return f"{row['status']}"
    u = f" {row['unit']}" if row["unit"] else ""
    return f"+- {row['sigma']:.3g}{u} ({100 * row['rel_sigma']:.2g} %), {row['status']}"


def scene_text(fit: Fit, base_ref: str, ranges_k: float | None = None, name: str | None = None) -> str:
    """The calibrated scene file (module doc): ``base = base_ref`` and what the logs changed."""
    rows = {r["field"]: r for r in field_table(fit)}
    base_name = fit.model.base.name if fit.model is not None else "base"
    fixed: dict[str, dict[str, tuple[str, str]]] = {}
    rand: dict[str, tuple[str, str]] = {}
    known: list[str] = []  # the one-point ranges: measured values, told to the model-based laws
    notes: list[str] = []

    def put(dotted: str, value, comment: str) -> None:
        table, _, key = dotted.rpartition(".")
        fixed.setdefault(table, {})[key] = (value, comment)

    for f, row in rows.items():
        how, rz, relative = WRITE[f]
        if row["status"].startswith("not identified"):
            notes.append(f"{f}: not identified by these logs (relative uncertainty above "
                         f"{100 * 0.1:g} % when fitted): the base value {row['base']:g} is kept")
            continue
        comment = _pm(row)
        if how == "report":
            notes.append(f"{f} of the identification body: {row['value']:.6g} {row['unit']} {comment} (not "
                         "written: the base's drops are the benchmark's)")
            continue
        v = row["value"] / row["base"] if relative else row["value"]
        if how == "fixed":
            put(f, _num(row["value"]), comment)
        if rz is not None and (how == "range" or ranges_k):
            s = row["rel_sigma"] * (ranges_k or 0.0) if ranges_k else 0.0
            lo, hi = v * math.exp(-s), v * math.exp(s)
            if rz == "restitution":
                hi = min(hi, 1.0)
                lo = min(lo, hi)
            why = ("hardware only: the controller keeps the fixed value" if how == "range" else "")
            rc = f"{f} = {row['value']:.6g} {row['unit']} {comment}" + (f"; {why}" if why else "")
            if ranges_k:
                rc += f"; +-{ranges_k:g} sigma"
            rand[rz] = (f"[{_num(lo)}, {_num(hi)}]", rc)
            if lo == hi:
                known.append(rz)
    for ch, est in fit.sensors.items():
        put(f"effects.sensors.{ch}.offset", _num(est.offset),
            f"+- {est.offset_se:.2g} (quiet episodes, n = {est.n})")
        put(f"effects.sensors.{ch}.noise_std", _num(est.noise_std), f"+- {est.noise_se:.2g} (quiet episodes)")
    rate = fit.model.base.control_rate if fit.model is not None else 1.0
    active = list(fit.model.base.effects.active) if fit.model is not None else []
    base_active = list(active)
    for k, eff, key in ((fit.k_act, "actuator_delay", "actuator_s"),
                        (fit.k_sens, "sensor_delay", "sensor_s")):
        if k > 0:
            put(f"effects.delay.{key}", _num(k / rate), f"{k} ticks (the whole-tick delay that fits best)")
            if eff not in active:
                active.append(eff)
    lines = [
        f"# {name or base_name + '-identified'}: the scene {base_ref!r} calibrated to a rig's own logs by",
        f"# impact-env identify ({datetime.date.today().isoformat()}), from {len(fit.logs)} logs:",
        *[f"#   {p}" for p in fit.logs],
        "# value  +- standard uncertainty (1 sigma, from the fit's Jacobian scaled by its reduced",
        f"# chi-square {fit.chi2_red:.3g}), and whether the logs identified it.  Fields the controller reads",
        "# too (c, m2, m2', the command scale) are one-point ranges under [randomize]: the hardware",
        "# is the identified one, policies keep the observation scales they were made for; and",
        "# control.known_hardware lists them: the model-based laws (mpc) plan on the identified values.",
        *[f"# {n}" for n in notes],
        f"base = {json.dumps(base_ref)}",
        f"name = {json.dumps(name or base_name + '-identified')}",
        "description = "
        f"{json.dumps('calibrated by impact-env identify from ' + str(len(fit.logs)) + ' logs')}",
    ]
    if active != base_active:
        lines += ["", "[effects]", f"active = {json.dumps(active)}  # the identified delays switched on"]
    if known:
        lines += ["", "[control]", f"known_hardware = {json.dumps(known)}  # the one-point ranges below: "
                  "measured, so the model-based laws plan on them"]
    for table in sorted(fixed):
        lines += ["", f"[{table}]"]
        for key, (val, comment) in fixed[table].items():
            lines.append(f"{key} = {val}  # {comment}")
    if rand:
        lines += ["", "[randomize]"]
        for key, (val, comment) in rand.items():
            lines.append(f"{key} = {val}  # {comment}")
    return "\n".join(lines) + "\n"


def markdown(fit: Fit, scene_file: str | None = None) -> str:
    """The report: fitted values beside the base's, residuals per channel, correlations, stages."""
    rows = field_table(fit)
    out = ["# Identification report", "",
           f"{len(fit.logs)} logs, {fit.n_samples} residuals, reduced chi-square {fit.chi2_red:.3f} "
           f"(1 when the model explains the logs down to the sensors' noise), {fit.wall_s:.0f} s.",
           "" if scene_file is None else f"Scene file: `{scene_file}`.", "",
           "| field | base | identified | standard uncertainty | status |", "|---|---|---|---|---|"]
    for r in rows:
        u = f" {r['unit']}" if r["unit"] else ""
        sig = f"{r['sigma']:.3g}{u} ({100 * r['rel_sigma']:.2g} %)" if r["rel_sigma"] > 0 else "-"
        out.append(f"| `{r['field']}` | {r['base']:.6g}{u} | {r['value']:.6g}{u} | {sig} | {r['status']} |")
    out += ["", "| sensor | offset | noise std | samples |", "|---|---|---|---|"]
    for k, e in fit.sensors.items():
        out.append(f"| {k} | {e.offset:.4g} +- {e.offset_se:.2g} | "
                   f"{e.noise_std:.4g} +- {e.noise_se:.2g} | {e.n} |")
    out += ["", f"Delays: actuator {fit.k_act} ticks, sensor {fit.k_sens} ticks (cost at the delays tried: "
            + "; ".join(f"{st}: " + ", ".join(f"{k}: {c:.4g}" for k, c in sorted(d.items()))
                        for st, d in fit.delay_cost.items()) + ")", "",
            "RMS residual per channel (measured minus simulated; compare with the noise above):", "",
            "| episodes | " + " | ".join(fit.sensors) + " |", "|---|" + "---|" * len(fit.sensors)]
    for kind, d in fit.residual_rms.items():
        out.append(f"| {kind} | " + " | ".join(f"{d.get(c, float('nan')):.4g}" for c in fit.sensors) + " |")
    corr = _strong_correlations(fit)
    out += ["", "Strongly correlated parameters (|rho| >= 0.9: the logs determine their combination better "
            "than each): " + (", ".join(f"{c['a']} / {c['b']} {c['rho']:+.3f}" for c in corr) or "none"), ""]
    out += ["What these channels cannot give (structure, not noise): the coil's resistance and inductance "
            "enter only as the pole R/L (the resistance is kept); sensor gains are taken as calibrated (a "
            "gain and the mass it multiplies scale together); the actuator and sensor delays are told apart "
            "only by the drops' timing from the release.", ""]
    return "\n".join(out) + "\n"


def plot(fit: Fit, exps, out_dir, fmt: str = "png") -> list[Path]:
    """Measured against simulated readings for a shaker episode and a drop (labelled, SI units)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    assert fit.model is not None
    out = []
    units = {"accelerometer": "m/s^2", "force": "N", "potentiometer": "m"}
    for kind, title in (("shaker", "shaker only (body 1 held)"), ("ident_drop", "identification drop")):
        e = next((x for x in exps if x.kind == kind), None)
        if e is None:
            continue
        R = fit.model.simulate(e, fit.x[None, :], fit.k_act, fit.k_sens)[0]
        t = np.arange(e.n) / e.rate
        if kind == "shaker":
            i0 = int(0.6 * e.n)
            win = slice(i0, min(e.n, i0 + int(0.01 * e.rate)))
        else:
            on = int(np.argmax(np.abs(e.readings[1:, 1] - fit.sensors["force"].offset) > 5.0)) + 1
            win = slice(max(on - 10, 1), min(e.n, on + int(0.008 * e.rate)))
        fig, axes = plt.subplots(3, 1, figsize=(8, 7.5), sharex=False)
        for c, (ax, ch) in enumerate(zip(axes, ("accelerometer", "force", "potentiometer"), strict=True)):
            w = slice(1, e.n) if ch == "potentiometer" else win
            ax.plot(t[w] * 1e3, e.readings[w, c], ".", ms=2.5, color="0.45", label="measured (log)")
            ax.plot(t[w] * 1e3, R[w, c], "-", lw=1.2, color="C3", label="simulated (identified scene)")
            ax.set_ylabel(f"{ch}, {units[ch]}")
            ax.set_xlabel("time since the episode's start, ms")
            ax.grid(alpha=0.3)
        axes[0].legend(loc="upper right", fontsize=8)
        axes[0].set_title(f"{title}: {Path(e.path).name}")
        fig.tight_layout()
        out.append(save_figure(fig, figure_path(Path(out_dir) / f"fit_{kind}", fmt)))
    return out
