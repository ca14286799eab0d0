"""Shaker (amplifier + electrodynamic exciter) response: force demand (N) -> force on body 2 (N).

Model ``coil`` (default): a voltage amplifier with the exciter's usable band (LDS V406 with
PA 100E: 5-9000 Hz, thesis sec 4.3) driving the coil, whose current follows the voltage through
the electrical pole R/L; the force is ``Bl i``.  The command is scaled so that the mid-band gain
is 1 N/N:

    H(s) = s/(s + w_hp) * w_lp/(s + w_lp) * w_e/(s + w_e),   w_e = R/L

The V406's coil values are not in the thesis: R = 1 ohm, L = 50 uH (pole at 3.2 kHz),
Bl = 14 N/A (98 N at 7 A) are assumptions in the range of published small-shaker data, marked
as such; replace them with identified values.

Back-EMF (``back_emf = true``, voltage mode only).  The moving coil induces ``Bl v_up`` against
the amplifier, so the coil current is ``i = (V + Bl v2) / (R + s L)`` (v2 down positive) and the
force gains the term

    f_emf = (Bl^2 / R) * w_e/(s + w_e) [v2]          (N; Bl^2/R = 196 N s/m with the values above)

an electrical damper on body 2, low-passed by the coil pole.  It is coupled to the plant at the
control rate: body 2's velocity at the start of each control period is the (held) second input
of the same exactly-discretised model, so the damping acts with at most one period of lag.  The
loop gain of that explicit coupling per period is ``(Bl^2/R) T / m2`` (0.02 on the rig); the
scene refuses values above 0.5.  **It is off by default and in** ``rig``: the rig's suspension
damping (20 N s/m) was calibrated, with the plant alone, to the thesis's uncontrolled decay, so it
stands for all of body 2's damping; switching the back-EMF on with the assumed R and Bl adds ten
times that damping and shortens the uncontrolled decay (recalibrate the suspension, or use
identified R and Bl, before relying on it).  In ``current`` mode the amplifier's current loop
holds i = command / Bl whatever the coil's motion: no coil pole and no back-EMF, H(s) is the
band-pass alone.

Model ``measured``: a response measured on the rig, given as FIR taps at the control rate
(the thesis convolved its commands with the measured response, sec 4.3).

``inverse_filter`` (both models): the thesis's approximate inverse: the command is pre-filtered by
``(s + w_e)/w_e * w_i/(s + w_i)`` (w_i = 2 pi inverse_rolloff_hz), which cancels the coil pole and
keeps the filter proper.

The continuous model is discretised exactly for a zero-order-hold command at the control rate
(``scipy.signal.cont2discrete``), so the force held over period k is the exact response of the
continuous model to the held command.  The numba kernel steps a state-space model.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy import signal

from impact_env._jit import jit
from impact_env.config import ConfigError, check_choice, check_range, doc_field
from impact_env.effects.effect import HARDWARE, Effect

_f = doc_field
MAX_TAPS = 4096  # measured impulse responses are a few hundred taps at 10 kHz


@dataclass(frozen=True)
class ShakerConfig:
    """The amplifier and exciter between the force demand and body 2.  It runs when ``shaker``
    is in ``effects.active`` (nothing else switches it)."""

    model: str = _f("coil", "", "coil (parametric) | measured (FIR taps)")
    amplifier: str = _f("voltage", "", "voltage (coil pole R/L, optional back-EMF) | current (current loop: "
                        "band-pass only)")
    back_emf: bool = _f(False, "", "voltage mode: couple the coil's back-EMF Bl v2 (electrical damping "
                        "Bl^2/R on body 2); off: the suspension damping stands for it (see module doc)")
    highpass_hz: float = _f(5.0, "Hz", "lower band edge of amplifier + shaker (V406/PA 100E data: 5 Hz)")
    lowpass_hz: float = _f(9000.0, "Hz", "upper band edge (V406 data: 9 kHz)")
    coil_resistance: float = _f(1.0, "ohm", "ASSUMED coil resistance R (not in the thesis)")
    coil_inductance: float = _f(50e-6, "H", "ASSUMED coil inductance L (not in the thesis); pole R/(2 pi L)")
    force_factor: float = _f(14.0, "N/A", "ASSUMED Bl (98 N rated at about 7 A); enters only the back-EMF's "
                             "damping Bl^2/R (the command is scaled to 1 N/N mid-band)")
    fir_taps: tuple[float, ...] = _f((), "N/N",
                                     "measured impulse response at the control rate (model = measured)")
    inverse_filter: bool = _f(False, "", "pre-filter the demand by an approximate inverse of the coil pole")
    inverse_rolloff_hz: float = _f(20000.0, "Hz", "roll-off that keeps the inverse filter proper")

    def __post_init__(self):
        # bounds: band edges from 1 mHz to 10 MHz, coils from 0.1 mohm / 1 nH to 10 kohm / 10 H
        # (every exciter lies far inside; beyond them the discretisation overflows or rounds a
        # pole onto the unit circle)
        check_choice("effects.shaker.model", self.model, ("coil", "measured"))
        check_range("effects.shaker.highpass_hz", self.highpass_hz, "Hz", 0.0, 1e7)
        if 0.0 < self.highpass_hz < 1e-3:
            raise ConfigError(f"effects.shaker.highpass_hz = {self.highpass_hz!r} Hz is out of range: must "
                              "be 0 (no high-pass) or >= 0.001 Hz")
        check_range("effects.shaker.lowpass_hz", self.lowpass_hz, "Hz", 1e-3, 1e7)
        check_range("effects.shaker.coil_resistance", self.coil_resistance, "ohm", 1e-4, 1e4)
        check_range("effects.shaker.coil_inductance", self.coil_inductance, "H", 1e-9, 10.0)
        check_range("effects.shaker.force_factor", self.force_factor, "N/A", 1e-3, 1e4)
        check_range("effects.shaker.inverse_rolloff_hz", self.inverse_rolloff_hz, "Hz", 1e-3, 1e7)
        if len(self.fir_taps) > MAX_TAPS:
            raise ConfigError(f"effects.shaker.fir_taps has {len(self.fir_taps)} taps, more than {MAX_TAPS}")
        for i, tap in enumerate(self.fir_taps):
            check_range(f"effects.shaker.fir_taps[{i}]", tap, "N/N", -1e6, 1e6)
        if self.highpass_hz >= self.lowpass_hz:
            raise ConfigError(f"effects.shaker.highpass_hz = {self.highpass_hz:g} Hz must be below "
                              f"effects.shaker.lowpass_hz = {self.lowpass_hz:g} Hz")
        check_choice("effects.shaker.amplifier", self.amplifier, ("voltage", "current"))
        if not isinstance(self.back_emf, bool):
            raise ConfigError(f"effects.shaker.back_emf must be true or false, got {self.back_emf!r}")
        if self.back_emf and (self.model != "coil" or self.amplifier != "voltage"):
            raise ConfigError("effects.shaker.back_emf needs model = coil and amplifier = voltage "
                              f"(got model = {self.model!r}, amplifier = {self.amplifier!r})")
        if self.inverse_filter and self.model == "coil" and self.amplifier == "current":
            raise ConfigError("effects.shaker.inverse_filter cancels the coil pole of voltage mode; "
                              "with amplifier = current there is none")
        if self.model == "measured" and len(self.fir_taps) == 0:
            raise ConfigError("effects.shaker.fir_taps must hold the measured impulse response "
                              "when effects.shaker.model = measured")

    @property
    def electrical_pole_hz(self) -> float:
        return self.coil_resistance / (2 * np.pi * self.coil_inductance)

    @property
    def emf_damping(self) -> float:
        """Bl^2 / R, the back-EMF's damping coefficient on body 2 (N s/m)."""
        return self.force_factor**2 / self.coil_resistance

    def check_coupling(self, m2: float, rate: float) -> None:
        """ConfigError if the back-EMF's per-period coupling gain (Bl^2/R) T / m2 exceeds 0.5."""
        if self.back_emf:
            gain = self.emf_damping / (rate * m2)
            if gain > 0.5:
                raise ConfigError(
                    f"effects.shaker.back_emf: the electrical damping Bl^2/R = {self.emf_damping:g} N s/m "
                    f"on m2 = {m2:g} kg over one control period ({1 / rate:g} s) gives a coupling gain "
                    f"{gain:.3g} > 0.5: raise control.rate or check coil_resistance and force_factor")


