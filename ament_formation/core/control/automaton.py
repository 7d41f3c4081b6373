"""Per-robot switching automaton (spec S8): entry, re-targeting and exit tests, dwell, T_min,
cool-down and the emergency ellipse, plus the rotation-direction choice (S6.6) and the parking
factor (S6.5) that the automaton needs when it switches.

Modes (one int per robot): ``MODE_C`` coordination, ``MODE_OBSTACLE`` A(j) for obstacle j,
``MODE_YIELD`` A(k, yield) for robot k, ``MODE_MUTUAL`` A(k, mutual). Robot-robot arbitration
(S7) is in :mod:`ament_formation.core.control.encounters`; both are evaluated at the decision rate
by
:func:`ament_formation.core.control.encounters.decide`, which the simulator and the per-robot
:class:`ament_formation.core.control.controller.RobotController` call alike.

Everything here is scalar numba code (``@njit(cache=True)``) so the closed loop can run it for
N = 1000 robots; the functions are also plain callables from Python.

Departures from the letter of S8, each motivated by S14:

* S14.2 -- the heading test uses the velocity of the robot relative to the *material point* of the
  obstacle under the robot, ``z_dot_rel = p_dot - (c_dot + phi_dot J z)``, so a rotating bar that
  sweeps toward a robot is seen (for static, non-rotating obstacles this is the S8 test exactly);
  ``dh/dt = grad h . z_dot_rel`` is then the exact total derivative (S6.3(b)).
* S14.2 -- besides the emergency ellipse E, an *imminent* contact (inside Q, approaching, the ray
  along z_dot_rel reaches P within ``imminent_s``) is an emergency too: the margin scales with the
  boundary speed instead of the fixed rho_em.
* S14.2 -- an emergency may not replace a current target that is itself in emergency (no
  flip-flopping between two emergency zones every step).
"""

from __future__ import annotations

from collections import namedtuple
import dataclasses
from dataclasses import dataclass
import math

from numba import njit
import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.model.ellipse import ellipse_coords, h_value, ray_time, segment_hits
from ament_formation.core.params import AvoidanceParams

MODE_C = 0
MODE_OBSTACLE = 1
MODE_YIELD = 2
MODE_MUTUAL = 3
MODE_NAMES = ('coordination', 'obstacle', 'yield', 'mutual')

INF = math.inf


