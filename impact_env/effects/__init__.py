"""Effects: what stands between the policy and the plant on the rig.

One signal path, run once per control period (default rate on the rig: 10 kHz), in the order
of its code (the hardware stage's ``hardware_tick``, then the controller's front end's
``condition``; ``tests/test_signal_path.py`` holds this text to it)::

    action -> command scaling -> actuator delay -> shaker -> saturation -> plant
           -> sensors (gain, offset, noise, ADC quantisation) -> sensor delay   (the hardware: raw readings)
           -> filters -> detector -> observation                              (the controller)

Each effect is a small module with

* a frozen config dataclass (SI fields with ``unit``/``doc`` metadata, validated at construction;
  errors name the field as ``effects.<name>.<field>``),
* Python functions that turn the config into plain float64 parameter arrays and build/reset the
  effect's explicit state (float64 arrays, updated in place: nothing hidden, everything savable),
* numba kernels (``impact_env._jit.jit``, compiled lazily) that take plain arrays and floats,
  update the state in place and return the output.

Modules:

* :mod:`impact_env.effects.shaker`: amplifier + exciter response (force demand -> force).
* :mod:`impact_env.effects.saturation`: peak limit, RMS (thermal) budget, slew-rate limit.
* :mod:`impact_env.effects.sensors`: accelerometer, force transducer, potentiometer, optional
  body-1 displacement sensor: gain, offset, Gaussian noise, ADC quantisation and clipping.
* :mod:`impact_env.effects.filters`: per-channel Butterworth band-/low-pass (SOS, TDF-II).
* :mod:`impact_env.effects.delay`: transport delay lines (sensor path and actuator path),
  delays in seconds turned into whole control periods by a stated rule.
* :mod:`impact_env.effects.detector`: contact detection from the sensors (thesis eq 4.4) and
  a scorer of a detector's output against the true contact.

Randomness: no kernel draws random numbers.  The caller draws standard normals from a numpy
``Generator`` and passes them in, so a seed fixes every noise sample, whatever the compiler does.

Nothing is imported here: ``import impact_env.effects.<module>`` loads only what is used
(the filter module imports scipy.signal on first design).
"""
