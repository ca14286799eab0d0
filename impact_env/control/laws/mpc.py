"""``mpc``: the sensor-fed model-based law: each tick the extended Kalman filter of
:mod:`impact_env.control.estimation` turns the frame's filtered readings (accelerometer, force
transducer, potentiometer) into an estimate of both bodies' states and body 1's mass, and the
controller acts on the estimate.

Controller (until the MPC solver of ``mpc-state`` is wired to the estimate): PD on the
estimated penetration, ``f2 = -m2 (kp d + kd d')`` while the estimate is in contact (d > 0),
0 otherwise, with ``pd-penetration``'s gains: the same law as that baseline, on the estimator's
d and d' (no filter delay, no static load removed, no differencing noise) instead of the
eq 4.4 estimate.

The estimator is part of the policy: its state and covariance live in the law's memory row, so
it runs wherever the law runs; its lost-track bit and count are there too
(:class:`impact_env.control.estimation.layout.EkfMemory`).
"""

from __future__ import annotations

from collections import namedtuple

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.control.estimation.ekf import ekf_measure, ekf_tick
from impact_env.control.estimation.layout import MEMORY, V1, V2, X1, X2, EkfConstants, EkfMemory
from impact_env.control.estimation.model import SETTINGS, ekf_constants
from impact_env.control.laws.estimate import SensorReads
from impact_env.control.laws.law import Law, Param

#: the EKF's constants, then the controller's
Constants = namedtuple("Constants", EkfConstants._fields + ("kp", "kd"))  # type: ignore[misc]
K = positions(Constants)
EM = EkfMemory

PARAMS = {
    "kp": Param(2.2e5, "1/s^2", "proportional gain on the estimated penetration, per kg of m2", lo=0.0),
    "kd": Param(320.0, "1/s", "derivative gain on the estimated penetration rate, per kg of m2", lo=0.0),
    "q_a1": Param(SETTINGS["q_a1"], "m/s^2", "estimator: white acceleration on body 1", lo=0.0),
    "q_a2": Param(SETTINGS["q_a2"], "m/s^2", "estimator: white acceleration on body 2", lo=0.0),
}


def constants_of(scene, P: dict) -> dict:
    k = ekf_constants(scene, {"q_a1": P["q_a1"], "q_a2": P["q_a2"]})
    k.update(kp=P["kp"], kd=P["kd"])
    return k


@jit(inline="always")
def force(slots, k, v, mem):
    frame = mem[EM.innov:EM.innov + 3]
    frame[0] = v[slots[0]]
    frame[1] = v[slots[1]]
    frame[2] = v[slots[2]]
    ekf_measure(k, mem, frame)
    x = mem[EM.x:EM.x + 4]
    d = x[X1] - x[X2]
    f = 0.0
    if d > 0.0:
        f = -k[K.m2] * (k[K.kp] * d + k[K.kd] * (x[V1] - x[V2]))
    ekf_tick(k, mem, frame, f)
    return f


LAW = Law("mpc", "sensors", "an extended Kalman filter on the scene's model (both bodies, m1, the "
          "shaker, the limit, the filters inverted) fed by the accelerometer, transducer and "
          "potentiometer; for now PD on its penetration estimate with pd-penetration's gains",
          SensorReads, Constants, constants_of, memory=MEMORY, params=PARAMS, c_body=None)