@dataclass(frozen=True)
class SwitchingParams:
    """Timing and thresholds of the automaton and the encounter rules (S6.1, S7, S8, S14).

    Built from :class:`AvoidanceParams` plus the additions of this project (all documented
    at their use).
    """

    avoidance: AvoidanceParams = AvoidanceParams()
    decision_period_s: float = 0.01  # automaton/encounter evaluation period (100 Hz)
    imminent_s: float = 1.5  # S14.2: ray reaches P within this time -> emergency
    agent_horizon_s: float = 12.0  # S14.3: agent threat only if contact with I within this
    teammate_rel_speed_mps: float = 0.02  # S14.3: teammates moving together below this: no threat
    # S14.3 hysteresis: ... up to this when the pair was released from an encounter with each other
    teammate_release_speed_mps: float = 0.04
    mutual_drift_tau_s: float = 2.0  # S14.1: w_c relaxes toward the pair's mean V_c
    mutual_drift_cap_mps: float = 0.05  # |w_c target| cap
    speed_limit_mps: float = 0.25  # below S2.3 v_max (0.3): V_d and velocity feed-forwards clipped
    brake_gain_fraction: float = 0.4  # safety barrier: braking deceleration = this x K
    safety_gap_m: float = 0.01  # safety barrier: the robot stops this far outside P / contact
    safety_range_m: float = 0.3  # safety barrier: threats within this gap are checked
    safety_lag_s: float = 0.3  # safety barrier: reaction time of the S3 loop before it brakes
    # safety barrier: the floor's edges (x_min, x_max, y_min, y_max) [m] as walls; None: unbounded
    floor_m: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        for name in ('decision_period_s', *COMPILED_OWN_FIELDS):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f'must be a finite number > 0 (got {value!r})', name)
        if self.teammate_release_speed_mps < self.teammate_rel_speed_mps:
            raise ConfigError(
                f'must be >= teammate_rel_speed_mps ({self.teammate_rel_speed_mps}) '
                f'(got {self.teammate_release_speed_mps!r})',
                'teammate_release_speed_mps',
            )

    def for_avoidance(self, avoidance: AvoidanceParams) -> 'SwitchingParams':
        """These timings and thresholds with ``avoidance`` (a scenario's) in place of our own."""
        return dataclasses.replace(self, avoidance=avoidance)

    def on_floor(self, floor) -> 'SwitchingParams':
        """These parameters with the walls of ``floor`` (a scenario's :class:`FloorSpec`, with
        ``x_m`` and ``y_m`` pairs; None: no walls).
        """
        if floor is None:
            return dataclasses.replace(self, floor_m=None)
        bounds = (*map(float, floor.x_m), *map(float, floor.y_m))
        return dataclasses.replace(self, floor_m=bounds)

    def compiled(self) -> 'Switching':
        """These parameters as the compiled code reads them (:data:`Switching`)."""
        values = {**dataclasses.asdict(self.avoidance), **dataclasses.asdict(self)}
        floor = self.floor_m or (-math.inf, math.inf, -math.inf, math.inf)
        values.update(zip(FLOOR_FIELDS, floor))
        values['deferring_row'] = -1.0  # set per decision by RobotController (section 23)
        return Switching(**{name: float(values[name]) for name in Switching._fields})


# SwitchingParams' own numbers that the compiled code reads (each finite and > 0)
COMPILED_OWN_FIELDS = (
    'imminent_s',
    'agent_horizon_s',
    'teammate_rel_speed_mps',
    'teammate_release_speed_mps',
    'mutual_drift_tau_s',
    'mutual_drift_cap_mps',
    'speed_limit_mps',
    'brake_gain_fraction',
    'safety_gap_m',
    'safety_range_m',
    'safety_lag_s',
)
FLOOR_FIELDS = ('floor_x_min_m', 'floor_x_max_m', 'floor_y_min_m', 'floor_y_max_m')


Switching = namedtuple(
    'Switching',
    [f.name for f in dataclasses.fields(AvoidanceParams)]
    + [*COMPILED_OWN_FIELDS, *FLOOR_FIELDS, 'deferring_row'],
)
Switching.__doc__ = """:class:`SwitchingParams` for the compiled code: a named tuple of floats
(numba reads a field as fast as an array slot), fields named and in the units of
:class:`~ament_formation.core.params.AvoidanceParams` and :class:`SwitchingParams` (all but
``decision_period_s``, which only the Python drivers read; ``floor_m`` is the four
``floor_*_m`` fields, infinite when no floor is declared; ``deferring_row``: the row of a robot
that takes robot encounters other than emergencies only from the coordinator, -1 none,
docs/law-changes.md §23). Built by :meth:`SwitchingParams.compiled`.
"""


# --------------------------------------------------------------------------- ellipse geometry


@njit(cache=True)
def relative_velocity(zx, zy, vx, vy, cvx, cvy, phi_dot):
    """S14.2: robot velocity relative to the obstacle's material point at z,
    p_dot - (c_dot + phi_dot J z).
    """
    return vx - cvx + phi_dot * zy, vy - cvy - phi_dot * zx


@njit(cache=True)
def h_dot_sign_value(zx, zy, rvx, rvy, phi, r1, r2):
    """dh/dt (up to the positive factor of the scale) = grad h . z_dot_rel (S6.4, S6.3(b))."""
    u, w = ellipse_coords(zx, zy, phi, r1, r2)
    du, dw = ellipse_coords(rvx, rvy, phi, r1, r2)
    return 2.0 * (u * du + w * dw)


