"""Simulation: a scene turned into arrays (:mod:`~impact_env.hardware.arrays`), one headless drop
(:func:`~impact_env.sim.drop.simulate` -> :class:`~impact_env.sim.trajectory.Trajectory`), and
batches of rigs stepped one control period at a time (:class:`~impact_env.sim.simulator.Simulator`)."""
