"""Columns of the per-tick records a simulator step writes (float64[N, hold_ticks, N_REC]).

One row per control tick of the step, after the tick (SI units; booleans as 0/1):
``t`` (s since the episode start), the true state ``x1, v1, x2, v2`` (m, m/s; thesis frame,
x down), ``u`` (the drive command held over the tick, 1 = the scene's command scale),
``f_demand`` / ``f_applied`` (N: the demand and the force reaching body 2 after shaker and
saturation), ``saturated``, ``contact_force`` (N, true, at the end of the tick), ``detected``
(the front end's contact detector) and ``status`` (0 while the plant is finite and its kernel
reported no failure; once not, it stays so for the rest of the step, whose ticks are not run).
The task (reward, termination) and the episode metrics read them; they are what a tick log of
the rig holds, plus the true state.
"""

REC_T, REC_X1, REC_V1, REC_X2, REC_V2, REC_U, REC_F_DEMAND, REC_F_APPLIED, REC_SATURATED, \
    REC_CONTACT_FORCE, REC_DETECTED, REC_STATUS = range(12)
N_REC = 12
