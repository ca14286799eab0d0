"""A compiled policy as one dependency-free C99 translation unit: ``impact_policy.c`` and
``impact_policy.h`` (``impact-env export SPEC --scene S --c DIR``).

The C file does, tick by tick, what the rig target's tick does between the DAQ readings and the
drive command (:mod:`impact_env.rig.controller`, onboard mode): sensor conditioning (the scene's
SOS filters), the contact detector of thesis eq 4.4, the observation (scaling, clipping,
history frame), the policy (a classic law, or an MLP with stable-baselines3's output
transform), the hold (the policy acts every ``hold_ticks`` ticks) and residual law, and the
safety layer (non-finite commands, the latched travel limit, the peak and RMS clamps;
:mod:`impact_env.rig.safety`).  Every number in it is printed from the same arrays the numba
kernels read (the policy's packed arrays, the scene's filter coefficients, the detector's and the
safety layer's parameter vectors), with ``repr`` (shortest round-trip), never retyped; the code
mirrors the kernels operation by operation, in the same order, so that the float64 build is
bitwise the numba target where both use the same libm (:mod:`impact_env.deploy.parity`).

The generated API (``impact_real`` is ``double``, or ``float`` when ``IMPACT_FLOAT32`` is
defined before including the header or on the compiler's command line)::

    void impact_init(impact_state *s);     /* power-on: all state zero, the RMS window cool */
    void impact_reset(impact_state *s);    /* a new episode: the next step is its tick 0 */
    void impact_idle(impact_state *s, long ticks);   /* time disarmed: the RMS window cools */
    uint32_t impact_step(impact_state *s, const impact_real readings[4],
                         impact_real *command, impact_real *force_n);

No allocation, no mutable globals, only ``<math.h>``, ``<stdint.h>`` and ``<string.h>``.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from impact_env.config import ConfigError
from impact_env.control import behind_filter, laws, plausibility
from impact_env.control import mlp as MLP
from impact_env.control.estimation import features as estimate
from impact_env.control.estimation.c_text import ekf_c
from impact_env.control.front_end import F_DETECTOR, F_FILTERS, FrontEnd
from impact_env.control.laws import pd_penetration
from impact_env.control.laws.estimate import MEMORY as FALLBACK_MEMORY
from impact_env.control.laws.estimate import SensorReads
from impact_env.control.observation import OBS_LIMIT
from impact_env.control.policy import CompiledPolicy
from impact_env.effects import detector as contact_detector
from impact_env.effects.filters import tpt_sections
from impact_env.rig import safety as rig_safety

HEADER_NAME = "impact_policy.h"
SOURCE_NAME = "impact_policy.c"
CHANNELS = ("accelerometer_mps2", "force_N", "potentiometer_m", "body1_displacement_m")


def _r(x: float) -> str:
    """A C double literal that parses back to exactly ``x``."""
    x = float(x)
    if not math.isfinite(x):
        raise ConfigError(f"cannot write the non-finite constant {x!r} into C")
    s = repr(x)
    return s if ("e" in s or "." in s) else s + ".0"


def _section_table(sections) -> str:
    """The C initialiser rows of float64[channel, section, 6] (a table per channel, a brace per
    section), each channel named."""
    rows = []
    for c in range(sections.shape[0]):
        secs = ",\n        ".join("{" + ", ".join(_r(x) for x in sections[c, k]) + "}"
                                     for k in range(sections.shape[1]))
        rows.append(f"    {{ /* {CHANNELS[c]} */\n        {secs}\n    }}")
    return ",\n".join(rows)


def _arr(values, per_line: int = 4) -> str:
    vals = [_r(v) for v in np.asarray(values, dtype=np.float64).ravel()]
    lines = [", ".join(vals[i:i + per_line]) for i in range(0, len(vals), per_line)]
    return "{\n    " + ",\n    ".join(lines) + "\n}" if vals else "{0}"


def _ident(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).upper()


def _memory(pol) -> int:
    """The floats of memory a policy's classic law, or the filter before its network, keeps (at
    least 1: C has no empty array)."""
    if pol.estimator is not None:
        return behind_filter.TAIL
    return max(laws.BY_NAME[pol.law["name"]].memory, 1)


def _has_memory(pol) -> bool:
    return pol.law is not None or pol.estimator is not None


def float32_refusal(policy: CompiledPolicy) -> str:
    """Why ``policy``'s C file has no float32 build (a law's ``c_double_only``, naming the law, or
    the filter before a network), or "" when it has one."""
    if policy.estimator is not None:
        return ("the filter before its network has no float32 build: the float32 front end's readings, a "
                "few last places from the double build's, move the filter's estimate in the first contact, "
                "the network turns that into 1e-3 to 1e-2 of full scale, and the filter, told the command "
                "the network gave, feeds it back until it is full scale; also with the filter and the "
                "network computed in double (scripts/c_float32_sources.py)")
    for pol in (policy, policy.residual_policy()):
        if pol is not None and pol.law is not None and laws.BY_NAME[pol.law["name"]].c_double_only:
            return f"{pol.law['name']} has no float32 build: {laws.BY_NAME[pol.law['name']].c_double_only}"
    return ""


def _drop_unused(src: str) -> str:
    """Without the scalar constants nothing reads (e.g. a law's own detector threshold when the
    front end's detector bit is in the observation): -Wall -Werror refuses unused ones."""
    out = []
    for line in src.split("\n"):
        m = re.match(r"static const (?:impact_real|double) ([A-Z0-9_]+) = ", line)
        if m and len(re.findall(rf"\b{m.group(1)}\b", src)) == 1:
            continue
        out.append(line)
    return "\n".join(out)


@dataclass(frozen=True)
class CArtifact:
    """The generated pair and what it was made from."""

    header: str
    source: str
    scene_sha256: str
    policy_sha256: str
    obs_size: int
    hold_ticks: int
    rms_window: int


def generate_c(policy: CompiledPolicy, scene, safety: rig_safety.SafetyConfig | None = None,
               spec: str = "") -> CArtifact:
    """The C header and source of ``policy`` on ``scene`` with the target's ``safety`` limits.
    ConfigError for what C cannot express here: a privileged observation (a rig measures no
    body-1 state), a law that reads one."""
    policy.check_scene(scene)
    if policy.layout.privileged:
        raise ConfigError(f"policy {policy.name!r} reads a privileged observation ({policy.observation}): "
                          "a rig measures no body-1 state, so it cannot be deployed; export one made "
                          "with observation='sensors'")
    residual = policy.residual_policy()
    if policy.law is not None and policy.law["name"] == "thesis-ideal":
        raise ConfigError("thesis-ideal reads the true state (x1, v1, x2, v2), which a rig does not "
                          "measure: deploy thesis-rig (eq 4.3, from the sensors) instead")
    scene_toml = scene.to_toml().encode()
    scene_sha = hashlib.sha256(scene_toml).hexdigest()
    pol_sha = policy.sha256()
    fe = FrontEnd(scene, policy.layout, 1)
    rfe = FrontEnd(scene, residual.layout, 1) if residual is not None else None
    cfg = safety or rig_safety.SafetyConfig()
    # the drive command's newtons are the rig's (the amplifier's calibration, the scene's
    # effects.command_scale), as the numba target's Controller has them; a policy made at another
    # scale keeps its own inside its law (f / its scale), as impact_env.control.policy.act does
    sp = rig_safety.safety_params(cfg, float(scene.effects.command_scale), policy.control_rate, policy.hold_ticks,
                          "onboard")
    plaus = plausibility.plausibility_params(scene)
    g = _Gen(policy, residual, scene, fe, rfe, sp, cfg, scene_sha, pol_sha, spec, plaus)
    return CArtifact(g.header(), g.source(), scene_sha, pol_sha, policy.layout.size, policy.hold_ticks,
                     int(sp[rig_safety.P_WINDOW]))


def write_c(policy: CompiledPolicy, scene, out_dir, force: bool = False,
            safety: rig_safety.SafetyConfig | None = None, spec: str = "") -> tuple[Path, Path]:
    """Write ``impact_policy.h`` and ``impact_policy.c`` into ``out_dir`` (created; an existing
    folder only with ``force``)."""
    out = Path(out_dir)
    if out.exists() and not force:
        raise ConfigError(f"--c {out}: the folder exists; pass --force to overwrite its "
                          f"{HEADER_NAME} and {SOURCE_NAME}")
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--c {out}: exists and is not a folder")
    art = generate_c(policy, scene, safety, spec)
    out.mkdir(parents=True, exist_ok=True)
    h, c = out / HEADER_NAME, out / SOURCE_NAME
    h.write_text(art.header)
    c.write_text(art.source)
    return h, c


class _Gen:
    """Builds the two texts (one method per section, in the order of the tick)."""

    def __init__(self, pol, res, scene, fe, rfe, sp, cfg, scene_sha, pol_sha, spec, plaus):
        self.pol, self.res, self.scene, self.fe, self.rfe = pol, res, scene, fe, rfe
        self.plaus = plaus
        self.sp, self.cfg, self.scene_sha, self.pol_sha, self.spec = sp, cfg, scene_sha, pol_sha, spec
        lay = pol.layout
        self.F, self.H, self.size = lay.frame_size, lay.history, lay.size
        self.nsec = fe.sos.shape[1]
        self.window = int(sp[rig_safety.P_WINDOW])
        self.scale = float(sp[rig_safety.P_SCALE])  # the scene's: see generate_c
        self.widest = 1
        if pol.mlp is not None:
            _, _, self.widest = MLP.pack_mlp(pol.mlp["layers"])

    # -- the header ------------------------------------------------------------------------------
    def _no_float32(self) -> str:
        why = float32_refusal(self.pol)
        if not why:
            return ""
        return f"""#ifdef IMPACT_FLOAT32
#error "{why.replace('"', "'")} (docs/rig/c-export.md): build it in double"
#endif

"""
    def _banner(self) -> str:
        pol, lay = self.pol, self.pol.layout
        what = (f"classic law {pol.law['name']}" if pol.law is not None else
                f"MLP {' x '.join(str(len(ly['bias'])) for ly in pol.mlp['layers'])}, output "
                f"{pol.mlp['output']} to [{pol.mlp['low']:g}, {pol.mlp['high']:g}]")
        rows = []
        for h in range(self.H):
            for j, (n, u, s) in enumerate(zip(lay.names, lay.units, lay.scales, strict=True)):
                age = "" if h == 0 else f" ({h} policy steps ago)"
                rows.append(f" *   [{h * self.F + j:3d}] {n}{age}: value [{u or '1'}] / {_r(s)}, clipped to "
                            f"+-{OBS_LIMIT:g}")
        if self.H > 1:
            for h in range(self.H):
                rows.append(f" *   [{self.H * self.F + h:3d}] the policy's action {h + 1} steps ago "
                            "(dimensionless)")
        res = (f"residual law {self.res.law['name']} added every tick, the sum clipped to [-1, 1]"
               if self.res is not None else "no residual law")
        why = float32_refusal(pol)
        f32 = (f"no float32 build ({why})" if why else
               "define IMPACT_FLOAT32 for float (MCUs without a double FPU; within the bound of\n"
               " * docs/rig/c-export.md)")
        body1 = ("checked like the others" if self.plaus.ch[3, plausibility.CC.on] else
                 "(disabled in the scene, as on the rig: pass NaN; not read)")
        return f"""/*
 * Generated by impact-env export{(' ' + self.spec) if self.spec else ''} --c: do not edit; regenerate.
 *
 * Policy  {pol.name}: {what}
 *         sha256 {self.pol_sha} (of its compiled policy file)
 * Scene   {self.scene.name}: sha256 {self.scene_sha} (of its TOML)
 * Timing  {pol.control_rate:g} Hz ticks; the policy acts every {pol.hold_ticks} tick(s); {res}
 *
 * Inputs, per tick (the DAQ's readings, SI, the thesis's frame: x down, force up):
 *   readings[0] accelerometer on body 2   m/s^2  down positive
 *   readings[1] force transducer          N      compression positive
 *   readings[2] potentiometer (x2)        m      down positive, 0 at rest
 *   readings[3] body-1 sensor             m      {body1}
 * Every reading is checked first (impact_env.control.plausibility): outside the converter's range,
 * NaN/inf, or a jump no physics gives sets IMPACT_STATUS_SENSOR_FAULT and the channel's bit, drives
 * 0 N and holds the channel's last plausible reading for the filters; faulty ticks in a row beyond
 * {int(self.plaus.limit_ticks)} latch IMPACT_STATUS_SENSOR_TIMEOUT (0 N until impact_reset: end the episode).
 * Outputs, per tick:
 *   *command   the drive command, dimensionless: 1 = {_r(self.scale)} N upwards (the
 *              amplifier's input; the driver turns it into volts)
 *   *force_n   the same in newtons after the safety layer (= command * {_r(self.scale)})
 *   return     status bits (IMPACT_STATUS_*), as the rig target logs them
 * Timing contract: call impact_step once per tick with the readings sampled at the tick's start
 * and apply *command at once; it acts until the next call (the DAC holds it).  Tick 0 of an
 * episode is the first call after impact_reset() (the release).
 *
 * Observation ({self.size} entries, {pol.observation}, history {self.H}):
{chr(10).join(rows)}
 *
 * Arithmetic: double by default (the reference: bitwise the simulator's numba kernels on the
 * same libm); {f32}.  The RMS clamp's ledger stays in double in both builds (its sums are exact).
 */"""

    def header(self) -> str:
        res_state = ""
        if self.res is not None:
            rl = self.res.layout
            res_state = f"""
    /* the residual law's frame and memory (history 1) */
    impact_real res_frame[{rl.frame_size}];
    float res_obs[{rl.size}];
    impact_real res_mem[{_memory(self.res)}];"""
        law_mem = ""
        if self.pol.law is not None:
            law_mem = f"\n    impact_real law_mem[{_memory(self.pol)}];  /* the law's memory, 0 at release */"
        elif self.pol.estimator is not None:
            law_mem = f"\n    impact_real law_mem[{_memory(self.pol)}];  /* the filter's memory, 0 at release */"
        return f"""{self._banner()}
#ifndef IMPACT_POLICY_H
#define IMPACT_POLICY_H

#include <stdint.h>

{self._no_float32()}#ifdef IMPACT_FLOAT32
typedef float impact_real;
#else
typedef double impact_real;
#endif

#define IMPACT_N_READINGS 4
#define IMPACT_OBS_SIZE {self.size}
#define IMPACT_FRAME_SIZE {self.F}
#define IMPACT_HISTORY {self.H}
#define IMPACT_HOLD_TICKS {self.pol.hold_ticks}
#define IMPACT_CONTROL_RATE_HZ {_r(self.pol.control_rate)}
#define IMPACT_COMMAND_SCALE_N {_r(self.scale)}
#define IMPACT_RMS_WINDOW_TICKS {self.window}

/* status bits (impact_env.rig.safety): bits 0-15 the safety layer */
#define IMPACT_STATUS_NONFINITE   0x{rig_safety.NONFINITE:04x}u  /* the command was NaN or infinite: 0 N */
#define IMPACT_STATUS_CLAMP_PEAK  0x{rig_safety.CLAMP_PEAK:04x}u  /* |f| cut to the peak rating */
#define IMPACT_STATUS_CLAMP_RMS   0x{rig_safety.CLAMP_RMS:04x}u  /* cut by the continuous (RMS) rating */
#define IMPACT_STATUS_TRAVEL      0x{rig_safety.TRAVEL:04x}u  /* latched: |x2| beyond the travel limit, 0 N */
#define IMPACT_STATUS_SENSOR_FAULT 0x{rig_safety.SENSOR_FAULT:04x}u  /* a reading implausible this tick: 0 N, held */
#define IMPACT_STATUS_SENSOR_ACCELEROMETER 0x{rig_safety.SENSOR_ACCELEROMETER:04x}u  /* ... readings[0] */
#define IMPACT_STATUS_SENSOR_FORCE 0x{rig_safety.SENSOR_FORCE:04x}u  /* ... readings[1] */
#define IMPACT_STATUS_SENSOR_POTENTIOMETER 0x{rig_safety.SENSOR_POTENTIOMETER:04x}u  /* ... readings[2] */
#define IMPACT_STATUS_SENSOR_BODY1 0x{rig_safety.SENSOR_BODY1:04x}u  /* ... readings[3] */
#define IMPACT_STATUS_SENSOR_TIMEOUT 0x{rig_safety.SENSOR_TIMEOUT:04x}u  /* latched: faults too long: 0 N, end it */

#define IMPACT_PL_DEMAND_TICKS {plausibility.DEMAND_TICKS}  /* force demands the armature check remembers */

typedef struct {{
    int64_t tick;                               /* ticks since the episode's release */
    /* the plausibility check: each channel's last plausible reading and its tick, the faulty
     * ticks in a row, the SENSOR_TIMEOUT latch, whether a reading was seen this episode */
    double pl_good[IMPACT_N_READINGS], pl_last[IMPACT_N_READINGS];
    double pl_run, pl_latch, pl_primed;
    /* ... each channel's previous raw reading and its exact repeats in a row (the stuck check),
     * the force demands of the last ticks (N, slot tick % IMPACT_PL_DEMAND_TICKS: the armature check) */
    double pl_prev[IMPACT_N_READINGS], pl_repeat[IMPACT_N_READINGS];
    double pl_demand[IMPACT_PL_DEMAND_TICKS];
    double pl_mean_square;  /* N^2: an upper bound of the amplifier's mean-square tracker */
    /* front end: filter memory per section (double: transposed direct form II; float32: the
     * trapezoidal SVF's two integrators), detector, conditioned readings */
    impact_real filt[IMPACT_N_READINGS][{self.nsec}][2];
    impact_real det_prev_s, det_latch;           /* eq 4.4 signal (N) at the last tick, contact bit */
    impact_real cond[IMPACT_N_READINGS];
    impact_real detected;
    /* the observation: frames newest first (scaled), past actions, the row the policy reads */
    impact_real frames[IMPACT_HISTORY][IMPACT_FRAME_SIZE];
    impact_real past_actions[IMPACT_HISTORY];
    float obs[IMPACT_OBS_SIZE];{res_state}{law_mem}
    impact_real action;                          /* the policy's action, held for a policy step */
    /* safety: latched bits, the RMS window of squared forces (whole quanta), per-episode counts */
    uint32_t latch;
    int64_t rms_head;
    double rms_sum;
    double rms_ring[IMPACT_RMS_WINDOW_TICKS];
    int64_t nonfinite_ticks, clamp_peak_ticks, clamp_rms_ticks, travel_trips, sensor_fault_ticks;
}} impact_state;

/* Power-on: every state zero (the RMS window cool). */
void impact_init(impact_state *s);
/* A new episode (the release): front end, policy and latches cleared; the RMS window, the coil's
 * heat, is kept. */
void impact_reset(impact_state *s);
/* Time spent disarmed, in ticks: the RMS window cools by that many 0 N ticks. */
void impact_idle(impact_state *s, int64_t ticks);
/* sizeof(impact_state), for callers that allocate it from another language */
unsigned long impact_state_bytes(void);
/* The front end's contact detector bit after the last impact_step (1: contact), for a log: with the
 * status bits, the tick's discrete decisions (the laws gate their force on it) */
int impact_contact(const impact_state *s);
/* One tick (see the banner): returns the status bits. */
uint32_t impact_step(impact_state *s, const impact_real readings[IMPACT_N_READINGS],
                     impact_real *command, impact_real *force_n);

#endif /* IMPACT_POLICY_H */
"""

    # -- the source -------------------------------------------------------------------------------
    def source(self) -> str:
        parts = [self._banner(), self._prelude(), self._plausibility(), self._front_end(),
                 self._observe("main", self.pol.layout), *self._law_preludes(),
                 self._policy()]
        if self.res is not None:
            parts += [self._observe("res", self.res.layout), self._law("res", self.res)]
        parts += [self._safety(), self._step()]
        return _drop_unused("\n\n".join(parts) + "\n")

    def _prelude(self) -> str:
        return f"""#include <math.h>
#include <string.h>

#include "{HEADER_NAME}"

#ifdef IMPACT_FLOAT32
#define R_SQRT sqrtf
#define R_POW powf
#define R_TANH tanhf
#define R_EXPM1 expm1f
#else
#define R_SQRT sqrt
#define R_POW pow
#define R_TANH tanh
#define R_EXPM1 expm1
#endif

/* a literal in the build's arithmetic (float literals would be promoted to double otherwise) */
#define RL(x) ((impact_real)(x))

/* every entry of an observation is clipped to this many reference units */
static const impact_real OBS_LIMIT = {_r(OBS_LIMIT)};
/* the force that drive command 1 demands, N upwards (the scene's effects.command_scale) */
static const impact_real COMMAND_SCALE_N = {_r(self.scale)};"""

    def _plausibility(self) -> str:
        ch = self.plaus.ch
        ph = self.plaus.phys
        P = plausibility.PH
        return f"""/* ---- sensor plausibility (impact_env.control.plausibility; docs/rig/faults.md): every
 * reading checked before the filters; compared in double in both builds ---- */

/* per channel: checked (1) or disabled (0: read as 0.0), the converter's range (lo, hi), the
 * largest change per tick (max_step |gain|, 0: no jump check), the noise allowance, the exact
 * repeats that flag it stuck (0: no stuck check), 1 / gain and the declared offset, from the
 * scene's effects.sensors */
static const double PL_ON[IMPACT_N_READINGS] = {_arr(ch[:, plausibility.CC.on])};
static const double PL_LO[IMPACT_N_READINGS] = {_arr(ch[:, plausibility.CC.lo])};
static const double PL_HI[IMPACT_N_READINGS] = {_arr(ch[:, plausibility.CC.hi])};
static const double PL_STEP[IMPACT_N_READINGS] = {_arr(ch[:, plausibility.CC.max_jump])};
static const double PL_TOL[IMPACT_N_READINGS] = {_arr(ch[:, plausibility.CC.tol])};
static const double PL_REPEAT[IMPACT_N_READINGS] = {_arr(ch[:, plausibility.CC.repeat])};
static const double PL_SCALE[IMPACT_N_READINGS] = {_arr(ch[:, plausibility.CC.scale])};
static const double PL_OFFSET[IMPACT_N_READINGS] = {_arr(ch[:, plausibility.CC.offset])};
/* faulty ticks in a row allowed (effects.sensors.fault_limit_s at the control rate) */
static const double PL_LIMIT_TICKS = {_r(self.plaus.limit_ticks)};
/* the cross-channel checks: on, m2' (kg), m2 - m2' (kg), k2 (N/m), the sign check's allowance
 * (N), the armature check's noise allowance (N), its change per tick the drive does not
 * explain (N), the shaker's gain on a change of the demand, the older demands' tail (N), the
 * largest force per N of demand, the amplifier's peak (N), RMS budget squared (N^2, < 0: none)
 * and mean-square tracker factor per tick */
static const double PH_ON = {_r(ph[P.on])};
static const double PH_TOP_MASS = {_r(ph[P.top_mass])};
static const double PH_LOWER_MASS = {_r(ph[P.lower_mass])};
static const double PH_K2 = {_r(ph[P.k2])};
static const double PH_TOL_SIGN = {_r(ph[P.tol_sign])};
static const double PH_TOL_ARM = {_r(ph[P.tol_arm])};
static const double PH_PER_TICK = {_r(ph[P.per_tick])};
static const double PH_DRIVE_GAIN = {_r(ph[P.drive_gain])};
static const double PH_TAIL = {_r(ph[P.tail])};
static const double PH_FORCE_GAIN = {_r(ph[P.force_gain])};
static const double PH_PEAK = {_r(ph[P.peak])};
static const double PH_RMS2 = {_r(ph[P.rms2])};
static const double PH_ALPHA = {_r(ph[P.alpha])};

static double pl_true(int c, double x) {{ return (x - PL_OFFSET[c]) * PL_SCALE[c]; }}

/* an upper bound of the shaker's force now (N): the largest remembered demand through it */
static double pl_largest_force(const impact_state *s)
{{
    double top = 0.0;
    for (int j = 0; j < IMPACT_PL_DEMAND_TICKS; j++) {{
        double d = fabs(s->pl_demand[j]);
        if (d > top) top = d;
    }}
    top = PH_FORCE_GAIN * top;
    return top < PH_PEAK ? top : PH_PEAK;
}}

/* the most the amplifier's RMS budget can cut the force this tick (N) */
static double pl_budget_cut(const impact_state *s)
{{
    if (PH_RMS2 < 0.0) return 0.0;
    double ms = s->pl_mean_square;
    double room = ms + (PH_RMS2 - ms) / PH_ALPHA;
    if (room < 0.0) room = 0.0;
    double cut = pl_largest_force(s) - sqrt(room);
    return cut > 0.0 ? cut : 0.0;
}}

/* tick's force demand (N) remembered for the armature check; the budget's bound updated */
static void pl_note(impact_state *s, double force)
{{
    s->pl_demand[s->tick % IMPACT_PL_DEMAND_TICKS] = force;
    if (PH_RMS2 >= 0.0) {{
        double top = pl_largest_force(s);
        s->pl_mean_square += PH_ALPHA * (top * top - s->pl_mean_square);
    }}
}}

/* the top part's Newton (m2' a2 + T, the contact force, is not negative) and the armature's
 * (its residual moved by no more than allowed since the held readings) */
static int pl_consistent(double a, double t, double x, double ag, double tg, double xg, double allowed)
{{
    if (PH_TOP_MASS * a + t < -PH_TOL_SIGN) return 0;
    double r = PH_LOWER_MASS * a - t + PH_K2 * x;
    double r_good = PH_LOWER_MASS * ag - tg + PH_K2 * xg;
    return fabs(r - r_good) <= allowed;
}}

/* the channel bits the cross-channel checks blame (0: consistent) */
static uint32_t pl_physics(const impact_state *s, const impact_real readings[IMPACT_N_READINGS])
{{
    double a = pl_true(0, (double)readings[0]), t = pl_true(1, (double)readings[1]);
    double ag = pl_true(0, s->pl_good[0]), tg = pl_true(1, s->pl_good[1]);
    double oldest = fmin(s->pl_last[0], s->pl_last[1]);
    double x = 0.0, xg = 0.0;
    int pot = PL_ON[2] != 0.0;
    if (pot) {{
        x = pl_true(2, (double)readings[2]);
        xg = pl_true(2, s->pl_good[2]);
        oldest = fmin(oldest, s->pl_last[2]);
    }}
    double change = 0.0;
    int head = (int)(s->tick % IMPACT_PL_DEMAND_TICKS);
    for (int j = 0; j < IMPACT_PL_DEMAND_TICKS; j++) {{
        if (j == head) continue;  /* the oldest demand: no predecessor remembered */
        int jp = j > 0 ? j - 1 : IMPACT_PL_DEMAND_TICKS - 1;
        double d = fabs(s->pl_demand[j] - s->pl_demand[jp]);
        if (d > change) change = d;
    }}
    double cut = pl_budget_cut(s);
    double ticks = (double)s->tick - oldest;
    double allowed = ticks * (PH_DRIVE_GAIN * change + PH_PER_TICK + cut) + PH_TAIL + PH_TOL_ARM;
    if (pl_consistent(a, t, x, ag, tg, xg, allowed)) return 0;
    int held_a = pl_consistent(ag, t, x, ag, tg, xg, allowed);
    int held_t = pl_consistent(a, tg, x, ag, tg, xg, allowed);
    int held_x = pot && pl_consistent(a, t, xg, ag, tg, xg, allowed);
    if (held_a && !held_t && !held_x) return IMPACT_STATUS_SENSOR_ACCELEROMETER;
    if (held_t && !held_a && !held_x) return IMPACT_STATUS_SENSOR_FORCE;
    if (held_x && !held_a && !held_t) return IMPACT_STATUS_SENSOR_POTENTIOMETER;
    return IMPACT_STATUS_SENSOR_ACCELEROMETER | IMPACT_STATUS_SENSOR_FORCE;
}}

/* the readings the front end may use (a bad one: the channel's last plausible one); the status bits */
static uint32_t plausible(impact_state *s, const impact_real readings[IMPACT_N_READINGS],
                          impact_real checked[IMPACT_N_READINGS])
{{
    uint32_t bits = 0;
    int primed = s->pl_primed != 0.0;
    for (int c = 0; c < IMPACT_N_READINGS; c++) {{
        if (PL_ON[c] == 0.0) continue;
        double x = (double)readings[c];
        int ok = PL_LO[c] <= x && x <= PL_HI[c];  /* false for NaN */
        if (ok && primed && PL_STEP[c] > 0.0) {{
            double allowed = PL_STEP[c] * ((double)s->tick - s->pl_last[c]) + PL_TOL[c];
            ok = fabs(x - s->pl_good[c]) <= allowed;
        }}
        if (primed && x == s->pl_prev[c]) s->pl_repeat[c] += 1.0;
        else s->pl_repeat[c] = 0.0;
        s->pl_prev[c] = x;
        /* stuck: only strictly inside the range (at the converter's limit it clips: repeats are real) */
        if (ok && PL_REPEAT[c] > 0.0 && s->pl_repeat[c] >= PL_REPEAT[c]
            && PL_LO[c] < x && x < PL_HI[c]) ok = 0;
        if (!ok) bits |= (uint32_t)1u << (9 + c);
    }}
    if (bits == 0 && primed && PH_ON != 0.0) bits = pl_physics(s, readings);
    for (int c = 0; c < IMPACT_N_READINGS; c++) {{
        if (PL_ON[c] == 0.0) {{
            checked[c] = 0.0;
        }} else if (bits & ((uint32_t)1u << (9 + c))) {{
            checked[c] = (impact_real)s->pl_good[c];
        }} else {{
            s->pl_good[c] = (double)readings[c];
            s->pl_last[c] = (double)s->tick;
            checked[c] = readings[c];
        }}
    }}
    s->pl_primed = 1.0;
    if (bits != 0) {{
        bits |= IMPACT_STATUS_SENSOR_FAULT;
        s->pl_run += 1.0;
        if (s->pl_run > PL_LIMIT_TICKS) s->pl_latch = 1.0;
    }} else {{
        s->pl_run = 0.0;
    }}
    if (s->pl_latch != 0.0) bits |= IMPACT_STATUS_SENSOR_TIMEOUT;
    return bits;
}}"""

    def _front_end(self) -> str:
        fe = self.fe
        dp = fe.det_params
        filters = bool(fe.flags & F_FILTERS)
        detector = bool(fe.flags & F_DETECTOR)
        sos = fe.sos
        sos_txt = _section_table(sos) if filters else ""
        tpt_txt = _section_table(tpt_sections(sos)) if filters else ""
        filt_code = """
    for (int c = 0; c < IMPACT_N_READINGS; c++) {
        impact_real v = s->cond[c];
        for (int k = 0; k < N_SECTIONS; k++) {
#ifdef IMPACT_FLOAT32
            const impact_real *t = TPT[c][k];  /* c1 c2 c3 m0 m1 m2; filt: the two integrators */
            impact_real v3 = v - s->filt[c][k][1];
            impact_real v1 = t[0] * s->filt[c][k][0] + t[1] * v3;
            impact_real v2 = s->filt[c][k][1] + t[1] * s->filt[c][k][0] + t[2] * v3;
            s->filt[c][k][0] = 2.0f * v1 - s->filt[c][k][0];
            s->filt[c][k][1] = 2.0f * v2 - s->filt[c][k][1];
            v = t[3] * v + t[4] * v1 + t[5] * v2;
#else
            const impact_real *b = SOS[c][k];
            impact_real y = b[0] * v + s->filt[c][k][0];
            s->filt[c][k][0] = b[1] * v - b[4] * y + s->filt[c][k][1];
            s->filt[c][k][1] = b[2] * v - b[5] * y;
            v = y;
#endif
        }
        s->cond[c] = v;
    }""" if filters else "\n    /* the scene has no filters effect: the readings pass as they are */"
        if not detector:
            det_code = "\n    s->detected = 0.0;  /* the scene has no detector effect */"
        elif dp[contact_detector.DP.use_derivative] == 0.0:
            det_code = """
    /* thesis eq 4.4: the contact force is m2' a2 + T; contact while it exceeds the threshold */
    impact_real sig = DET_TOP_MASS_KG * s->cond[0] + s->cond[1];
    s->det_latch = (sig > DET_THRESHOLD_N) ? 1.0 : 0.0;
    s->det_prev_s = sig;
    s->detected = (s->det_latch != 0.0) ? 1.0 : 0.0;"""
        else:
            det_code = """
    /* thesis eq 4.4 with a derivative trigger: d/dt (m2' a2 + T) beyond +-threshold sets/clears */
    impact_real sig = DET_TOP_MASS_KG * s->cond[0] + s->cond[1];
    impact_real ds = (sig - s->det_prev_s) * DET_RATE_HZ;
    if (ds > DET_DTHRESHOLD_N_PER_S) s->det_latch = 1.0;
    else if (ds < -DET_DTHRESHOLD_N_PER_S) s->det_latch = 0.0;
    s->det_prev_s = sig;
    s->detected = (s->det_latch != 0.0) ? 1.0 : 0.0;"""
        tables = f"""#define N_SECTIONS {sos.shape[1]}
#ifndef IMPACT_FLOAT32
/* Butterworth second-order sections per channel (b0 b1 b2 a0 a1 a2; scipy's sos layout; identity
 * sections pad short cascades), from the scene's effects.filters at {self.pol.control_rate:g} Hz,
 * run in transposed direct form II as the simulator's filters (bitwise the same) */
static const impact_real SOS[IMPACT_N_READINGS][N_SECTIONS][6] = {{
{sos_txt}
}};
#else
/* float32: the same sections as trapezoidal state-variable filters (c1 c2 c3 m0 m1 m2;
 * impact_env.effects.filters.tpt_sections): the same transfer functions, but a high-pass section
 * near z = 1 in direct form amplifies float32 rounding about 100x more (docs/rig/c-export.md) */
static const impact_real TPT[IMPACT_N_READINGS][N_SECTIONS][6] = {{
{tpt_txt}
}};
#endif
""" if filters else "/* the scene has no filters effect: no filter tables */\n"
        return f"""/* ---- front end: the scene's filters and the contact detector (impact_env.control.front_end) ---- */

{tables}/* the contact detector (effects.detector): m2' (kg), threshold (N), derivative threshold (N/s), rate */
static const impact_real DET_TOP_MASS_KG = {_r(dp[contact_detector.DP.top_mass])};
static const impact_real DET_THRESHOLD_N = {_r(dp[contact_detector.DP.threshold])};
static const impact_real DET_DTHRESHOLD_N_PER_S = {_r(dp[contact_detector.DP.derivative_threshold])};
static const impact_real DET_RATE_HZ = {_r(dp[contact_detector.DP.rate])};

/* the readings of a tick through the filters, then the detector */
static void condition(impact_state *s, const impact_real readings[IMPACT_N_READINGS])
{{
    for (int c = 0; c < IMPACT_N_READINGS; c++) s->cond[c] = readings[c];{filt_code}{det_code}
}}"""

    def _observe(self, which: str, lay) -> str:
        main = which == "main"
        chans = ", ".join(str(int(c)) for c in lay.sensor_channels) or "0"
        n_ch = len(lay.sensor_channels)
        frames = "s->frames" if main else "s->res_frame"
        pref = "OBS" if main else "RES_OBS"
        shift = ""
        if main and lay.history > 1:
            shift = """
    if (push) {
        for (int h = IMPACT_HISTORY - 1; h > 0; h--) s->past_actions[h] = s->past_actions[h - 1];
        s->past_actions[0] = action;
    }
    for (int h = IMPACT_HISTORY - 1; h > 0; h--)
        for (int j = 0; j < IMPACT_FRAME_SIZE; j++) s->frames[h][j] = s->frames[h - 1][j];"""
        f0 = f"{frames}[0]" if main else frames
        det = f"\n    {f0}[j++] = s->detected;" if lay.detector else ""
        out = ("""
    for (int h = 0; h < IMPACT_HISTORY; h++)
        for (int k = 0; k < IMPACT_FRAME_SIZE; k++) s->obs[h * IMPACT_FRAME_SIZE + k] = (float)s->frames[h][k];"""
               + ("""
    for (int h = 0; h < IMPACT_HISTORY; h++) s->obs[IMPACT_HISTORY * IMPACT_FRAME_SIZE + h] = (float)s->past_actions[h];"""
                  if lay.history > 1 else "")) if main else f"""
    for (int k = 0; k < {lay.frame_size}; k++) s->res_obs[k] = (float)s->res_frame[k];"""
        sig = "static void observe(impact_state *s, int push, impact_real action)" if main else \
            "static void observe_residual(impact_state *s)"
        unused = "" if (main and lay.history > 1) or not main else ""
        if main and lay.history == 1:
            unused = "\n    (void)push;\n    (void)action;"
        names = ", ".join(lay.names)
        return f"""/* ---- the {'policy' if main else 'residual law'}'s observation ({names}; impact_env.control.front_end.observe) ---- */

static const int {pref}_CHANNELS[{max(n_ch, 1)}] = {{{chans}}};
/* reference scales: obs = value / scale (impact_env.control.observation) */
static const impact_real {pref}_SCALES[{lay.frame_size}] = {_arr(lay.scales)};

{sig}
{{{unused}{shift}
    int j = 0;
    for (int k = 0; k < {n_ch}; k++) {f0}[j++] = s->cond[{pref}_CHANNELS[k]];{det}
    for (j = 0; j < {lay.frame_size}; j++) {{
        impact_real v = {f0}[j] / {pref}_SCALES[j];
        if (v > OBS_LIMIT) v = OBS_LIMIT;
        else if (v < -OBS_LIMIT) v = -OBS_LIMIT;
        {f0}[j] = v;
    }}{out}
}}"""

    def _law_preludes(self) -> list[str]:
        """The file-scope C text (static functions) of the classic laws in the file, each once."""
        out: list[str] = []
        if self.pol.estimator is not None:
            out.append("/* ---- the filter before the network (impact_env.control.estimation.c_text) ---- */\n\n"
                       + ekf_c())
        for pol in (self.pol, self.res):
            if pol is None or pol.law is None:
                continue
            law = laws.BY_NAME[pol.law["name"]]
            if law.c_prelude is not None:
                text = f"/* ---- {law.name}'s functions ({law.c_prelude.__module__}) ---- */\n\n{law.c_prelude()}"
                if text not in out:
                    out.append(text)
        return out

    def _policy(self) -> str:
        if self.pol.law is not None:
            return self._law("main", self.pol)
        return self._mlp()

    def _law(self, which: str, pol) -> str:
        """A classic law's C function, ``policy_act`` or ``residual_act`` (obs row, memory)."""
        kind, slots, k = laws.pack_law(pol.law["name"], pol.law["constants"], pol.layout.names)
        name = pol.law["name"]
        lay = pol.layout
        consts = laws.CONSTANTS[name]
        P = _ident(which)
        cdefs = "\n".join(f"static const impact_real {P}_{_ident(c)} = {_r(v)};"
                          for c, v in zip(consts, k, strict=True))
        sl = {s: int(slots[i]) for i, s in enumerate(laws.READS[name])}
        law = laws.BY_NAME[name]
        if law.c_body is None:
            raise ConfigError(f"law {name!r} cannot be deployed from the sensors")
        body = law.c_body(P, sl)
        if re.search(rf"\b{P}_CONSTANTS\b", body):  # the body reads them as one vector
            cdefs += (f"\n/* the same, as the vector the law's kernel reads ({name}'s Constants order) */\n"
                      f"static const impact_real {P}_CONSTANTS[{max(len(k), 1)}] = {{\n"
                      + "\n".join(f"    {_r(v)},  /* [{i}] {c} */" for i, (c, v) in enumerate(zip(consts, k, strict=True)))
                      + "\n};")
        fn = "policy_act" if which == "main" else "residual_act"
        return f"""/* ---- {'the policy' if which == 'main' else 'the residual law'}: {name} (impact_env.control.laws, kind {kind}) ---- */

{cdefs or '/* (no constants) */'}
static const impact_real {P}_COMMAND_SCALE_N = {_r(pol.command_scale)};
static const impact_real {P}_SCALES[{lay.frame_size}] = {_arr(lay.scales)};

/* the command in [-1, 1] for the observation row obs; mem: the law's memory */
static impact_real {fn}(const float *obs, impact_real *mem)
{{
    impact_real v[{lay.frame_size}];
    impact_real f;
    for (int j = 0; j < {lay.frame_size}; j++) v[j] = (impact_real)obs[j] * {P}_SCALES[j];{body}
    impact_real u = f / {P}_COMMAND_SCALE_N;
    if (u < -1.0) return -1.0;
    if (u > 1.0) return 1.0;
    return u;
}}"""

    def _mlp(self) -> str:
        m = self.pol.mlp
        layers = m["layers"]
        decl, calls = [], []
        for j, ly in enumerate(layers):
            W = np.asarray(ly["weight"], dtype=np.float64)
            b = np.asarray(ly["bias"], dtype=np.float64)
            act = ly.get("activation", "identity")
            a0, a1 = ([*map(float, ly.get("params", [0.0, 0.0])), 0.0, 0.0])[:2]
            n_out, n_in = W.shape
            rows = ",\n".join("    {" + ", ".join(_r(x) for x in W[o]) + "}" for o in range(n_out))
            decl.append(f"/* layer {j}: {n_in} -> {n_out}, {act} */\n"
                        f"static const impact_real W{j}[{n_out}][{n_in}] = {{\n{rows}\n}};\n"
                        f"static const impact_real B{j}[{n_out}] = {_arr(b)};")
            actc = {"identity": "c", "tanh": "R_TANH(c)", "relu": "(c > 0.0 ? c : 0.0)",
                    "hardtanh": f"(c < {_r(a0)} ? {_r(a0)} : (c > {_r(a1)} ? {_r(a1)} : c))",
                    "leaky_relu": f"(c > 0.0 ? c : RL({_r(a0)}) * c)",
                    "elu": f"(c > 0.0 ? c : RL({_r(a0)}) * R_EXPM1(c))"}[act]
            calls.append(f"""    for (int o = 0; o < {n_out}; o++) {{
        impact_real c = B{j}[o];
        for (int i = 0; i < {n_in}; i++) c += W{j}[o][i] * x[i];
        y[o] = {actc};
    }}
    for (int o = 0; o < {n_out}; o++) x[o] = y[o];""")
        low, high = _r(m["low"]), _r(m["high"])
        if m["output"] == "squash":
            out = f"return RL({low}) + (RL(0.5) * (R_TANH(a) + RL(1.0)) * (RL({high}) - RL({low})));"
            what = "tanh, then unscaled to [low, high] (SB3's squash)"
        else:
            out = f"return a < RL({low}) ? RL({low}) : (a > RL({high}) ? RL({high}) : a);"
            what = "clipped to [low, high] (SB3's predict for a Box action)"
        if self.pol.estimator is None:
            inputs, before, after, mem_use, mem_type = "", "", "", "\n    (void)mem;", "impact_real"
        else:
            lay = self.pol.layout
            k = behind_filter.estimator_vector(self.pol.estimator)
            sl = {r: (lay.names.index(r) if r in lay.names else -1) for r in SensorReads._fields}
            fallback_k = k[behind_filter.FALLBACK:]
            fallback_defs = "\n".join(f"static const impact_real EST_FALLBACK_{_ident(n)} = {_r(v)};"
                                       for n, v in zip(behind_filter.FALLBACK_NAMES, fallback_k, strict=True))
            inputs = (f"""

/* the filter before the network (impact_env.control.behind_filter): its constants (the EKF's, then
 * the reference length m, the reference speed m/s and the nominal m1 kg, then nis_gate), and the
 * constants of pd-penetration, which drives once the filter shows its model wrong */
static const impact_real EST_K[{behind_filter.FALLBACK}] = {{
""" + "\n".join(f"    {_r(v)},  /* [{i}] */" for i, v in enumerate(k[:behind_filter.FALLBACK])) + f"""
}};
{fallback_defs}
static const impact_real EST_SCALES[IMPACT_FRAME_SIZE] = {_arr(lay.scales)};
/* the memory: the fallback's, its flag and count of ticks, then the filter's */
#define EST_FALLBACK_ON {FALLBACK_MEMORY}
#define EST_FALLBACK_TICKS {FALLBACK_MEMORY + 1}
#define EST_FILTER {FALLBACK_MEMORY + 2}""")
            before = f"""
    /* the frame in SI; the filter's measurement half on it */
    impact_real v[IMPACT_FRAME_SIZE], frame[3];
    impact_real *filter_mem = mem + EST_FILTER;
    for (int j = 0; j < IMPACT_FRAME_SIZE; j++) v[j] = (impact_real)obs[j] * EST_SCALES[j];
    frame[0] = v[{sl["accelerometer"]}];
    frame[1] = v[{sl["force"]}];
    frame[2] = v[{sl["potentiometer"]}];
    ekf_measure(EST_K, filter_mem, frame);
    x[IMPACT_OBS_SIZE + 0] = filter_mem[EKF_M_X + EKF_X1] / EST_K[{estimate.REFS}];
    x[IMPACT_OBS_SIZE + 1] = filter_mem[EKF_M_X + EKF_V1] / EST_K[{estimate.REFS + 1}];
    x[IMPACT_OBS_SIZE + 2] = filter_mem[EKF_M_X + EKF_X2] / EST_K[{estimate.REFS}];
    x[IMPACT_OBS_SIZE + 3] = filter_mem[EKF_M_X + EKF_V2] / EST_K[{estimate.REFS + 1}];
    x[IMPACT_OBS_SIZE + 4] = filter_mem[EKF_M_X + EKF_IM1] * EST_K[{estimate.REFS + 2}] - 1.0;
    /* the fallback law runs every tick, so that it takes over with its differences warm */
    impact_real f_fallback;
    {{
        impact_real f;{pd_penetration.c_body("EST_FALLBACK", sl).replace(chr(10) + "    ", chr(10) + "        ")}
        f_fallback = f;
    }}
    if (filter_mem[EKF_M_NIS_LAST] > EST_K[{behind_filter.GATE}])
        mem[EST_FALLBACK_ON] = 1.0;
    impact_real u;
    if (mem[EST_FALLBACK_ON] > 0.0) {{
        mem[EST_FALLBACK_TICKS] += 1.0;
        u = f_fallback / COMMAND_SCALE_N;
        u = u < -1.0 ? -1.0 : (u > 1.0 ? 1.0 : u);
    }} else {{"""
            after = """
    }
    /* the filter's prediction with the command's force */
    ekf_tick(EST_K, filter_mem, frame, u * COMMAND_SCALE_N);
    return u;"""
            mem_use, mem_type = "", "impact_real"
            out = out.replace("return ", "u = ", 1)
        return f"""/* ---- the policy: an MLP actor (impact_env.control.mlp), each output summed b + W[o][0] x0 + ... in
 * input order, as the numba kernel does; output {what} ---- */

{chr(10).join(decl)}{inputs}

#define MLP_WIDEST {self.widest}

static impact_real policy_act(const float *obs, {mem_type} *mem)
{{
    impact_real x[MLP_WIDEST], y[MLP_WIDEST];{mem_use}
    for (int i = 0; i < IMPACT_OBS_SIZE; i++) x[i] = (impact_real)obs[i];{before}
{chr(10).join(calls)}
    impact_real a = x[0];
    {out}{after}
}}"""

    def _safety(self) -> str:
        sp = self.sp
        budget = sp[rig_safety.P_BUDGET]
        rms = "" if budget < 0 else """
    /* RMS clamp: the squares of the last RMS_WINDOW ticks' forces, in whole quanta, stay within
     * the budget n (continuous_n / sqrt 2)^2 */
    int64_t head = s->rms_head;
    double others = s->rms_sum - s->rms_ring[head];
    double sq = floor((double)f * (double)f / RMS_QUANTUM_N2 + 0.5);
    if (others + sq > RMS_BUDGET_QUANTA) {
        double room = RMS_BUDGET_QUANTA - others;
        if (room < 0.0) room = 0.0;
        double mag = sqrt(room * RMS_QUANTUM_N2);
        f = f > 0.0 ? (impact_real)mag : (impact_real)-mag;
        sq = floor((double)f * (double)f / RMS_QUANTUM_N2 + 0.5);
        if (sq > room) sq = room;
        status |= IMPACT_STATUS_CLAMP_RMS;
        s->clamp_rms_ticks++;
    }
    s->rms_ring[head] = sq;
    s->rms_sum = others + sq;
    s->rms_head = (head + 1) % IMPACT_RMS_WINDOW_TICKS;"""
        return f"""/* ---- the safety layer (impact_env.rig.safety, onboard mode): non-finite commands, the
 * latched travel limit, the peak and RMS clamps ---- */

static const impact_real SAFETY_PEAK_N = {_r(sp[rig_safety.P_PEAK])};          /* peak rating (thesis sec 4.3) */
static const impact_real SAFETY_TRAVEL_LIMIT_M = {_r(sp[rig_safety.P_TRAVEL])};  /* |x2| beyond it: 0 N, latched */
static const double RMS_QUANTUM_N2 = {_r(sp[rig_safety.P_QUANTUM])};        /* N^2 per quantum */
static const double RMS_BUDGET_QUANTA = {_r(budget)};  /* {'no RMS clamp' if budget < 0 else 'continuous rating'} */

#define MODIFIED (IMPACT_STATUS_NONFINITE | IMPACT_STATUS_CLAMP_PEAK | IMPACT_STATUS_CLAMP_RMS \\
                  | IMPACT_STATUS_TRAVEL | IMPACT_STATUS_SENSOR_FAULT | IMPACT_STATUS_SENSOR_TIMEOUT)

/* the force to apply (N, up) for the demanded command u; x2: the potentiometer's reading as the
 * plausibility check passed it; sensor: the check's bits for this tick */
static impact_real safety(impact_state *s, impact_real u, impact_real x2, uint32_t sensor, uint32_t *bits)
{{
    uint32_t status = 0;
    impact_real f = u * COMMAND_SCALE_N;
    if (!isfinite(f)) {{
        status |= IMPACT_STATUS_NONFINITE;
        s->nonfinite_ticks++;
        f = 0.0;
    }}
    if (!isfinite(x2)) sensor |= IMPACT_STATUS_SENSOR_FAULT | IMPACT_STATUS_SENSOR_POTENTIOMETER;
    if (sensor != 0) {{  /* never a force from a bad sample */
        status |= sensor;
        s->sensor_fault_ticks++;
        f = 0.0;
    }}
    uint32_t latch = s->latch;
    if (isfinite(x2) && fabs((double)x2) > (double)SAFETY_TRAVEL_LIMIT_M) {{
        if ((latch & IMPACT_STATUS_TRAVEL) == 0) s->travel_trips++;
        latch |= IMPACT_STATUS_TRAVEL;
    }}
    s->latch = latch;
    if (latch != 0) {{
        status |= latch;
        f = 0.0;
    }}
    if (f > SAFETY_PEAK_N) {{
        f = SAFETY_PEAK_N;
        status |= IMPACT_STATUS_CLAMP_PEAK;
    }} else if (f < -SAFETY_PEAK_N) {{
        f = -SAFETY_PEAK_N;
        status |= IMPACT_STATUS_CLAMP_PEAK;
    }}
    if (status & IMPACT_STATUS_CLAMP_PEAK) s->clamp_peak_ticks++;{rms}
    *bits = status;
    return f;
}}"""

    def _step(self) -> str:
        res = self.res is not None
        start_res = """
    memset(s->res_frame, 0, sizeof s->res_frame);
    memset(s->res_mem, 0, sizeof s->res_mem);
    observe_residual(s);""" if res else ""
        tick_res = "\n        observe_residual(s);" if res else ""
        add_res = """
    u = u + residual_act(s->res_obs, s->res_mem);
    u = u < -1.0 ? -1.0 : (u > 1.0 ? 1.0 : u);""" if res else ""
        mem = "s->law_mem" if _has_memory(self.pol) else "NULL"
        clear_mem = "\n    memset(s->law_mem, 0, sizeof s->law_mem);" if _has_memory(self.pol) else ""
        return f"""/* ---- the tick (impact_env.rig.controller: observe_tick, then act_tick) ---- */

/* the release: the front end starts from these readings, unfiltered (as the simulator's reset) */
static void start(impact_state *s, const impact_real readings[IMPACT_N_READINGS])
{{
    for (int c = 0; c < IMPACT_N_READINGS; c++) s->cond[c] = readings[c];
    memset(s->filt, 0, sizeof s->filt);
    s->det_prev_s = 0.0;
    s->det_latch = 0.0;
    s->detected = 0.0;
    memset(s->frames, 0, sizeof s->frames);
    memset(s->past_actions, 0, sizeof s->past_actions);
    observe(s, 0, 0.0);{start_res}{clear_mem}
    s->action = 0.0;
}}

unsigned long impact_state_bytes(void)
{{
    return (unsigned long)sizeof(impact_state);
}}

int impact_contact(const impact_state *s)
{{
    return s->detected != 0.0;
}}

void impact_init(impact_state *s)
{{
    memset(s, 0, sizeof *s);
}}

void impact_reset(impact_state *s)
{{
    s->tick = 0;
    s->latch = 0;
    s->nonfinite_ticks = s->clamp_peak_ticks = s->clamp_rms_ticks = s->travel_trips = 0;
    s->sensor_fault_ticks = 0;
    memset(s->pl_good, 0, sizeof s->pl_good);
    memset(s->pl_last, 0, sizeof s->pl_last);
    s->pl_run = s->pl_latch = s->pl_primed = 0.0;
    memset(s->pl_prev, 0, sizeof s->pl_prev);
    memset(s->pl_repeat, 0, sizeof s->pl_repeat);
    memset(s->pl_demand, 0, sizeof s->pl_demand);
    s->pl_mean_square = 0.0;
}}

void impact_idle(impact_state *s, int64_t ticks)
{{
    int64_t head = s->rms_head;
    for (int64_t k = 0; k < ticks && k < IMPACT_RMS_WINDOW_TICKS; k++) {{
        s->rms_sum -= s->rms_ring[head];
        s->rms_ring[head] = 0.0;
        head = (head + 1) % IMPACT_RMS_WINDOW_TICKS;
    }}
    s->rms_head = head;
}}

uint32_t impact_step(impact_state *s, const impact_real readings[IMPACT_N_READINGS],
                     impact_real *command, impact_real *force_n)
{{
    int boundary = (s->tick % IMPACT_HOLD_TICKS) == 0;
    impact_real checked[IMPACT_N_READINGS];
    uint32_t sensor = plausible(s, readings, checked);
    if (s->tick == 0) {{
        start(s, checked);
    }} else {{
        condition(s, checked);{tick_res}
        if (boundary) observe(s, 1, s->action);
    }}
    if (boundary) s->action = policy_act(s->obs, {mem});
    impact_real u = s->action;{add_res}
    uint32_t status;
    impact_real f = safety(s, u, checked[2], sensor, &status);
    pl_note(s, (double)f);  /* the armature check's drive */
    *command = (status & MODIFIED) ? f / COMMAND_SCALE_N : u;
    *force_n = f;
    s->tick++;
    return status;
}}"""