@njit(cache=True)
def threat_test(zx, zy, rvx, rvy, phi, r1, r2, prm):
    """S8.1 entry test for one target (ellipse r1, r2 = P) seen from z with relative velocity rv.

    Returns (triggered, emergency, lam_in, h_em, h_l): ``triggered`` = inside Q, the ray meets I
    and
    dh/dt < 0 (cool-down is the caller's business); ``emergency`` = inside E, or (S14.2) inside Q
    and approaching with the ray reaching P within ``imminent_s``.
    """
    return threat_test_q(zx, zy, rvx, rvy, phi, r1, r2, prm.protected_scale, prm)


@njit(cache=True)
def threat_test_q(zx, zy, rvx, rvy, phi, r1, r2, q_scale, prm):
    """:func:`threat_test` with the protected region Q = ``q_scale`` P (a teammate's, §22)."""
    hdot = h_dot_sign_value(zx, zy, rvx, rvy, phi, r1, r2)
    h_em = h_value(zx, zy, phi, prm.emergency_scale * r1, prm.emergency_scale * r2)
    h_q = h_value(zx, zy, phi, q_scale * r1, q_scale * r2)
    h_l = h_value(zx, zy, phi, prm.limit_cycle_scale * r1, prm.limit_cycle_scale * r2)
    lam_in = INF
    triggered = False
    emergency = h_em < 0.0
    if h_q < 0.0 and hdot < 0.0:
        lam_in = ray_time(zx, zy, rvx, rvy, phi, prm.heading_scale * r1, prm.heading_scale * r2)
        triggered = lam_in < INF
        if not emergency:
            lam_p = ray_time(zx, zy, rvx, rvy, phi, r1, r2)
            emergency = lam_p < prm.imminent_s
    return triggered, emergency, lam_in, h_em, h_l


@njit(cache=True)
def exit_conditions(px, py, gx, gy, vcx, vcy, cx, cy, cvx, cvy, phi, phi_dot, r1, r2, prm):
    """S8.3 items 1-3 for one target P (centre c, velocity c_dot, orientation phi).

    1. the segment [p, g] misses C = rho_clr P; 2. h_em >= 0; 3. the coordination field V_c the
    robot would switch to does not pass the heading test against I (relative to the material
    point, S14.2).
    """
    zx = px - cx
    zy = py - cy
    if segment_hits(
        px, py, gx, gy, cx, cy, phi, prm.clearance_scale * r1, prm.clearance_scale * r2
    ):
        return False
    if h_value(zx, zy, phi, prm.emergency_scale * r1, prm.emergency_scale * r2) < 0.0:
        return False
    rvx, rvy = relative_velocity(zx, zy, vcx, vcy, cvx, cvy, phi_dot)
    if h_dot_sign_value(zx, zy, rvx, rvy, phi, r1, r2) >= 0.0:
        return True
    return ray_time(zx, zy, rvx, rvy, phi, prm.heading_scale * r1, prm.heading_scale * r2) == INF


@njit(cache=True)
def exit_timer(conditions_hold, t_s, since_s, t_entry_s, prm):
    """S8.3 item 4: returns (exit_now, new_since_s). ``since_s`` < 0 means "not holding"."""
    if not conditions_hold:
        return False, -1.0
    if since_s < 0.0:
        since_s = t_s
    ok = (t_s - since_s >= prm.dwell_s - 1e-9) and (t_s - t_entry_s >= prm.min_avoid_s - 1e-9)
    return ok, since_s


@njit(cache=True)
def in_cooldown(kind, target, t_s, last_kind, last_target, last_exit_s, prm):
    """S8.4: heading-triggered re-entry to the target just left is blocked for T_cool."""
    return kind == last_kind and target == last_target and t_s - last_exit_s < prm.cooldown_s


