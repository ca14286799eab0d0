"""Body 1's energy from flight times (impact_env.rig.flight_energy), validated against the simulator's
exact contact events and true catch energy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from impact_env.hardware import stage as hardware_stage
from impact_env.rig import flight_energy
from impact_env.rig import log as tick_log
from impact_env.rig.safety import CLAMP_RMS
from impact_env.scene import load_scene
from impact_env.sim.drop import simulate
from impact_env.sim.simulator import Simulator

G = 9.81
# the log holds raw sensors; the nominal drop (0.1 kg from 50 mm), whose flight count the bounds were set for
RIG_RAW = {"effects.active": ["shaker", "saturation", "sensors", "detector"],
           "randomize.m1": [], "randomize.drop_height": []}


def _flights_from_events(ev):
    """Closed flights of exact events (rows t, kind, x1, v1, x2, v2): (separation row, onset row)."""
    out = []
    for i in range(len(ev) - 1):
        if ev[i, 1] < 0 and ev[i + 1, 1] > 0:
            out.append((ev[i], ev[i + 1]))
    return out


# -- eq 4.5 itself --------------------------------------------------------------------------------------
def test_eq45_is_exact_for_ballistic_flights_between_instantaneous_contacts():
    """An elastic pad (no damping: the flight starts at d = 0) and an immobile body 2 (m2 = 1e6
    kg): each flight gives body 1's take-off energy to the integrator's accuracy."""
    scene = load_scene("ideal", {"plant.m2": 1.0e6, "episode.horizon": 0.5})
    tr = simulate(scene)
    flights = _flights_from_events(tr.events)
    assert len(flights) == 2  # T = 2 v0 / g = 0.2 s
    for sep, on in flights:
        T = on[0] - sep[0]
        e_true = 0.5 * scene.plant.m1 * sep[3] ** 2
        w = ((on[4] - sep[4]) - (sep[2] - sep[4])) / T
        bound = scene.plant.m1 * abs(w) * abs(G * T - w) / 2  # body 2's recoil: about 1e-8 relative
        assert abs(float(flight_energy.flight_energy(T, scene.plant.m1, G)) - e_true) <= bound + 1e-9 * e_true


def test_ballistic_identity_on_the_rig():
    """With body 2 moving and a damped pad, ``u = g T / 2 - (dx2 - d_sep) / T`` exactly (the flight
    is ballistic), and eq 4.5's error is ``m1 |w| |g T - w| / 2``."""
    scene = load_scene("rig")
    tr = simulate(scene, plant_only=True)
    flights = _flights_from_events(tr.events)
    assert len(flights) >= 5
    m1 = scene.plant.m1
    rel = []
    for sep, on in flights:
        T = on[0] - sep[0]
        w = ((on[4] - sep[4]) - (sep[2] - sep[4])) / T
        assert -sep[3] == pytest.approx(G * T / 2 - w, rel=1e-7, abs=1e-9)
        e_true = 0.5 * m1 * sep[3] ** 2
        err = float(flight_energy.flight_energy(T, m1, G)) - e_true
        assert abs(err) == pytest.approx(m1 * abs(w) * abs(G * T - w) / 2, rel=1e-5, abs=1e-12)
        rel.append(abs(err) / e_true)
    assert rel[0] < 0.01  # the first bounce (0.13 s): body 2 hardly moves relative to body 1's rise


