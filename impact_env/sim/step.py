"""The simulator's compiled step: for every active env, ``hold`` ticks of the hardware stage
under the held command, each followed by the front end's conditioning; then, unless the plant
failed, the observation.  One call per step for the whole batch.

The order inside a tick is the rig's: the command for the tick is the policy's held action,
plus, with a residual law, that law's command from the readings of the tick before (its own
observation frame, rebuilt every tick), clipped to [-1, 1]; the hardware
(:func:`impact_env.hardware.stage.hardware_tick`) produces the raw readings; the controller's
front end (:func:`impact_env.control.front_end.condition`) filters them and runs the detector.
At the end of the step the front end writes the policy's observation
(:func:`~impact_env.control.front_end.observe`).  Every tick leaves a record
(:mod:`impact_env.sim.records`).

``law`` = (on, pi, pf, mem float64[N, m], ob): the residual law's packed policy
(:func:`impact_env.control.policy.act`), memory and observation buffers; ``on`` false: none.
"""

from __future__ import annotations

from impact_env._jit import jit
from impact_env.control.front_end import condition, observe
from impact_env.control.policy import act
from impact_env.hardware.stage import (
    INFO_CONTACT_FORCE,
    INFO_F_APPLIED,
    INFO_F_DEMAND,
    INFO_SATURATED,
    hardware_tick,
    state_ok,
)
from impact_env.sim import records as R


@jit(inline="always")
def env_step(i, a, hold, hw, fe, ob, law, records):
    """Env i: ``hold`` ticks under the action ``a`` (and the residual law), then its
    observation.  Returns False if the plant failed (its observation is then left as it was)."""
    cfg, plant, fx, noise, out = hw
    Y = plant[0]
    t = plant[7]
    info = out[1]
    detected = fe[6]
    law_on, law_pi, law_pf, law_mem, law_ob = law
    ok = True
    u = a
    for k in range(hold):
        if ok:
            if law_on:
                u = a + act(law_pi, law_pf, law_ob[7][i], law_mem[i])
                u = -1.0 if u < -1.0 else (1.0 if u > 1.0 else u)
            hardware_tick(i, u, cfg, plant, fx, noise, out)
            condition(i, out[0], fe)
            ok = state_ok(i, plant, info)
            if ok and law_on:
                observe(i, False, 0.0, Y[i], fe, law_ob)
        r = records[i, k]
        r[R.REC_T] = t[i]
        for j in range(4):
            r[R.REC_X1 + j] = Y[i, j]
        r[R.REC_U] = u
        r[R.REC_F_DEMAND] = info[i, INFO_F_DEMAND]
        r[R.REC_F_APPLIED] = info[i, INFO_F_APPLIED]
        r[R.REC_SATURATED] = info[i, INFO_SATURATED]
        r[R.REC_CONTACT_FORCE] = info[i, INFO_CONTACT_FORCE]
        r[R.REC_DETECTED] = detected[i]
        r[R.REC_STATUS] = 0.0 if ok else 1.0
    if ok:
        observe(i, True, a, Y[i], fe, ob)
    return ok


@jit
def sim_step(actions, active, hold, hw, fe, ob, law, records):
    """:func:`env_step` for every env i with ``active[i]`` under ``actions[i]``."""
    for i in range(actions.shape[0]):
        if active[i]:
            env_step(i, actions[i], hold, hw, fe, ob, law, records)
