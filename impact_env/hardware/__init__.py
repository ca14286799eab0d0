"""The hardware side of the rig: what happens between the drive command leaving the controller and
the raw sensor readings coming back (actuator delay, shaker, amplifier limit, plant, sensors with
their ADC, sensor delay).

:mod:`~impact_env.hardware.stage` holds the compiled stage (one tick of one env),
:mod:`~impact_env.hardware.batch` the arrays of N rigs of a scene (:class:`Hardware`), and
:mod:`~impact_env.hardware.blocks` the packing of per-env rows.  The boundary to the controller
(:mod:`impact_env.control`) is the raw readings (float64[4]: accelerometer m/s^2, force
transducer N, potentiometer m, body-1 sensor m) one way and the drive command (1 = the scene's
``effects.command_scale`` newtons upwards) the other: on the physical rig that boundary is the
DAQ card.
"""