# -- from a simulated log -------------------------------------------------------------------------------
def simulated_log(scene, seed=0, policy=None):
    """A rig episode as the target would log it (raw sensors, applied force, detector bit), from
    the simulator, with its exact contact events (absolute times) and true catch energy."""
    sim = Simulator(scene, 1, events_per_env=512)
    sim.reset([np.random.default_rng(seed)])
    n = int(round(scene.episode.horizon * scene.control_rate))
    tl = tick_log.TickLog(
        n,
        0,
        extra=("x2_m", "v2_mps", "catch_energy_J", "peak_contact_N"),
        extra_units={"x2_m": "m", "v2_mps": "m/s", "catch_energy_J": "J", "peak_contact_N": "N"},
    )
    act = np.zeros(1)
    events = []
    for k in range(n):
        act[0] = 0.0 if policy is None else policy(sim)
        t0, e0 = sim.t[0], int(sim.hw.EVN[0, 0])
        sim.step(act)
        for j in range(e0, int(sim.hw.EVN[0, 0])):
            row = sim.hw.EV[0, j].copy()
            row[0] += t0
            events.append(row)
        r, info = sim.readings[0], sim.info[0]
        tl.record(
            tick=k + 1,
            t_s=sim.t[0],
            accelerometer_mps2=r[0],
            force_N=r[1],
            potentiometer_m=r[2],
            action=act[0],
            force_demand_N=info[hardware_stage.INFO_F_DEMAND],
            force_applied_N=info[hardware_stage.INFO_F_APPLIED],
            contact_detected=sim.detected[0],
            step=k + 1,
            x2_m=sim.Y[0, 2],
            v2_mps=sim.Y[0, 3],
            catch_energy_J=sim.catch_energy()[0],
            peak_contact_N=max(info[hardware_stage.INFO_PEAK_FORCE], info[hardware_stage.INFO_CONTACT_FORCE]),
        )
    meta = tick_log.EpisodeMeta(scene_toml=scene.to_toml(), mode="onboard", hold_ticks=1, seed=seed,
                                control_rate_hz=scene.control_rate)
    return tl.to_episode(meta), np.array(events), float(sim.impact_energy[0])


@pytest.fixture(scope="module")
def passive_rig():
    scene = load_scene("rig", RIG_RAW)
    return (scene, *simulated_log(scene))


@pytest.fixture(scope="module")
def caught_rig():
    """The thesis's law (eq 2.17, corrected 2.18; sec 3.3 gains) on the true state, clipped to
    the rig's +-200 N: body 1 leaves once, flies 0.13 s and is caught after a few hops."""
    from baselines.thesis_ideal import ThesisIdeal

    scene = load_scene("rig", RIG_RAW)
    law = ThesisIdeal(scene)

    def policy(sim):
        y = sim.Y[0]
        f2 = law.force_from_state(y[0], y[1], y[2], y[3])
        return float(np.clip(f2 / scene.effects.command_scale, -1.0, 1.0))

    return (scene, *simulated_log(scene, policy=policy))


def _phi_noise(scene):
    s = scene.effects.sensors
    return math.hypot(s.force.noise_std, scene.effects.detector.top_mass * s.accelerometer.noise_std)


class FlightCheck:
    """The derived error bounds of one flight of the estimate against its exact events.

    Timing: the measured flight is longer than the exact one by at most the threshold's crossing
    delays (:func:`crossing_delays` at the threshold plus 5 sigma of the force noise) and one
    sample per edge, shorter by at most a sample per edge: ``|dT| <= dT_max``.  Body 2's travel
    read at the measured edges is off by at most ``|v2| (edge error)`` plus 5 sigma of the
    potentiometer's noise per edge.  Velocity at the separation, exactly
    ``v1 = (dx2 - d_sep) / T - g T / 2``:

    * ``thesis`` (dx2 = d_sep = 0 assumed): ``|dv1| <= g dT_max / 2 + |dx2 - d_sep| / T``;
    * ``ballistic``: ``|dv1| <= g dT_max / 2 + e_x / Tm + |dx2| dT_max / (T Tm) + d_sep / T``.

    Energy: ``|dE| <= m1 |dv1| (2 |v1| + |dv1|) / 2``.
    """

    def __init__(self, scene, sep, on, Tm, v2max, method):
        m1, dt = scene.plant.m1, 1.0 / scene.control_rate
        thr = scene.effects.detector.threshold_n + 5.0 * _phi_noise(scene)
        self.T = T = on[0] - sep[0]
        self.d_sep = d_sep = sep[2] - sep[4]
        late_on, early_off = flight_energy.crossing_delays(
            thr, scene.plant.c, on[3] - on[5], sep[5] - sep[3], d_sep
        )
        self.dT_max = dT = late_on + early_off + 2 * dt
        dx2 = on[4] - sep[4]
        sx = scene.effects.sensors.potentiometer.noise_std
        self.e_x = v2max * (late_on + early_off + 2 * dt) + 2 * 5.0 * sx
        self.edge_x = v2max * (early_off + dt) + 5.0 * sx
        if method == "thesis":
            dv = G * dT / 2 + abs(dx2 - d_sep) / T
        else:
            dv = G * dT / 2 + self.e_x / Tm + abs(dx2) * dT / (T * Tm) + d_sep / T
        self.dv = dv
        self.v1 = sep[3]
        self.dE = m1 * dv * (2 * abs(sep[3]) + dv) / 2
        self.e_sep = 0.5 * m1 * sep[3] ** 2 + flight_energy.Plant.of(scene).rest_energy


