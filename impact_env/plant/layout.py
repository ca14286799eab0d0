"""Index layout of the plant's state and parameter arrays: named positions (numba freezes them as constants).

Frame (the thesis's, section 2.3): x points **downwards**; positions are those of the facing
surfaces, with body 2's surface at x = 0 when body 2 is at rest, so the penetration is
``d = x1 - x2`` (m) and contact needs ``d > 0``.  The shaker force f2 (N) acts on body 2 and is
positive **upwards**, i.e. towards body 1 (eq 2.7b: ``m2 x2'' = Phi - f2``).
"""

from typing import NamedTuple

from impact_env._packed import positions


class StateSlots(NamedTuple):
    """The entries of a state vector y (float64[N_STATE])."""

    x1: float  # body 1 position, m (down positive)
    v1: float  # body 1 velocity, m/s
    x2: float  # body 2 position, m
    v2: float  # body 2 velocity, m/s
    w_ext: float  # work done on the system by the shaker force since t0, J
    w_diss: float  # energy dissipated (pad damping, suspension damping) since t0, J


class ParamSlots(NamedTuple):
    """The entries of a plant parameter vector p (float64[N_PARAM])."""

    m1: float  # kg
    m2: float  # kg
    c: float  # Hertz stiffness, N/m^1.5
    b: float  # Tsuji damping coefficient, N s/m^1.25 (0: elastic Hertz)
    g: float  # gravity on body 1, m/s^2
    k2: float  # suspension stiffness of body 2, N/m
    c2: float  # suspension damping of body 2, N s/m


#: positions by name (impact_env._packed): ``y[STATE.x1]``, ``p[PARAM.c]``
STATE = positions(StateSlots)
PARAM = positions(ParamSlots)
N_STATE = len(STATE)
N_PARAM = len(PARAM)
# the same positions as plain ints, for the kernels that still read them so (plant/integrators.py,
# plant/free_flight.py, sim/metrics.py, eval/, rig/, deploy/): the names above are the convention
X1, V1, X2, V2, W_EXT, W_DISS = STATE
M1, M2, C, B, G, K2, C2 = PARAM

# contact modes
FREE = 0  # event-located integration, no contact force
CONTACT = 1  # event-located integration, contact force (smoothly extended past d = 0)
AUTO = 2  # no event location: the force switches inside the right-hand side (thesis style)

# methods
EULER = 0
SYMPLECTIC_EULER = 1
RK4 = 2
DOPRI5 = 3
SPLIT = 4  # exact free flight, dopri5 in contact (impact_env.plant.free_flight)

# kernel status codes
OK = 0
DIVERGED = 1
STEP_UNDERFLOW = 2
EVENT_OVERFLOW = 3



class EventSlots(NamedTuple):
    """The columns of the plant's event log (float64[E, N_EVENT_COLS]): one row per contact event."""

    t: float  # the event's time, s
    kind: float  # +1 onset, -1 separation
    x1: float  # the state at the event: body 1 position, m
    v1: float  # body 1 velocity, m/s
    x2: float  # body 2 position, m
    v2: float  # body 2 velocity, m/s


EVENT = positions(EventSlots)
N_EVENT_COLS = len(EVENT)
