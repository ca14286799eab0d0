"""Every field of every config section does something, or it would not be there.

For each leaf field of :class:`impact_env.scene.Scene` (except the two labels ``name`` and
``description``) the test changes the field, in a context that lets it act (an inverse filter's
roll-off needs the inverse filter on, and so on), and requires the env's first steps to change:
observations (sensors, detector bit and true state), rewards, ends and info, or a refusal where
the field is a check (``integrator.min_steps_per_contact``).  The rig's sensor plausibility check
(``effects.sensors.<channel>.max_step``, ``effects.sensors.fault_limit_s``) runs in the target's
tick and the C export, not in the env: its verdicts on fixed probe readings are part of the
fingerprint too, and so is the model the model-based laws plan on (``mpc-state``'s solver
constants: ``control.known_hardware`` acts there).  A field that nothing reads fails
here: ``effects.shaker.enabled`` did, and is gone.
"""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

import impact_env  # noqa: F401  (registers ImpactCatch-v0)
from impact_env.config import ConfigError
from impact_env.control import plausibility
from impact_env.scene import Scene, load_scene
from impact_env.scene.effects import EFFECTS

STEPS = 40  # 4 ms at 10 kHz: the touch comes after 1 ms
ALL_EFFECTS = list(EFFECTS)
BASE = {"effects.active": ALL_EFFECTS, "effects.sensors.body1_displacement.enabled": True,
        "effects.filters.body1_displacement.kind": "bandpass"}

# field -> (context overrides, new value); fields not listed get a default change (see _change)
SPECIAL = {
    "initial.impact_speed": ({}, 1.3),
    "integrator.method": ({}, "dopri5"),
    "integrator.rtol": ({}, 1e-4),
    "integrator.dt": ({"integrator.method": "rk4"}, None),  # (split, the default, has no fixed step)
    "integrator.event_location": ({"integrator.method": "rk4"}, None),
    "integrator.min_steps_per_contact": ({"integrator.method": "rk4"}, 1e4),  # a check: refuses this dt
    "episode.horizon": ({"episode.horizon": 2e-3}, 3e-3),
    "effects.active": ({}, ["sensors"]),
    "effects.shaker.model": ({"effects.shaker.fir_taps": [0.5, 0.5]}, "measured"),
    "effects.shaker.amplifier": ({}, "current"),
    "effects.shaker.force_factor": ({"effects.shaker.back_emf": True}, 10.0),
    "effects.shaker.fir_taps": ({"effects.shaker.model": "measured", "effects.shaker.fir_taps": [1.0]},
                                [0.5, 0.5]),
    "effects.shaker.inverse_rolloff_hz": ({"effects.shaker.inverse_filter": True}, 15000.0),
    "effects.filters.potentiometer.low_hz": ({"effects.filters.potentiometer.kind": "bandpass"}, 25.0),
    "effects.detector.threshold_n": ({}, 50.0),  # above the first impact's force pulse
    "effects.saturation.peak_n": ({}, 150.0),
    "effects.saturation.continuous_n": ({"effects.saturation.tau_s": 1e-3}, 50.0),
    "effects.saturation.tau_s": ({}, 1e-3),
    "effects.saturation.slew_n_per_s": ({}, 1e5),
    "effects.detector.derivative_threshold_n_per_s": ({"effects.detector.use_derivative": True}, 2e4),
    "effects.delay.sensor_s": ({}, 1e-4),
    "effects.delay.actuator_s": ({}, 1e-4),
    "randomize.m1": ({}, [0.09, 0.11]),  # (rig draws 0.08-0.12 kg and 30-70 mm already)
    "randomize.drop_height": ({}, [0.04, 0.06]),
    "randomize.impact_speed": ({"initial.impact_speed": 1.0}, [0.9, 1.1]),
    "randomize.c": ({}, [1.5e6, 2.5e6]),
    "randomize.restitution": ({}, [0.7, 0.9]),
    "randomize.suspension_stiffness": ({}, [0.8e4, 1.2e4]),
    "randomize.suspension_damping": ({}, [10.0, 30.0]),
    "randomize.noise_scale": ({}, [0.5, 2.0]),
    "randomize.command_gain": ({}, [0.9, 1.1]),
    "randomize.shaker_lowpass_hz": ({}, [6000.0, 12000.0]),
    "randomize.shaker_coil_inductance": ({}, [30e-6, 80e-6]),
    "randomize.sensor_delay_s": ({}, [0.0, 2e-4]),
    "randomize.actuator_delay_s": ({}, [0.0, 2e-4]),
    "randomize.m2": ({}, [0.8, 1.2]),
    "randomize.top_mass": ({}, [0.08, 0.12]),
    "control.known_hardware": ({"randomize.c": [2.4e6, 2.4e6]}, ["c"]),  # the measured pad, told
}
LABELS = ("name", "description")


def leaf_fields(cls=Scene, prefix=""):
    for f in dataclasses.fields(cls):
        key = f"{prefix}.{f.name}" if prefix else f.name
        sub = f.default_factory if f.default_factory is not dataclasses.MISSING else None
        if sub is not None and dataclasses.is_dataclass(sub):
            yield from leaf_fields(sub, key)
        else:
            yield key


def _get(scene, key):
    v = scene
    for part in key.split("."):
        v = getattr(v, part)
    return v