def _thr(scene):
    return scene.effects.detector.threshold_n + 5.0 * _phi_noise(scene)


def _match(est, sep, on, scene):
    """The estimated flight whose edges lie where the derived delays put them: the separation
    within [t_sep - early_off - dt, t_sep + dt], the touch within [t_on - dt, t_on + late_on + dt]."""
    dt = 1.0 / scene.control_rate
    late_on, early_off = flight_energy.crossing_delays(
        _thr(scene), scene.plant.c, on[3] - on[5], sep[5] - sep[3], sep[2] - sep[4]
    )
    fl = est.flights
    ok = (
        (fl[:, flight_energy.FL.t_sep] >= sep[0] - early_off - dt)
        & (fl[:, flight_energy.FL.t_sep] <= sep[0] + dt)
        & (fl[:, flight_energy.FL.t_on] >= on[0] - dt)
        & (fl[:, flight_energy.FL.t_on] <= on[0] + late_on + dt)
    )
    j = np.flatnonzero(ok)
    return int(j[0]) if j.size else None


def _unresolvable(scene, log, events, sep, on):
    """A force threshold cannot see a flight if the true contact force stays below it (plus 5
    sigma of the noise) in the contact before or after the flight (a soft landing, or a lift-off
    from light contact)."""
    t, peak = log["t_s"], log["peak_contact_N"]
    later = events[events[:, 0] > on[0] + 1e-9]
    nxt = later[later[:, 1] < 0]
    earlier = events[(events[:, 0] < sep[0] - 1e-9) & (events[:, 1] > 0)]
    after = (t > on[0]) & (t <= (nxt[0, 0] if len(nxt) else t[-1]) + 1e-4)
    before = (t >= (earlier[-1, 0] if len(earlier) else 0.0)) & (t <= sep[0] + 1e-4)
    return min(peak[after].max(initial=0.0), peak[before].max(initial=0.0)) < _thr(scene)


def _v2max(log, a, b):
    m = (log["t_s"] >= a - 2e-3) & (log["t_s"] <= b + 2e-3)
    return float(np.max(np.abs(log["v2_mps"][m])))


@pytest.mark.parametrize("case", ["passive_rig", "caught_rig"])
@pytest.mark.parametrize("source,method",
                         [("force", "ballistic"), ("force", "thesis"), ("detector", "ballistic")])
