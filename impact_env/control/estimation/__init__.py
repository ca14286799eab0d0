"""State estimation for the sensor-fed laws: an extended Kalman filter on the scene's own model
(:mod:`impact_env.control.estimation.model` builds its constants from a scene,
:mod:`impact_env.control.estimation.ekf` runs it, one tick per call, allocation-free)."""
