"""Preset scenes.  Each is documented field by field where it departs from the defaults."""

from __future__ import annotations

from impact_env.config import with_overrides
from impact_env.scene.scene import Scene


def ideal() -> Scene:
    """Thesis chapter 3: ideal conditions.  Elastic Hertz pad (sec 2.1: restitution 1), no
    suspension, no effects, the control law sampled at every integration step (1 us).

    * ``integrator.method`` = rk4 (dt 1 us): the law is sampled at every 1 us step, where the
      default ``split`` integrator (exact free flight) has nothing to gain: RK4 is cheaper there.
    * ``effects.command_scale`` = 2000 N: the ideal scene has no force limit (ch. 3), but an
      action in [-1, 1] needs a scale; the thesis's ideal law peaks at about 860 N (notes;
      ``docs/reproduction.md``: 848 N), so 2000 N leaves it unclipped with margin.
    """

    base = Scene(name="ideal", description="Thesis ch. 3: elastic Hertz contact, no suspension, "
                 "no effects, control at every 1 us integration step, 2000 N per unit action.")
    return with_overrides(base, {"effects.command_scale": 2000.0, "integrator.method": "rk4"})


PRESETS = {"ideal": ideal}


def rig() -> Scene:
    """Thesis chapter 4: the physical rig, every effect on, control at 10 kHz, 200 N pulses.

    Numbers the thesis does not give (see docs in each field and the README):
    * pad restitution 0.8 and a 16 Hz, 10 %-damped suspension of body 2 (k2 = 1e4 N/m,
      c2 = 20 N s/m): chosen so that the energy of an uncontrolled 50 mm drop dies out in the
      thesis's 0.30-0.35 s (sec 4.4): the system's energy above rest falls below 1 % of the
      impact energy at 0.338 s, after which body 1's catch energy stays below 1 % for good
      (``impact-env drop --scene rig --json``, ``time_to_1pct_energy_s``).  The thesis calls
      sylomer "quite damped" but gives no restitution; 0.8 is what the decay time asks for
      with this suspension.
    * horizon 0.4 s, so that the uncontrolled decay (about 0.34 s) is seen to its end.
    * control rate 10 kHz (notes' start value; dSPACE loops of the period ran at 10-20 kHz).
    * per-episode drops: ``randomize.m1`` 0.08-0.12 kg and ``randomize.drop_height`` 30-70 mm
      (uniform).  A benchmark of identical drops measures sensor noise only; the thesis's
      discussion (sec 5) wants a controller that "should be able to dampen the fall in many
      situations without any tuning": "many bodies could have dropped upon the controller",
      as long as they are not too heavy or dropped from too high for the shaker.  These ranges
      (+-20 % in mass, impact speeds 0.77-1.17 m/s around the nominal 0.99 m/s) raise the
      elastic peak contact force, which grows as (m v^2)^0.6, by at most 1.37x (to about
      120 N at the heavy, high corner), still inside the 200 N the shaker can answer with.
      The nominal drop (0.1 kg, 50 mm) is what ``impact-env drop``, ``scene show`` and the
      thesis reproduction use; ``rig-randomized`` adds the hardware's uncertainty on top.
    """

    base = Scene(name="rig", description="Thesis ch. 4: the shaker rig: pad restitution 0.8, "
                 "suspended body 2, shaker response, 200 N saturation, noisy 16-bit sensors, "
                 "20-1000 Hz filters, contact detector; control at 10 kHz; drops of 0.08-0.12 kg "
                 "from 30-70 mm (nominal 0.1 kg, 50 mm).")
    return with_overrides(base, {
        "plant.restitution": 0.8,
        "plant.suspension_stiffness": 1.0e4,
        "plant.suspension_damping": 20.0,
        "control.rate": 1.0e4,
        "episode.horizon": 0.4,
        "effects.active": ["shaker", "saturation", "sensors", "filters", "detector"],
        "randomize.m1": [0.08, 0.12],
        "randomize.drop_height": [0.03, 0.07],
    })


PRESETS["rig"] = rig


def rig_randomized() -> Scene:
    """``rig`` (whose drops already vary: m1 0.08-0.12 kg, drop height 30-70 mm, see :func:`rig`)
    with the hardware's uncertainty on top, for training agents that must work on a rig whose
    numbers are uncertain.  Every range is centred on (or starts at) the ``rig`` value; draws
    follow the seed policy of :mod:`impact_env.scene.randomize` (one uniform number per range, in
    field order, then the sensor noise).  Ranges and why:

    * ``m1`` 0.08-0.12 kg and ``drop_height`` 30-70 mm: as ``rig``.
    * ``c`` 1.5e6-2.5e6 N/m^1.5 (log-uniform, about +-25 %): the pad stiffness is one fit
      (thesis eq 4.1-4.2) of a sylomer pad, whose stiffness moves with preload, temperature and
      wear.
    * ``restitution`` 0.7-0.9 (uniform): the rig's 0.8 is calibrated, not measured (see ``rig``).
    * ``suspension_stiffness`` 0.8e4-1.2e4 N/m and ``suspension_damping`` 10-30 N s/m (uniform):
      the shaker's suspension is not in the thesis; +-20 % and +-50 % around the calibrated values
      (13-19 Hz, 5-15 % damping).
    * ``noise_scale`` 0.5-2 (log-uniform): every sensor noise level is an assumption; a factor
      of two either way.
    * ``command_gain`` 0.9-1.1 (uniform): amplifier gain and force factor Bl (which varies with
      the coil's position and temperature) known to about 10 %.
    * ``shaker_lowpass_hz`` 6-12 kHz (log-uniform) around the V406's 9 kHz band edge, and
      ``shaker_coil_inductance`` 30-80 uH (log-uniform; electrical pole 2.0-5.3 kHz) around the
      assumed 50 uH: the exciter's parameters are not identified.
    * ``sensor_delay_s`` 0-0.2 ms (0-2 control periods) and ``actuator_delay_s`` 0-0.1 ms
      (0-1 period): converter, bus and computation latency, which the thesis does not quantify;
      the ``rig`` has none, so both delay effects are switched on here with a nominal 0 s.
    """

    base = rig()
    return with_overrides(base, {
        "name": "rig-randomized",
        "description": "rig (drops of 0.08-0.12 kg from 30-70 mm) with per-episode ranges on c, pad "
                       "restitution, suspension, noise levels, shaker gain and response, and delays too.",
        "effects.active": list(base.effects.active) + ["sensor_delay", "actuator_delay"],
        "randomize.m1": [0.08, 0.12],
        "randomize.drop_height": [0.03, 0.07],
        "randomize.c": [1.5e6, 2.5e6],
        "randomize.restitution": [0.7, 0.9],
        "randomize.suspension_stiffness": [0.8e4, 1.2e4],
        "randomize.suspension_damping": [10.0, 30.0],
        "randomize.noise_scale": [0.5, 2.0],
        "randomize.command_gain": [0.9, 1.1],
        "randomize.shaker_lowpass_hz": [6000.0, 12000.0],
        "randomize.shaker_coil_inductance": [30e-6, 80e-6],
        "randomize.sensor_delay_s": [0.0, 2e-4],
        "randomize.actuator_delay_s": [0.0, 1e-4],
    })


PRESETS["rig-randomized"] = rig_randomized