def test_flight_energies_within_the_derived_bounds(case, source, method, request):
    """Every measured flight against the exact one, within :class:`FlightCheck`'s bounds; only
    flights too low for the threshold to resolve may go unseen."""
    scene, log, events, e0 = request.getfixturevalue(case)
    x2 = log["potentiometer_m"] if method == "ballistic" else None
    est = flight_energy.estimate_energy(
        log["t_s"], flight_energy.contact_from_log(log, source), flight_energy.Plant.of(scene), x2
    )
    matched = 0
    for sep, on in _flights_from_events(events):
        j = _match(est, sep, on, scene)
        if j is None:
            assert _unresolvable(scene, log, events, sep, on)
            continue
        matched += 1
        f = est.flights[j]
        chk = FlightCheck(scene, sep, on, f[flight_energy.FL.T], _v2max(log, sep[0], on[0]), method)
        assert -2 / scene.control_rate <= f[flight_energy.FL.T] - chk.T <= chk.dT_max
        assert abs(f[flight_energy.FL.e_sep] - chk.e_sep) <= chk.dE
        if method == "ballistic":
            assert abs(f[flight_energy.FL.v1] - chk.v1) <= chk.dv
    assert matched >= (8 if case == "passive_rig" else 2)


@pytest.mark.parametrize("case", ["passive_rig", "caught_rig"])
def test_summary_against_the_simulator(case, request):
    """compare's metrics from the log's estimate against the simulator's truth: residual
    energies read inside a flight (in flight the catch energy follows body 2's travel: the bound
    adds ``m1 g`` times the potentiometer's error there), the exit velocity, the bounces, and the
    catch time to within the event interval that holds the true 1 % crossing (the estimate is
    piecewise between contact edges)."""
    scene, log, events, e0 = request.getfixturevalue(case)
    s = flight_energy.summarize(log)
    t, e_true = log["t_s"], log["catch_energy_J"]
    m1 = scene.plant.m1
    flights = _flights_from_events(events)
    t_touch = events[0, 0]
    est = flight_energy.estimate_energy(
        t, flight_energy.contact_from_log(log), flight_energy.Plant.of(scene), log["potentiometer_m"]
    )
    checked = 0
    for mark in (10, 50, 100):
        k = int(np.flatnonzero(t - s["t_touch_s"] >= mark * 1e-3 - 1e-12)[0])
        inside = [(a, b) for a, b in flights
                  if a[0] + 2e-3 < t[k] < b[0] - 2e-3 and _match(est, a, b, scene) is not None]
        if not inside:
            continue  # read during a contact: an interpolation, not checked
        sep, on = inside[0]
        j = _match(est, sep, on, scene)
        chk = FlightCheck(
            scene, sep, on, est.flights[j, flight_energy.FL.T], _v2max(log, sep[0], on[0]), "ballistic"
        )
        sx = scene.effects.sensors.potentiometer.noise_std
        bound = chk.dE + m1 * G * (chk.edge_x + 5.0 * sx + chk.d_sep)
        assert abs(s[f"residual_energy_{mark}ms"] * e0 - e_true[k]) <= bound, mark
        checked += 1
    assert checked >= 2
    sep, on = flights[0]
    chk = FlightCheck(
        scene, sep, on, est.flights[0, flight_energy.FL.T], _v2max(log, sep[0], on[0]), "ballistic"
    )
    assert abs(s["exit_velocity_ratio"] * scene.impact_speed - (-sep[3])) <= chk.dv
    # bounces: every true flight of 1 ms or more that the force threshold resolves, and no other
    true_bounces = [(a, b) for a, b in flights if b[0] - a[0] >= 1e-3]
    seen = [1 for a, b in true_bounces if _match(est, a, b, scene) is not None]
    assert s["bounces"] == len(seen) == len(est.flights)
    assert all(_unresolvable(scene, log, events, a, b) for a, b in true_bounces
               if _match(est, a, b, scene) is None)
    above = np.flatnonzero(e_true >= 0.01 * e0)
    ttc_true = t[above[-1] + 1] - t_touch
    i = int(np.searchsorted(events[:, 0], t_touch + ttc_true))
    tol = events[min(i, len(events) - 1), 0] - events[max(i - 2, 0), 0]
    assert abs(s["time_to_catch_s"] - ttc_true) <= tol
    assert s["caught"]
    print(f"{case}, estimate vs simulator: catch {s['time_to_catch_s']:.4f} s vs {ttc_true:.4f} s, "
          f"exit velocity ratio {s['exit_velocity_ratio']:.4f} vs {-sep[3] / scene.impact_speed:.4f}, "
          f"bounces {s['bounces']} vs {len(true_bounces)}, residual 10/50/100 ms "
          + "/".join(f"{s[f'residual_energy_{m}ms']:.3f}" for m in (10, 50, 100)) + " vs "
          + "/".join(f"{e_true[int(np.flatnonzero(t - s['t_touch_s'] >= m * 1e-3 - 1e-12)[0])] / e0:.3f}"
                     for m in (10, 50, 100))
          + f", energy integral {s['energy_integral_ms']:.2f} ms vs "
          f"{float(np.sum(e_true / e0)) / scene.control_rate * 1e3:.2f} ms")


