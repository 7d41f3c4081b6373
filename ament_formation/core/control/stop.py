"""The controlled stop (docs/design.md §7): what a robot's controller commands when its
inputs go stale (no camera pose for ``pose_timeout_s``, its parent's state lost): wheels to rest,
held there; and
when the camera-loss stop must begin so that the robot is at rest by ``pose_timeout_s``
(:class:`StopLead`, docs/safety.md §7).
"""

from __future__ import annotations

from collections import namedtuple
import math

from numba import njit
import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.model.dynamics import b2_inv, f2, PlantCoeffs
from ament_formation.core.params import ControlGains


def stop_torque(
    state: np.ndarray,
    k: PlantCoeffs,
    stop_time_s: float,
    gains: ControlGains,
    decel_mps2: float = 0.0,
    period_s: float = 0.01,
) -> np.ndarray:
    """Controlled stop (docs/design.md §7): torques (N, 2) that bring (v, omega) to rest and
    hold them there against the bounded disturbance g.

    A sliding-mode velocity regulator on sigma = x2 (S2.2: x2dot = f2 + B2 u + g):
    u = B2^-1 (-x2 / T - K sat(x2 / eps) - f2), with T = ``stop_time_s`` and the gains of
    :func:`stop_gains` (the formation law's K_p, or ``decel_mps2`` on v; boundary layers wide
    enough for the sampled loop at ``period_s``), so the residual speed is |g| / (1/T + K/eps):
    about 2 mm/s and 0.02 rad/s with the defaults, where a plain -x2/T brake would creep at g T.
    Uniformly scaled into the torque limit (S3.6).
    """
    u = _stop_law(state, k, stop_time_s, gains, decel_mps2, period_s)
    scale = np.maximum(1.0, np.max(np.abs(u), axis=1) / k.tau_max)
    return u / scale[:, None]


# The boundary layer of the stop law is at least STOP_LAYER_PERIODS * K * T_s (S3.5 asks
# eps >= K T_s). Inside it the law is linear with rate 1/T + K/eps, and the loop from a torque
# command to the wheel speeds it makes, back through the board's telemetry, the bridge and the
# estimator, is about 3.5 control periods long: in the twin the stop chattered (|omega| up to
# 0.15 rad/s, never at rest) at K/eps = 54 /s, i.e. eps = 1.85 K T_s, and settled from 3 K T_s
# (docs/safety.md §7). The formation law itself runs at eps_p = 3.7 K_p T_s.
STOP_LAYER_PERIODS = 5.0


def stop_gains(
    gains: ControlGains, decel_mps2: float = 0.0, period_s: float = 0.01
) -> tuple[tuple[float, float], tuple[float, float]]:
    """((K, eps) of v [m/s^2, m/s], (K, eps) of omega [rad/s^2, rad/s]) of the stop law for a
    robot with the formation law's ``gains`` (per unit of d: the omega pair is divided by d by
    the caller, as the formation law's point gains are).

    K: the formation law's K_p, on v raised to ``decel_mps2`` when that is larger (the camera-loss
    stop). eps: the formation law's eps_p / 2, or STOP_LAYER_PERIODS K ``period_s`` when that is
    wider (the sampled loop's stability, above).
    """
    k_p, half_eps = gains.switching_gain_mps2, 0.5 * gains.boundary_layer_mps
    k_v = max(k_p, decel_mps2)
    return (
        (k_v, max(half_eps, STOP_LAYER_PERIODS * k_v * period_s)),
        (k_p, max(half_eps, STOP_LAYER_PERIODS * k_p * period_s)),
    )


def _stop_law(
    state: np.ndarray,
    k: PlantCoeffs,
    stop_time_s: float,
    gains: ControlGains,
    decel_mps2: float = 0.0,
    period_s: float = 0.01,
):
    """The torques (N, 2) of :func:`stop_torque` before the scaling into the torque limit."""
    x2 = state[:, 3:5]
    (gain_v, eps_v), (gain_w, eps_w) = stop_gains(gains, decel_mps2, period_s)
    gain = np.stack((np.full_like(k.d, gain_v), gain_w / k.d), axis=-1)
    eps = np.stack((np.full_like(k.d, eps_v), eps_w / k.d), axis=-1)
    x2dot = -x2 / stop_time_s - gain * np.clip(x2 / eps, -1.0, 1.0) - f2(state, k)
    return np.einsum('nij,nj->ni', b2_inv(k), x2dot)


