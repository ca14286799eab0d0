"""The controller side of the rig: the compiled code that runs on the real-time target, and in the
simulator exactly as on the target.

:mod:`~impact_env.control.observation` (what a policy sees: layout, units, scales),
:mod:`~impact_env.control.front_end` (filters, contact detector, observation frame).  Its
boundary to the hardware (:mod:`impact_env.hardware`) is the raw readings one way and the drive
command the other.
"""