# -- the estimate's rules on synthetic contacts ---------------------------------------------------------
PLANT = flight_energy.Plant(m1=0.1, m2=1.0, c=2.0e6, g=G, impact_speed=1.0)
RATE = 1.0e4
T_GRID = np.arange(0, 4000) / RATE


def test_estimate_flights_interpolation_and_the_final_contact():
    c = flight_energy.Contacts(onsets=np.array([0.001, 0.101, 0.151]), separations=np.array([0.005, 0.104]),
                               t_end=0.3999)
    est = flight_energy.estimate_energy(T_GRID, c, PLANT)
    u0, e0 = PLANT.rest_energy, PLANT.impact_energy
    f1 = flight_energy.flight_energy(0.096, 0.1, G) + u0
    f2 = flight_energy.flight_energy(0.047, 0.1, G) + u0
    np.testing.assert_allclose(est.flights[:, flight_energy.FL.T], [0.096, 0.047])
    # no x2: eq 4.5
    np.testing.assert_allclose(est.flights[:, flight_energy.FL.v1], [-G * 0.096 / 2, -G * 0.047 / 2])
    np.testing.assert_allclose(est.flights[:, flight_energy.FL.e_sep], [f1, f2])
    np.testing.assert_allclose(est.flights[:, flight_energy.FL.e_land], [f1, f2])
    E = est.energy_J

    def at(t):
        return E[int(round(t * RATE))]

    assert at(0.0) == e0 and at(0.05) == pytest.approx(f1) and at(0.13) == pytest.approx(f2)
    assert at(0.003) == pytest.approx(e0 + (f1 - e0) * 0.5)  # middle of the first contact
    assert at(0.1025) == pytest.approx(f1 + (f2 - f1) * 0.5)
    settle = flight_energy.hertz_contact_time(G * 0.047 / 2, PLANT.effective_mass, PLANT.c)
    assert 0.001 < settle < 0.02
    assert at(0.151 + settle / 2) == pytest.approx(f2 / 2, rel=0.05) and at(0.151 + settle + 1e-3) == 0.0
    assert est.t_touch == 0.001 and np.all(np.isfinite(E))
    assert est.contact[int(0.003 * RATE)] and not est.contact[int(0.05 * RATE)] and est.contact[-1]


def test_hertz_contact_time_matches_the_notes():
    # thesis notes: m1 = 0.1, m2 = 1, c = 2e6, 1 m/s -> 3.72 ms
    assert flight_energy.hertz_contact_time(1.0, PLANT.effective_mass, PLANT.c) == pytest.approx(
        3.72e-3, rel=2e-3
    )


def test_open_last_flight_is_unknown_and_no_contact_is_the_drop():
    c = flight_energy.Contacts(np.array([0.001, 0.101]), np.array([0.005, 0.104]), 0.3999, open_flight=True)
    E = flight_energy.estimate_energy(T_GRID, c, PLANT).energy_J
    assert np.isnan(E[int(0.2 * RATE)]) and np.isnan(E[int(0.102 * RATE)])
    assert np.isfinite(E[int(0.05 * RATE)])
    none = flight_energy.estimate_energy(T_GRID, flight_energy.Contacts(np.zeros(0), np.zeros(0), 0.4), PLANT)
    assert np.all(none.energy_J == PLANT.impact_energy) and math.isnan(none.t_touch)