StopK = namedtuple('StopK', ['stop_time_s', 'gain_v', 'eps_v', 'g_v', 'rest_v', 'gain_w', 'eps_w',
                             'g_w', 'rest_w', 'margin_s', 'max_s', 'speed_max_mps',
                             'turn_rate_max_radps', 'hold_gain_v', 'hold_eps_v'])
StopK.__doc__ = """A :class:`StopLead` for the compiled code: the camera-loss stop law's gains
on v [m/s^2, m/s] and omega [rad/s^2, rad/s] (``gain_*``, ``eps_*``, the disturbance bound
``g_*`` and rest band ``rest_*``), its margin and cap [s], the speed bounds, and the v pair of
the hold-parent stop (the formation law's K and boundary layer, ``hold_*``; omega as above)."""


# The stop law closes its loop through the wheels' telemetry: the (v, omega) it brakes is that of
# the newest wheel sample, as old as that sample, and its command takes STOP_LOOP_LAG_S more to
# act (DDS, the bridge, the serial line, the board's 10 ms step). A loop of rate c (1/T + K/eps,
# 23.3 /s) delayed by tau is stable only for c tau < pi/2 and rings from about 1: integrated on the
# plant, the stop came to rest with the measurement up to 50 ms old, and not at all from 70 ms
# (|omega| swinging up to 0.35 rad/s at 70 ms, 1.1 rad/s at 150 ms) -- what a loaded robot
# computer or a stalled serial link give. So the rates are scaled by delay_scale_k: c tau is kept
# at most STOP_DELAY_MARGIN (docs/safety.md §7, "A late measurement"); with fresh samples (age up
# to 14 ms) nothing changes.
STOP_LOOP_LAG_S = 0.02
STOP_DELAY_MARGIN = 0.8


@njit(cache=True, error_model='numpy')
def delay_scale_k(stop_time_s, gain_v, eps_v, gain_w, eps_w, age_s):
    """Factor (0, 1] for the stop law's rates when its (v, omega) is ``age_s`` old."""
    rate = 1.0 / stop_time_s + max(gain_v / eps_v, gain_w / eps_w)
    loop = rate * (max(age_s, 0.0) + STOP_LOOP_LAG_S)
    return 1.0 if loop <= STOP_DELAY_MARGIN else STOP_DELAY_MARGIN / loop


@njit(cache=True, error_model='numpy')
def stop_torque_k(v, w, plant, tau_max, stop_time_s, gain_v, eps_v, gain_w, eps_w):
    """:func:`stop_torque` of one robot (its (v, omega), plant and gains per unit of its own
    components) -> (tau_left, tau_right).
    """
    mt, it, r, a, d, mc = plant
    vdot = -v / stop_time_s - gain_v * min(1.0, max(-1.0, v / eps_v)) - mc * d / mt * w * w
    wdot = -w / stop_time_s - gain_w * min(1.0, max(-1.0, w / eps_w)) + mc * d / it * w * v
    lin = 0.5 * r * mt * vdot
    ang = 0.5 * r * 2.0 * it / a * wdot
    t1, t2 = lin - ang, lin + ang
    scale = max(1.0, max(abs(t1), abs(t2)) / tau_max)
    return t1 / scale, t2 / scale


@njit(cache=True, error_model='numpy')
def band_time_k(y0, stop_time_s, gain, eps, g_bar, y_rest):
    """:func:`time_to_band` in the compiled code."""
    y = abs(y0)
    t = 0.0
    b = gain - g_bar
    if y > eps:
        t = stop_time_s * math.log((y + b * stop_time_s) / (eps + b * stop_time_s))
        y = eps
    rate = 1.0 / stop_time_s + gain / eps
    residual = g_bar / rate
    if y > y_rest:
        t += math.log((y - residual) / (y_rest - residual)) / rate
    return t


@njit(cache=True, error_model='numpy')
def lead_k(v, w, sk):
    """:meth:`StopLead.lead_s` in the compiled code (``sk`` :data:`StopK`)."""
    rest = max(band_time_k(v, sk.stop_time_s, sk.gain_v, sk.eps_v, sk.g_v, sk.rest_v),
               band_time_k(w, sk.stop_time_s, sk.gain_w, sk.eps_w, sk.g_w, sk.rest_w))
    return min(rest + sk.margin_s, sk.max_s)


REST_SPEED_MPS = 0.005  # at rest: both wheels' rim speeds |v -+ (a/2) omega| below this
# (docs/safety.md, bench/bench_stop.py REST_SPEED_MPS)


