"""Index layout of the plant's state and parameter arrays (plain ints, frozen by numba as constants).

Frame (the thesis's, section 2.3): x points **downwards**; positions are those of the facing
surfaces, with body 2's surface at x = 0 when body 2 is at rest, so the penetration is
``d = x1 - x2`` (m) and contact needs ``d > 0``.  The shaker force f2 (N) acts on body 2 and is
positive **upwards**, i.e. towards body 1 (eq 2.7b: ``m2 x2'' = Phi - f2``).
"""

# state vector y (float64[N_STATE])
X1 = 0  # body 1 position, m (down positive)
V1 = 1  # body 1 velocity, m/s
X2 = 2  # body 2 position, m
V2 = 3  # body 2 velocity, m/s
W_EXT = 4  # work done on the system by the shaker force since t0, J
W_DISS = 5  # energy dissipated (pad damping, suspension damping) since t0, J
N_STATE = 6

# parameter vector p (float64[N_PARAM])
M1 = 0  # kg
M2 = 1  # kg
C = 2  # Hertz stiffness, N/m^1.5
B = 3  # Tsuji damping coefficient, N s/m^1.25 (0: elastic Hertz)
G = 4  # gravity on body 1, m/s^2
K2 = 5  # suspension stiffness of body 2, N/m
C2 = 6  # suspension damping of body 2, N s/m
N_PARAM = 7

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

# event buffer columns: t, kind (+1 onset, -1 separation), x1, v1, x2, v2
N_EVENT_COLS = 6