def _change(scene, key):
    """A valid new value for a field without an entry in SPECIAL."""
    v = _get(scene, key)
    if isinstance(v, bool):
        return not v
    if isinstance(v, int):
        return v + 1 if "adc_bits" not in key else 12
    if isinstance(v, float):
        return 1.25 * v if v != 0.0 else 1e-3
    if key.endswith(".kind"):
        return "lowpass" if v == "bandpass" else "bandpass"
    raise AssertionError(f"no default change for {key} = {v!r}: add it to SPECIAL")


def fingerprint(scene: Scene):
    """The env's first STEPS steps at a constant action (or the refusal's message)."""
    try:
        env = gym.make("ImpactCatch-v0", scene=scene, observation="both", terminate_on_catch=False)
    except ConfigError as exc:
        return ("refused", str(exc))
    obs, _ = env.reset(seed=3)
    rows = [obs]
    for _ in range(STEPS):
        obs, r, term, trunc, info = env.step(np.array([0.8], dtype=np.float32))
        rows.append(np.concatenate([obs, [r, term, trunc],
                                    [float(np.asarray(x).ravel()[0]) for x in info.values()
                                     if np.size(x) == 1 and np.asarray(x).dtype.kind in "biuf"]]))
        if term or trunc:
            break
    env.close()
    try:
        probe = _plausibility_probe(scene)
    except ConfigError as exc:
        return ("refused", str(exc))
    return ("ran", len(rows), np.concatenate([np.ravel(x) for x in rows] + [probe, _model_probe(scene)]))


def _model_probe(scene: Scene) -> np.ndarray:
    """The constants of ``mpc-state``'s model for ``scene`` (empty where the law refuses it)."""
    from impact_env.control.laws import mpc_state

    gains = {name: p.default for name, p in mpc_state.PARAMS.items()}
    gains["m1"] = scene.plant.m1
    try:
        return np.array(list(mpc_state.solver_constants(scene, gains).values()), dtype=np.float64)
    except ConfigError:
        return np.zeros(0)


def _plausibility_probe(scene: Scene) -> np.ndarray:
    """The sensor check's verdicts (:func:`impact_env.control.plausibility.check_readings`) on
    probe readings: on each channel a jump across 0 of each of a ladder of sizes 5 % apart (a
    largest step changed by 25 % moves the verdict of some rung), then a run of faulty ticks
    (the tick that latches SENSOR_TIMEOUT moves with the fault limit)."""
    p = plausibility.plausibility_params(scene)
    out = np.zeros(4)
    verdicts = []
    for c in range(4):
        for x in np.geomspace(1e-8, 1e4, 567):
            s = plausibility.reset_state(plausibility.make_state())
            raw = np.zeros(4)
            raw[c] = -0.5 * x  # a jump of x across 0: up to twice a converter's half range
            verdicts.append(plausibility.check_readings(0, raw, p, s, out))
            raw[c] = 0.5 * x
            verdicts.append(plausibility.check_readings(1, raw, p, s, out))
    s = plausibility.reset_state(plausibility.make_state())
    plausibility.check_readings(0, np.zeros(4), p, s, out)
    for m in range(1, 40):
        verdicts.append(plausibility.check_readings(m, np.array([np.nan, 0.0, 0.0, 0.0]), p, s, out))
    return np.asarray(verdicts, dtype=np.float64)


def same(a, b) -> bool:
    if a[0] != b[0] or a[1] != b[1]:
        return False
    return a[0] == "refused" or (a[2].shape == b[2].shape and np.array_equal(a[2], b[2]))


FIELDS = [k for k in leaf_fields() if k not in LABELS]


@pytest.mark.slow
@pytest.mark.parametrize("key", FIELDS)
def test_every_field_acts(key):
    context, new = SPECIAL.get(key, ({}, None))
    base = load_scene("rig", {**BASE, **context})
    if new is None:
        new = _change(base, key)
    changed = base.with_overrides({key: new})
    assert _get(changed, key) != _get(base, key), key
    assert not same(fingerprint(base), fingerprint(changed)), f"{key}: changing it to {new!r} changes nothing"


def test_the_shaker_has_no_enabled_switch():
    """``effects.shaker.enabled`` was never read (``effects.active`` decides): it is gone, and a
    file that still sets it fails naming the key."""
    with pytest.raises(ConfigError, match=r"unknown key 'effects.shaker.enabled'"):
        load_scene({"effects": {"shaker": {"enabled": True}}})


def test_a_scene_given_by_impact_speed_round_trips():
    """A scene given by ``initial.impact_speed`` writes no drop height; read back (TOML, or a
    second round of overrides) it must not get the default drop height as well (it used to
    fail with "give exactly one of drop_height or impact_speed")."""
    import tomllib

    from impact_env.scene.load import scene_from_dict

    s = load_scene("rig", {"initial.impact_speed": 1.2})
    assert scene_from_dict(tomllib.loads(s.to_toml())) == s
    t = s.with_overrides({"plant.m1": 0.09})
    assert t.initial.impact_speed == 1.2 and t.initial.drop_height is None
    assert load_scene("rig").initial.drop_height == 0.05
    with pytest.raises(ConfigError, match="got both"):
        load_scene({"initial": {"drop_height": 0.05, "impact_speed": 1.0}})