def time_to_band(
    y0: float, stop_time_s: float, gain: float, eps: float, g_bar: float, y_rest: float
) -> float:
    """Time [s] for one component y of x2 (v or omega) to fall from ``|y0|`` to ``y_rest`` under
    the stop law, the disturbance at its bound against the motion (worst case):

    * outside the boundary layer (|y| > eps): y' = -y/T - (K - g_bar): y + (K - g_bar) T decays
      with time constant T, so eps is reached after T ln((|y0| + b T) / (eps + b T)),
      b = K - g_bar;
    * inside: y' = -(1/T + K/eps) y + g_bar: an exponential of rate c = 1/T + K/eps toward the
      residual g_bar / c, reached to ``y_rest`` after ln((eps - res) / (y_rest - res)) / c.

    Needs K > g_bar and g_bar / c < y_rest (checked by :class:`StopLead`). Exact for a constant
    disturbance at its bound along the motion, an upper bound for any |g| <= g_bar (comparison),
    while the law is not torque-limited (StopLead checks that up to its speed bounds). One
    implementation: the compiled :func:`band_time_k`.
    """
    return float(band_time_k(float(y0), float(stop_time_s), float(gain), float(eps),
                             float(g_bar), float(y_rest)))


class StopLead:
    """When the camera-loss stop must begin so that the robot is at rest by ``pose_timeout_s``
    (docs/design.md §7, docs/safety.md §7).

    Rule: the controlled stop (:func:`stop_torque`) begins once the camera age exceeds
    ``pose_timeout_s - lead(v, omega)``, lead = time to rest from the current speed under the stop
    law + ``margin_s``, capped at its worst case ``max_s`` (the lead at the speed bounds
    ``speed_max_mps``, ``turn_rate_max_radps``). At rest = both wheels' rim speeds
    |v -+ (a/2) omega| below REST_SPEED_MPS, reached when |v| <= REST_SPEED_MPS / 2 and
    (a/2)|omega| <= REST_SPEED_MPS / 2; the time to rest is the longer of the two components'
    :func:`time_to_band` (the law acts on v and omega separately: u = B2^-1 (...) decouples them
    while it is not torque-limited), with the disturbance at the scenario's bound (g1_bar, g2_bar).

    Checks (ConfigError naming the parameter): the switching gain beats the disturbance bound and
    holds the robot within the rest band; the unscaled stop law stays within the torque limit for
    every |v| <= speed_max_mps, |omega| <= turn_rate_max_radps (so the closed form holds there);
    ``max_s <= pose_timeout_s`` (:meth:`check`).
    """

    def __init__(
        self,
        robot,
        stop_time_s: float,
        gains: ControlGains,
        disturbance_bound=(0.0, 0.0),
        margin_s: float = 0.03,
        speed_max_mps: float = 0.15,
        turn_rate_max_radps: float = 2.5,
        decel_mps2: float = 0.0,
        period_s: float = 0.01,
    ):
        d, a = robot.com_offset_m, robot.axle_length_m
        self.stop_time_s = float(stop_time_s)
        self.decel_mps2, self.period_s = float(decel_mps2), float(period_s)
        self.margin_s = float(margin_s)
        self.speed_max_mps = float(speed_max_mps)
        self.turn_rate_max_radps = float(turn_rate_max_radps)
        k = PlantCoeffs.from_params([robot])
        self.peak_torque_nm = self._peak_torque(k, gains)
        if (
            self.peak_torque_nm > robot.torque_limit_nm
            and self.decel_mps2 > gains.switching_gain_mps2
        ):
            # the largest v gain the torque limit allows within the bounds (a weaker robot)
            lo, hi = gains.switching_gain_mps2, self.decel_mps2
            for _ in range(20):
                self.decel_mps2 = 0.5 * (lo + hi)
                lo, hi = (
                    (self.decel_mps2, hi)
                    if self._peak_torque(k, gains) <= robot.torque_limit_nm
                    else (lo, self.decel_mps2)
                )
            self.decel_mps2 = lo
            self.peak_torque_nm = self._peak_torque(k, gains)
        if self.peak_torque_nm > robot.torque_limit_nm:
            raise ConfigError(
                f'the controlled stop needs {self.peak_torque_nm:.3f} N m at speeds up to '
                f'{self.speed_max_mps:g} m/s and {self.turn_rate_max_radps:g} rad/s, more than '
                f'the torque limit {robot.torque_limit_nm:g} N m, so its time to rest is not '
                'guaranteed: lower stop_speed_max_mps / stop_turn_rate_max_radps or raise '
                'stop_time_s',
                'stop_speed_max_mps',
            )
        (gain_v, eps_v), (gain_w, eps_w) = stop_gains(gains, self.decel_mps2, self.period_s)
        g1, g2 = (float(g) for g in disturbance_bound)
        # (K, eps, g_bar, rest band) of v [m/s] and of omega [rad/s], as stop_torque
        self._v = (gain_v, eps_v, g1, 0.5 * REST_SPEED_MPS)
        self._w = (gain_w / d, eps_w / d, g2, REST_SPEED_MPS / a)
        for name, (k_c, eps_c, g_c, rest_c), unit in (
            ('v', self._v, 'm/s^2'),
            ('omega', self._w, 'rad/s^2'),
        ):
            residual = g_c / (1.0 / self.stop_time_s + k_c / eps_c)
            if not (k_c > g_c and residual < rest_c):
                raise ConfigError(
                    f"the controlled stop cannot bring {name} to rest against the scenario's "
                    f'disturbance bound {g_c:g} {unit} (switching gain {k_c:g} {unit}, residual '
                    f'{residual:.4g} >= rest band {rest_c:.4g}): lower stop_time_s or raise '
                    'control.switching_gain_mps2',
                    'stop_time_s',
                )
        self.time_to_rest_max_s = self.time_to_rest(self.speed_max_mps, self.turn_rate_max_radps)
        self.max_s = self.time_to_rest_max_s + self.margin_s

    def _peak_torque(self, k: PlantCoeffs, gains: ControlGains, n: int = 41) -> float:
        """Largest unscaled stop-law torque [N m] over |v| <= speed_max_mps,
        |omega| <= turn_rate_max_radps (an n x n grid of the box, its edges included).
        """
        vv, ww = np.meshgrid(
            np.linspace(-self.speed_max_mps, self.speed_max_mps, n),
            np.linspace(-self.turn_rate_max_radps, self.turn_rate_max_radps, n),
        )
        states = np.zeros((vv.size, 5))
        states[:, 3], states[:, 4] = vv.ravel(), ww.ravel()
        kn = k.take(np.zeros(vv.size, dtype=int))
        u = _stop_law(states, kn, self.stop_time_s, gains, self.decel_mps2, self.period_s)
        return float(np.max(np.abs(u)))

    def time_to_rest(self, v: float, omega: float) -> float:
        """Time [s] from (v, omega) to rest under the stop law (worst-case disturbance)."""
        return max(
            time_to_band(v, self.stop_time_s, *self._v),
            time_to_band(omega, self.stop_time_s, *self._w),
        )

    def lead_s(self, v: float, omega: float) -> float:
        """How long before ``pose_timeout_s`` the stop begins at (v, omega) [s], <= max_s."""
        return min(self.time_to_rest(v, omega) + self.margin_s, self.max_s)

    def over_bound(self, v: float, omega: float) -> bool:
        """Faster than the speed bounds: the guarantee does not cover (v, omega)."""
        return abs(v) > self.speed_max_mps or abs(omega) > self.turn_rate_max_radps

    def compiled(self, gains: ControlGains) -> StopK:
        """:data:`StopK` of this lead, with the hold-parent stop's v gains (the formation law's,
        :func:`stop_gains` without the camera-loss deceleration).
        """
        (k_v, e_v), _w = stop_gains(gains, 0.0, self.period_s)
        return StopK(self.stop_time_s, *self._v, *self._w, self.margin_s, self.max_s,
                     self.speed_max_mps, self.turn_rate_max_radps, k_v, e_v)

    def check(self, pose_timeout_s: float) -> None:
        """Raise ConfigError unless the worst-case lead fits in ``pose_timeout_s``."""
        if self.max_s > pose_timeout_s:
            raise ConfigError(
                f'must be >= {self.max_s:.3f} s: the controlled stop from '
                f'{self.speed_max_mps:g} m/s (stop_speed_max_mps) and '
                f'{self.turn_rate_max_radps:g} rad/s (stop_turn_rate_max_radps) takes '
                f'{self.time_to_rest_max_s:.3f} s to rest (stop_time_s {self.stop_time_s:g} s), '
                f'plus stop_margin_s {self.margin_s:g} s, so it must begin that long before '
                f'pose_timeout_s (got {pose_timeout_s:g} s); raise pose_timeout_s or lower '
                'stop_speed_max_mps, stop_turn_rate_max_radps, stop_time_s or stop_margin_s',
                'pose_timeout_s',
            )