def continuous_tf(cfg: ShakerConfig) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) of the coil model H(s), force per force demand, mid-band gain 1."""
    wh = 2 * np.pi * cfg.highpass_hz
    wl = 2 * np.pi * cfg.lowpass_hz
    we = cfg.coil_resistance / cfg.coil_inductance
    if cfg.amplifier == "current":
        if wh > 0:
            return np.array([wl, 0.0]), np.polymul([1.0, wh], [1.0, wl])
        return np.array([wl]), np.array([1.0, wl])
    if wh > 0:
        num = np.array([wl * we, 0.0])
        den = np.polymul(np.polymul([1.0, wh], [1.0, wl]), [1.0, we])
    else:
        num = np.array([wl * we])
        den = np.polymul([1.0, wl], [1.0, we])
    return num, den


def inverse_tf(cfg: ShakerConfig) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) of the approximate inverse pre-filter."""
    we = cfg.coil_resistance / cfg.coil_inductance
    wi = 2 * np.pi * cfg.inverse_rolloff_hz
    return np.array([wi / we, wi]), np.array([1.0, wi])


def discrete_model(cfg: ShakerConfig, rate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(A, B, C, D) of the discretised shaker (with the inverse pre-filter if enabled) at ``rate``."""
    if cfg.model == "measured":
        taps = np.asarray(cfg.fir_taps, dtype=float)
        n = max(len(taps) - 1, 1)
        A = np.eye(n, k=-1)  # shift register of the last n inputs
        B = np.zeros((n, 1))
        B[0, 0] = 1.0
        C = np.zeros((1, n))
        C[0, : len(taps) - 1] = taps[1:]
        sys_d = (A, B, C, np.array([[taps[0]]]))
    else:
        num, den = continuous_tf(cfg)
        sys_d = signal.cont2discrete(signal.tf2ss(num, den), 1.0 / rate, method="zoh")[:4]
    if cfg.inverse_filter:
        ni, di = inverse_tf(cfg)
        inv = signal.cont2discrete(signal.tf2ss(ni, di), 1.0 / rate, method="bilinear")[:4]
        sys_d = _series(inv, sys_d)
    A, B, C, D = (np.ascontiguousarray(np.atleast_2d(m), dtype=float) for m in sys_d)
    _check_discrete(cfg, rate, A, B, C, D)
    return A, B[:, 0].copy(), C[0].copy(), float(D[0, 0])


def _check_discrete(cfg: ShakerConfig, rate: float, *mats) -> None:
    """ConfigError, naming the fields, unless the discretised model is finite and stable."""
    if not all(np.all(np.isfinite(m)) for m in mats) or np.max(np.abs(np.linalg.eigvals(mats[0]))) >= 1.0:
        raise ConfigError(
            "effects.shaker: the model discretised at control.rate = "
            f"{rate:g} Hz is not finite and stable (effects.shaker.highpass_hz = {cfg.highpass_hz:g} Hz, "
            f"lowpass_hz = {cfg.lowpass_hz:g} Hz, coil pole R/(2 pi L) = {cfg.electrical_pole_hz:g} Hz from "
            f"coil_resistance and coil_inductance, inverse_rolloff_hz = {cfg.inverse_rolloff_hz:g} Hz): "
            "move the band edges and poles well inside 0 .. 1e7 Hz")


def continuous_emf_model(cfg: ShakerConfig):
    """(A, B, C, D) of the voltage-mode coil model with back-EMF, inputs [demand N, v2 m/s]:
    the amplifier's band-pass (state space of ``tf2ss``) in series with the coil pole, whose
    input is the band-passed demand plus ``(Bl^2/R) v2``.  Output: force on body 2 (N, up)."""
    wh = 2 * np.pi * cfg.highpass_hz
    wl = 2 * np.pi * cfg.lowpass_hz
    we = cfg.coil_resistance / cfg.coil_inductance
    if wh > 0:
        num, den = np.array([wl, 0.0]), np.polymul([1.0, wh], [1.0, wl])
    else:
        num, den = np.array([wl]), np.array([1.0, wl])
    Aa, Ba, Ca, Da = (np.atleast_2d(m) for m in signal.tf2ss(num, den))
    na = Aa.shape[0]
    A = np.block([[Aa, np.zeros((na, 1))], [we * Ca, np.array([[-we]])]])
    B = np.zeros((na + 1, 2))
    B[:na, 0] = Ba[:, 0]
    B[na, 0] = we * Da[0, 0]
    B[na, 1] = we * cfg.emf_damping
    C = np.zeros((1, na + 1))
    C[0, na] = 1.0
    return A, B, C, np.zeros((1, 2))


def discrete_emf_model(cfg: ShakerConfig, rate: float):
    """(A, B, C, D, E) at ``rate``: :func:`discrete_model` plus E, the input vector of body 2's
    velocity (held over the period) for the back-EMF; E = 0 without ``back_emf``.  Without
    back-EMF A, B, C, D are exactly those of :func:`discrete_model`.

    Cached per (config, rate) (a Simulator resets drawn scenes whose shaker is often the same);
    every call returns fresh copies."""
    A, B, C, D, E = _discrete_emf_model(cfg, float(rate))
    return A.copy(), B.copy(), C.copy(), D, E.copy()


@functools.lru_cache(maxsize=64)
def _discrete_emf_model(cfg: ShakerConfig, rate: float):
    if not cfg.back_emf:
        A0, B0, C0, D0 = discrete_model(cfg, rate)
        return A0, B0, C0, D0, np.zeros_like(B0)
    A, B2, C, D2 = signal.cont2discrete(continuous_emf_model(cfg), 1.0 / rate, method="zoh")[:4]
    Bu, E = B2[:, :1], B2[:, 1:]
    D = D2[:, :1]
    if cfg.inverse_filter:
        ni, di = inverse_tf(cfg)
        inv = signal.cont2discrete(signal.tf2ss(ni, di), 1.0 / rate, method="bilinear")[:4]
        A, Bu, C, D = _series(inv, (A, Bu, C, D))
        E = np.vstack([np.zeros((A.shape[0] - E.shape[0], 1)), E])
    A, Bu, C, D, E = (np.ascontiguousarray(np.atleast_2d(m), dtype=float) for m in (A, Bu, C, D, E))
    _check_discrete(cfg, rate, A, Bu, C, D, E)
    return A, Bu[:, 0].copy(), C[0].copy(), float(D[0, 0]), E[:, 0].copy()


def _series(first, second):
    """State-space of ``second(first(u))``."""
    A1, B1, C1, D1 = (np.atleast_2d(m) for m in first)
    A2, B2, C2, D2 = (np.atleast_2d(m) for m in second)
    n1, n2 = A1.shape[0], A2.shape[0]
    A = np.block([[A1, np.zeros((n1, n2))], [B2 @ C1, A2]])
    B = np.vstack([B1, B2 @ D1])
    C = np.hstack([D2 @ C1, C2])
    return A, B, C, D2 @ D1


@jit
def shaker_step(A, B, C, D, x, u):
    """Force held over this period for the demand u (N); advances the state x in place."""
    return shaker_step_into(A, B, C, D, x, u, np.empty(x.shape[0]))


@jit(inline="always")
def shaker_step_into(A, B, C, D, x, u, scratch):
    """:func:`shaker_step` with a caller-owned scratch array (float64[n]) instead of an allocation."""
    return _shaker_step_flat(A.ravel(), 0, B, C, D, x, u, scratch)


@jit(inline="always")
def _shaker_step_flat(p, a0, B, C, D, x, u, scratch):
    """The step, with A read row-major from ``p[a0:]``: the packed block's row is used as it
    is, where a reshape would cost a call into numba's helper every tick."""
    n = x.shape[0]
    y = D * u
    for i in range(n):
        y += C[i] * x[i]
    for i in range(n):
        acc = B[i] * u
        for j in range(n):
            acc += p[a0 + i * n + j] * x[j]
        scratch[i] = acc
    for i in range(n):
        x[i] = scratch[i]
    return y


# -- packed block (one env's shaker inside a per-env row; see impact_env.hardware.blocks) --------
# parameters: [D, A (order * order, row-major), B, C, E (order each)]; state: [x, scratch]

def block_sizes(order: int) -> tuple[int, int]:
    """(parameter, state) sizes of a packed shaker model of state order ``order``."""
    return 1 + order * order + 3 * order, 2 * order


P_D = 0  # the packed block: [D, A (ns x ns), B, C, E]


def pack_params(A, B, C, D, E) -> np.ndarray:
    """The parameter block of the discretised model (A, B, C, D, E), as :func:`discrete_emf_model`
    returns it."""
    return np.concatenate([[float(D)], np.asarray(A, float).ravel(), np.asarray(B, float),
                           np.asarray(C, float), np.asarray(E, float)])


@jit(inline="always")
def shaker_packed(p, st, u, v2, back_emf):
    """Force held over this period for the demand u (N), on a packed block; with ``back_emf``
    body 2's velocity v2 (m/s, down positive, held over the period) enters through E."""
    ns = st.shape[0] // 2
    x = st[:ns]
    o = P_D + 1 + ns * ns
    f = _shaker_step_flat(p, P_D + 1, p[o:o + ns], p[o + ns:o + 2 * ns], p[P_D], x, u, st[ns:])
    if back_emf:
        for j in range(ns):
            x[j] += p[o + 2 * ns + j] * v2
    return f


def _pack(cfg: ShakerConfig, rate: float, on: bool) -> tuple[np.ndarray, int]:
    """The discretised model at ``rate``; a shaker that is off gets a model of order 1 and zeros
    (never read)."""
    if on:
        A, B, C, D, E = discrete_emf_model(cfg, rate)
    else:
        A, B, C, D, E = np.zeros((1, 1)), np.zeros(1), np.zeros(1), 0.0, np.zeros(1)
    return pack_params(A, B, C, D, E), block_sizes(A.shape[0])[1]


EFFECT = Effect("shaker", HARDWARE, "shaker", ShakerConfig,
                "the amplifier and exciter: force demand to force on body 2", readings_only=False, pack=_pack,
                options=("back_emf",))