def test_level_edges_are_interpolated_and_bits_are_split():
    t = np.arange(10) * 1e-3
    s = np.array([0, 0, 1, 3, 5, 5, 3, 1, 0, 0], dtype=float)
    c = flight_energy.contact_intervals(t, signal=s, threshold_n=2.0, min_flight_s=0.0)
    np.testing.assert_allclose(c.onsets, [2.5e-3])  # 1 -> 3 crosses 2 halfway
    np.testing.assert_allclose(c.separations, [6.5e-3])
    b = flight_energy.contact_intervals(t, contact=s > 2.0, min_flight_s=0.0)
    np.testing.assert_allclose(b.onsets, [2.5e-3])
    np.testing.assert_allclose(b.separations, [6.5e-3])
    assert c.open_flight and c.threshold_n == 2.0 and b.threshold_n == 0.0


def test_chatter_light_contact_and_rest_are_not_flights():
    t = np.arange(3000) / RATE
    s = np.zeros_like(t)
    s[10:40] = 50.0  # impact
    s[40:45] = 0.0  # 0.5 ms "flight": chatter
    s[45:60] = 30.0
    s[60:1000] = 0.0  # a real flight
    s[1000:1030] = 20.0
    s[1030:1500] = 1.0  # light contact: about m1 g, below the 2 N threshold
    s[1500:1520] = 10.0
    s[1520:] = 0.98  # at rest
    c = flight_energy.contact_intervals(t, signal=s, threshold_n=2.0, min_flight_s=1e-3, rest_level_n=0.49)
    assert len(c.onsets) == 2 and len(c.separations) == 1 and not c.open_flight
    np.testing.assert_allclose([c.onsets[1] - c.separations[0]], [(1000 - 60) / RATE], atol=1.5 / RATE)
    flying = flight_energy.contact_intervals(
        t, signal=np.where(t > 0.152, 0.0, s), threshold_n=2.0, rest_level_n=0.49
    )
    assert flying.open_flight  # force 0 after the last contact: a flight that has not landed


def test_contact_argument_errors():
    t = np.arange(5) * 1e-3
    with pytest.raises(ValueError, match="exactly one"):
        flight_energy.contact_intervals(t)
    with pytest.raises(ValueError, match="increasing"):
        flight_energy.contact_intervals(t[::-1], contact=np.zeros(5, bool))
    with pytest.raises(ValueError, match="non-finite"):
        flight_energy.contact_intervals(t, signal=np.array([0, np.nan, 0, 0, 0.0]), threshold_n=1.0)


def test_summary_measured_columns_and_sources():
    scene = load_scene("rig")
    n = 200
    tl = tick_log.TickLog(n, 0)
    for k in range(n):
        tl.record(tick=k, t_s=k / 1e4, force_applied_N=50.0 if k < 100 else -20.0, force_demand_N=60.0,
                  action=1.0 if k < 10 else 0.3, status=CLAMP_RMS if 50 <= k < 55 else 0)
    log = tl.to_episode(tick_log.EpisodeMeta(scene.to_toml(), "host", 1, 0, 1e4))
    s = flight_energy.summarize(log, source="detector")
    assert s["peak_force_N"] == 50.0 and s["rms_force_N"] == pytest.approx(math.sqrt((50**2 + 20**2) / 2))
    assert s["peak_demand_N"] == 60.0 and s["saturation_time_s"] == pytest.approx(15e-4)
    assert s["bounces"] == 0 and s["residual_energy_10ms"] != s["residual_energy_10ms"]  # NaN: no touch
    assert not s["caught"]
    with pytest.raises(ValueError, match="source"):
        flight_energy.summarize(log, source="camera")