AutomatonArrays = namedtuple(
    'AutomatonArrays',
    [
        'mode',
        'tgt',
        'sdir',
        't_entry',
        'since',
        'last_kind',
        'last_tgt',
        'last_exit',
        'wc',
        'wtgt',
        'sweep_s',
    ],
)
AutomatonArrays.__doc__ = """The automaton state of N robots as the compiled code takes it (the
arrays of :class:`AutomatonState`, updated in place; see there for their meaning and units).
"""


RobotMode = namedtuple(
    'RobotMode', ['mode', 'target', 'direction', 't_entry_s', 'drift', 'drift_target']
)
RobotMode.__doc__ = """Row i of :data:`AutomatonArrays` as scalars (what the law of robot i reads):
``mode`` (MODE_*), ``target`` (obstacle index or robot row), ``direction`` (+1 CCW, -1 CW),
``t_entry_s`` [s], ``drift`` and ``drift_target`` (2-tuples, [m/s]) the mutual-pair w_c and its
target.
"""


@njit(cache=True)
def robot_mode_k(auto, i):
    """:data:`RobotMode` of robot row i of ``auto`` (:data:`AutomatonArrays`)."""
    wc, wtgt = auto.wc, auto.wtgt
    return RobotMode(
        auto.mode[i],
        auto.tgt[i],
        auto.sdir[i],
        auto.t_entry[i],
        (wc[i, 0], wc[i, 1]),
        (wtgt[i, 0], wtgt[i, 1]),
    )


class AutomatonState:
    """The automaton state of N robots as the arrays the compiled code updates in place.

    Attributes (all (N,) unless stated): ``mode`` int (MODE_*), ``tgt`` int (obstacle index or
    robot row, -1 in coordination), ``sdir`` float (+1 CCW, -1 CW), ``t_entry`` [s], ``since`` [s]
    (start of the S8.3 dwell window, < 0 when the exit conditions do not hold), ``last_kind`` /
    ``last_tgt`` / ``last_exit`` (the cool-down record: 1 obstacle, 2 robot), ``wc`` and ``wtgt``
    (N, 2) [m/s] mutual-pair drift and its target, ``sweep_s`` [s] the time a sweep round static
    obstacles had spent on the obstacles before the current one (0 otherwise: liveness only,
    docs/law-changes.md §26).
    """

    def __init__(self, n: int):
        self.mode = np.zeros(n, dtype=np.int64)
        self.tgt = np.full(n, -1, dtype=np.int64)
        self.sdir = np.ones(n)
        self.t_entry = np.zeros(n)
        self.since = np.full(n, -1.0)
        self.last_kind = np.zeros(n, dtype=np.int64)
        self.last_tgt = np.full(n, -1, dtype=np.int64)
        self.last_exit = np.full(n, -1e9)
        self.wc = np.zeros((n, 2))
        self.wtgt = np.zeros((n, 2))
        self.sweep_s = np.zeros(n)

    @property
    def n(self) -> int:
        return int(self.mode.shape[0])

    def arrays(self) -> AutomatonArrays:
        """The state itself (no copies) as :data:`AutomatonArrays`."""
        return AutomatonArrays(
            self.mode,
            self.tgt,
            self.sdir,
            self.t_entry,
            self.since,
            self.last_kind,
            self.last_tgt,
            self.last_exit,
            self.wc,
            self.wtgt,
            self.sweep_s,
        )

    def set_mode(self, i: int, mode: int, target: int, direction: float, t_entry_s: float) -> None:
        """Put robot row ``i`` into ``mode`` toward ``target`` (for tests and for a coordinator's
        encounter assignment).
        """
        self.mode[i] = mode
        self.tgt[i] = target
        self.sdir[i] = direction
        self.t_entry[i] = t_entry_s
        self.since[i] = -1.0
        self.sweep_s[i] = 0.0
