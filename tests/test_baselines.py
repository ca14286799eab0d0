"""Baselines (baselines/): the SB3 predict interface, the registry, and the thesis's laws."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from baselines import POLICIES, PDPenetration, ThesisIdeal, ThesisRig, make_policy, parse_spec
from impact_env import simulate
from impact_env.config import ConfigError
from impact_env.control import laws
from impact_env.control.observation import make_layout
from impact_env.policy.sb3 import parse_model_spec
from impact_env.scene import load_scene
from impact_env.sim.drop import SimulationDiverged

RIG = load_scene("rig")
IDEAL = load_scene("ideal")


# -- registry and interface ---------------------------------------------------------------------

def test_registry_names_and_params():
    assert set(POLICIES) == set(laws.LAWS) and {"thesis-rig", "thesis-ideal"} <= set(POLICIES)
    p = make_policy("thesis-rig:h01=1.2e6,h11=18", RIG)
    assert isinstance(p, ThesisRig) and p.params["h01"] == 1.2e6 and p.params["h11"] == 18.0
    assert make_policy("thesis-rig", RIG).params["h01"] == 2.3e6
    assert parse_spec("thesis-ideal:free_law=printed") == ("thesis-ideal", {"free_law": "printed"})


def test_every_law_module_is_registered_and_dispatched():
    """A module of impact_env/control/laws/ that declares a Law is in the registry (a new law's
    module without its registry line fails here), the compiled dispatch runs each registered
    law's own kernel (its branch in law_force), each law's class exists by name, and the docs'
    table of laws is the one the registry writes (``python scripts/docs_tables.py``)."""
    import importlib
    import pkgutil
    from pathlib import Path

    from impact_env.control.laws.law import Law

    declared = []
    for mod in pkgutil.iter_modules(laws.__path__):
        m = importlib.import_module(f"{laws.__name__}.{mod.name}")
        declared += [v for v in vars(m).values() if isinstance(v, Law)]
    assert set(declared) == set(laws.REGISTRY)
    rng = np.random.default_rng(5)
    for law in laws.REGISTRY:
        m = importlib.import_module(f"{laws.__name__}.{law.name.replace('-', '_')}")
        names = tuple(law.reads._fields)
        slots = laws.law_slots(law.name, names)
        k = rng.uniform(0.5, 2.0, (16, len(law.constants._fields)))
        v = rng.uniform(-1.0, 1.0, (16, len(names)))
        want = np.array([m.force.py_func(slots, k[i], v[i], np.zeros(laws.MEMORY)) for i in range(16)])
        got = laws.law_forces(laws.KIND[law.name], slots, k, v, np.zeros((16, laws.MEMORY)), np.empty(16))
        np.testing.assert_allclose(got, want, rtol=1e-12, err_msg=law.name)
        assert POLICIES[law.name].law is law
    docs = (Path(__file__).resolve().parents[1] / "docs" / "baselines.md").read_text()
    assert laws.markdown_table() in docs, "docs/baselines.md: stale laws table (scripts/docs_tables.py)"


@pytest.mark.parametrize("spec,match", [
    ("thesis-rgi",
     "unknown policy 'thesis-rgi'; did you mean 'thesis-rig'.*valid: .*passive, .*thesis-ideal"),
    ("thesis-rig:h02x=1", r"unknown parameter\(s\) h02x.*valid: h01, h11"),
    ("thesis-rig:h01=-5", "h01 = -5.0 1/s\\^2 is out of range: must be finite and >= 0"),
    ("thesis-rig:h01=abc", "h01 must be a number"),
    ("thesis-rig:h01", "parameters are KEY=VALUE"),
    ("thesis-ideal:free_law=maybe", "free_law = 'maybe' is not one of corrected, printed"),
    ("", "non-empty"),
])
def test_registry_errors_name_the_valid_choices(spec, match):
    with pytest.raises(ConfigError, match=match):
        make_policy(spec, RIG)


def test_model_spec_errors():
    with pytest.raises(ConfigError, match="not found"):
        parse_model_spec("ppo:/nonexistent/agent.zip")
    with pytest.raises(ConfigError, match="must be one of observation=..., history=..., hold_ticks=..."):
        parse_model_spec("x.zip:colour=red")


@pytest.mark.parametrize("name", sorted(POLICIES))
def test_predict_shapes_dtype_and_action_limits(name):
    """Every baseline passes through the env's action limits: float64 actions in [-1, 1], single
    and batched, for wild observations too."""
    scene = IDEAL if name == "thesis-ideal" else RIG
    pol = make_policy(name, scene)
    lay = make_layout(scene, pol.observation)
    rng = np.random.default_rng(0)
    obs = rng.normal(0.0, 1.0, (64, lay.size)) * np.logspace(-3, 4, 64)[:, None]
    if "contact_detected" in lay.names:
        obs[:, lay.index("contact_detected")] = rng.integers(0, 2, 64)
    for _ in range(3):
        a, state = pol.predict(obs.astype(np.float32), episode_start=np.zeros(64, bool))
        assert a.shape == (64, 1) and a.dtype == np.float64
        assert np.all(np.isfinite(a)) and np.all(np.abs(a) <= 1.0)
    a1, _ = pol.predict(obs[0].astype(np.float32))
    assert a1.shape == (1,) and a1.dtype == np.float64 and abs(a1[0]) <= 1.0
    assert pol.observation in ("sensors", "privileged")


def test_predict_rejects_wrong_observation_size():
    pol = make_policy("thesis-rig", RIG)
    with pytest.raises(ValueError, match="observation has 3 entries"):
        pol.predict(np.zeros(3, np.float32))
    # a history-4 observation is accepted: the current frame comes first
    k = make_layout(RIG, "sensors", 4).size
    pol.predict(np.zeros(k, np.float32))


def test_passive_is_zero():
    a, state = make_policy("passive", RIG).predict(np.ones((5, 4), np.float32))
    assert np.all(a == 0) and state is None


# -- the rig law on synthetic sensor frames ----------------------------------------------------------

def _sensor_obs(pol, a2, t, x2, det):
    lay = pol.layout
    v = np.zeros((len(a2), lay.frame_size))
    v[:, lay.index("accelerometer")] = a2
    v[:, lay.index("force")] = t
    v[:, lay.index("potentiometer")] = x2
    v[:, lay.index("contact_detected")] = det
    return v / lay.scales


def test_thesis_rig_law_on_known_readings():
    """eq 4.3 with the derivative corrected: Phi = m2' a2 + T, d = (Phi/c)^(2/3), d' from
    successive samples, active only where the detector reports contact."""
    pol = ThesisRig(RIG, h01=2.0e6, h11=50.0)
    p, mt, rate = RIG.plant, RIG.effects.sensors.force.top_mass, RIG.control_rate
    a2 = np.array([10.0, 10.0, 10.0])
    t1, t2 = np.array([20.0, 20.0, 20.0]), np.array([40.0, 40.0, 40.0])
    det = np.array([1.0, 1.0, 0.0])
    pol.predict(_sensor_obs(pol, a2, t1, 0.0, det), episode_start=np.ones(3, bool))
    a, state = pol.predict(_sensor_obs(pol, a2, t2, 0.0, det))
    phi1, phi2 = mt * 10 + 20, mt * 10 + 40
    d1, d2 = (phi1 / p.c) ** (2 / 3), (phi2 / p.c) ** (2 / 3)
    f = p.m2 * (phi2 * (p.m1 + p.m2) / (p.m1 * p.m2) - p.gravity - 50.0 * (d2 - d1) * rate - 2.0e6 * d2)
    want = np.clip(f / RIG.effects.command_scale, -1, 1)
    np.testing.assert_allclose(a[:2, 0], want, rtol=1e-5)
    assert a[2, 0] == 0.0  # no contact detected: no force
    np.testing.assert_allclose(state[:, 0], d2, rtol=1e-5)
    values = _sensor_obs(pol, a2, t2, 0.0, det)[:2] * pol.layout.scales
    np.testing.assert_allclose(pol.force(values, state[:2].copy()),
                               p.m2 * (phi2 * 11.0 - p.gravity - 2.0e6 * d2), rtol=1e-5)


def test_memory_in_state_equals_internal_memory_and_resets():
    pol_a, pol_b = ThesisRig(RIG), ThesisRig(RIG)
    rng = np.random.default_rng(1)
    frames = [_sensor_obs(pol_a, rng.normal(0, 50, 4), rng.normal(20, 20, 4), 0.0, np.ones(4))
              for _ in range(5)]
    state = None
    for k, obs in enumerate(frames):
        start = np.full(4, k == 0)
        a, state = pol_a.predict(obs, state=state, episode_start=start)
        b, _ = pol_b.predict(obs, episode_start=start)
        np.testing.assert_array_equal(a, b)
    # a reset row forgets its previous penetration: its rate term starts from zero
    fresh = ThesisRig(RIG)
    c, _ = fresh.predict(frames[-1], episode_start=np.ones(4, bool))
    d, _ = pol_b.predict(frames[-1], episode_start=np.array([True, False, False, False]))
    assert c[0, 0] == d[0, 0]


def test_sensor_laws_need_their_channels():
    scene = RIG.with_overrides({"effects.sensors.potentiometer.enabled": False})
    with pytest.raises(ConfigError, match="needs the 'potentiometer' channel"):
        ThesisRig(scene)
    with pytest.raises(ConfigError, match="needs the 'potentiometer' channel"):
        PDPenetration(scene)


def test_pd_penetration_law():
    pol = PDPenetration(RIG, kp=1e5, kd=100.0)
    a2, t = np.array([0.0, 0.0]), np.array([50.0, 50.0])
    pol.predict(_sensor_obs(pol, a2, t, 0.0, np.array([1.0, 0.0])), episode_start=np.ones(2, bool))
    a, _ = pol.predict(_sensor_obs(pol, a2, t, 0.0, np.array([1.0, 0.0])))
    d = (50.0 / RIG.plant.c) ** (2 / 3)
    np.testing.assert_allclose(a[0, 0], -RIG.plant.m2 * 1e5 * d / RIG.effects.command_scale, rtol=1e-5)
    assert a[1, 0] == 0.0


# -- the ideal law (thesis ch. 2-3) --------------------------------------------------------------------

def _run_ideal(scene, t_end, **gains):
    pol = ThesisIdeal(scene, **gains)
    tr = simulate(scene, controller=lambda t, y: float(pol.force_from_state(*y)), t_end=t_end,
                  record_rate=1e5)
    return pol, tr


def test_printed_eq_2_18_diverges_and_corrected_holds():
    """With a gap before the touch the out-of-contact law acts: the printed sign makes the
    tracking error grow (e'' = +h11 e' + h01 e) until the state leaves the finite range."""
    scene = IDEAL  # 1 ms of free fall before the touch
    with pytest.raises(SimulationDiverged):
        _run_ideal(scene, 0.02, free_law="printed")
    _pol, tr = _run_ideal(scene, 0.02)
    assert np.all(np.abs(tr.x2) < 0.01) and np.abs(tr.shaker_force).max() < 5e3


@pytest.mark.parametrize("pre_contact", [0.0, 1e-3])
def test_corrected_ideal_law_keeps_contact_and_tracks_eq_2_15(pre_contact):
    """Thesis sec 3.4: with the sec 3.3 gains the bodies stay in contact all the time; the
    tracking error e = y1 - d obeys e'' + h11 e' + h01 e = -(h12 y2' + h02 y2)/m2 (eq 2.15
    forced by the body-2 terms, eq 2.19), compared with scipy's lsim of that system."""
    scene = IDEAL.with_overrides({"initial.pre_contact_time": pre_contact})
    pol, tr = _run_ideal(scene, 0.03)
    after = tr.t > tr.t_first_contact + 1e-9
    assert len(tr.onsets()) == 1 and len(tr.separations()) == 0
    assert np.all(tr.contact[after]) and (tr.x1 - tr.x2)[after].min() > 0
    P = pol.params
    e, de = tr.x1 - tr.x2 - P["dref"], tr.v1 - tr.v2
    u = -(P["h12"] * tr.v2 + P["h02"] * tr.x2) / scene.plant.m2
    lti = signal.StateSpace([[0, 1], [-P["h01"], -P["h11"]]], [[0], [1]], [[1, 0]], [[0]])
    _, e_ref, _ = signal.lsim(lti, u, tr.t, X0=[e[0], de[0]])
    assert np.abs(e_ref - e).max() < 3e-3 * np.abs(e).max()


def test_tracking_error_is_the_closed_form_second_order_decay():
    """h12 = h02 = 0: eq 2.15 exactly, e(t) = exp(-a t)(e0 cos wt + (de0 + a e0)/w sin wt)."""
    pol, tr = _run_ideal(IDEAL.with_overrides({"initial.pre_contact_time": 0.0}), 0.01, h12=0.0, h02=0.0)
    h01, h11 = pol.params["h01"], pol.params["h11"]
    e = tr.x1 - tr.x2 - pol.params["dref"]
    e0, de0 = e[0], tr.v1[0] - tr.v2[0]
    a, w = h11 / 2, np.sqrt(h01 - h11**2 / 4)
    ref = np.exp(-a * tr.t) * (e0 * np.cos(w * tr.t) + (de0 + a * e0) / w * np.sin(w * tr.t))
    assert np.abs(ref - e).max() < 3e-3 * np.abs(e).max()


def test_ideal_predict_matches_force_from_state():
    pol = ThesisIdeal(IDEAL.with_overrides({"effects.command_scale": 5000.0}))
    y = np.array([[1e-4, 0.5, 2e-5, 0.1], [-1e-3, 1.0, 0.0, 0.0]])
    a, _ = pol.predict(y / pol.layout.scales)
    np.testing.assert_allclose(a[:, 0] * 5000.0, pol.force_from_state(*y.T), rtol=1e-6)
