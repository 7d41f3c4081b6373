"""Pose estimate of a robot's controlled point from wheel odometry and delayed camera poses
(docs/control-law.md S10.1), compiled for one robot or many in one call.

Between camera frames the pose is propagated with the wheel encoders (an exact arc per step,
S2.2 kinematics (16)-(18) for constant v, omega over the step). Each camera pose carries its
capture stamp; it is compared with the estimate *at that stamp* (odometry steps are kept for
``history_s`` in a ring), the innovation is applied there with a complementary gain, and the
steps recorded since are re-applied, so a frame that arrives 100 ms late corrects the pose it
saw, not the current one. Non-finite inputs are rejected and counted; camera poses far from the
prediction are gated out, unless several in a row disagree (then the estimator re-locks onto
the camera).

Conventions: pose (3,) [x_m, y_m, theta_rad] of p (distance d ahead of the axle midpoint);
state (5,) [x_m, y_m, theta_rad, v_mps, omega_radps]; wheel pairs [left, right]; times [s] on
the robot's clock. The state of R robots lives in :data:`EstimatorArrays`; the kernels take a
row. :class:`PoseEstimator` is one robot's, with a Python API.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass
import math

from numba import njit
import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.params import RobotParams

HISTORY = 256  # odometry steps kept per robot (more than history_s at the wheel rate)
# float slots of a robot's row (F_OUT_T: the time of the latest state returned, state_at_k)
(F_ANCHOR_T, F_ANCHOR_X, F_ANCHOR_Y, F_ANCHOR_TH, F_AXLE_X, F_AXLE_Y, F_TH, F_QL, F_QR, F_Q_T,
 F_V, F_W, F_ODOM_T, F_CAMERA_T, F_OUT_T) = range(15)
N_F = 15
# int slots: initialised, has a wheel sample, gated frames in a row, ring head, ring count
I_INIT, I_HAS_Q, I_GATED, I_HEAD, I_COUNT = range(5)
N_I = 5
COUNTERS = ('odometry', 'camera_accepted', 'rejected_nonfinite', 'rejected_outlier',
            'rejected_stale', 'rejected_glitch', 'relocks')
(C_ODOM, C_CAM, C_NONFINITE, C_OUTLIER, C_STALE, C_GLITCH, C_RELOCK) = range(7)
# outcomes of camera_update_k
CAMERA_OUTCOMES = ('initialized', 'accepted', 'relocked', 'rejected_nonfinite',
                   'rejected_stale', 'rejected_outlier')

EstimatorArrays = namedtuple('EstimatorArrays', ['f', 'i', 'steps', 'counters'])
EstimatorArrays.__doc__ = """The estimates of R robots: ``f`` (R, 15) float slots (F_*),
``i`` (R, 5) int slots (I_*), ``steps`` (R, HISTORY, 3) the odometry ring [t_s, ds_m, dth_rad],
``counters`` (R, 7) int (:data:`COUNTERS`)."""

EstimatorK = namedtuple('EstimatorK', ['r', 'a', 'd', 'gain', 'gate_m', 'gate_rad', 'relock',
                                       'history_s', 'max_rate', 'max_extrapolation_s'])


@dataclass(frozen=True)
class EstimatorParams:
    """Geometry and tuning of the S10.1 fusion."""

    wheel_radius_m: float = 0.035
    axle_length_m: float = 0.20
    com_offset_m: float = 0.05
    camera_gain: float = 0.5  # fraction of the innovation applied per frame, (0, 1]
    gate_position_m: float = 0.25  # reject camera poses further than this from the prediction
    gate_heading_rad: float = 0.6
    relock_after: int = 5  # this many consecutive gated frames: accept (gain 1)
    history_s: float = 1.0  # odometry kept for latency compensation
    max_wheel_speed_radps: float = 200.0  # larger encoder jumps are glitches
    max_extrapolation_s: float = 0.05  # state_at() extrapolates at most this far past odometry

    def __post_init__(self) -> None:
        for name in ('wheel_radius_m', 'axle_length_m', 'com_offset_m', 'gate_position_m',
                     'gate_heading_rad', 'history_s', 'max_wheel_speed_radps'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f'must be a finite number > 0 (got {v!r})', name)
        if not (0.0 < self.camera_gain <= 1.0):
            raise ConfigError(f'must be in (0, 1] (got {self.camera_gain!r})', 'camera_gain')
        if not (isinstance(self.relock_after, int) and self.relock_after >= 1):
            raise ConfigError(
                f'must be an integer >= 1 (got {self.relock_after!r})', 'relock_after'
            )
        if not (math.isfinite(self.max_extrapolation_s) and self.max_extrapolation_s >= 0):
            raise ConfigError(
                f'must be >= 0 s (got {self.max_extrapolation_s!r})', 'max_extrapolation_s'
            )

    @classmethod
    def from_robot(cls, robot: RobotParams, **tuning) -> 'EstimatorParams':
        """Geometry from a robot's parameters (S2.3) plus any tuning fields."""
        return cls(wheel_radius_m=robot.wheel_radius_m, axle_length_m=robot.axle_length_m,
                   com_offset_m=robot.com_offset_m, **tuning)

    def compiled(self) -> EstimatorK:
        return EstimatorK(self.wheel_radius_m, self.axle_length_m, self.com_offset_m,
                          self.camera_gain, self.gate_position_m, self.gate_heading_rad,
                          float(self.relock_after), self.history_s, self.max_wheel_speed_radps,
                          self.max_extrapolation_s)


def new_estimates(n: int) -> EstimatorArrays:
    """:data:`EstimatorArrays` of n robots, none initialised."""
    f = np.zeros((n, N_F))
    f[:, F_CAMERA_T] = -np.inf
    f[:, F_ODOM_T] = np.nan
    f[:, F_OUT_T] = -np.inf
    return EstimatorArrays(f, np.zeros((n, N_I), dtype=np.int64), np.zeros((n, HISTORY, 3)),
                           np.zeros((n, len(COUNTERS)), dtype=np.int64))


@njit(cache=True, error_model='numpy')
def wrap(a):
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True, error_model='numpy')
def arc_step(x, y, theta, ds, dth):
    """One odometry step of an axle pose: an exact arc, chord = ds sinc(dth/2) along
    theta + dth/2.
    """
    h = 0.5 * dth
    chord = ds * (math.sin(h) / h if abs(h) > 1e-9 else 1.0 - h * h / 6.0)
    return x + chord * math.cos(theta + h), y + chord * math.sin(theta + h), theta + dth


@njit(cache=True, error_model='numpy')
def _fold(e, row, upto):
    """The axle pose after the anchor and the first ``upto`` steps of the ring."""
    f = e.f[row]
    x, y, th = f[F_ANCHOR_X], f[F_ANCHOR_Y], f[F_ANCHOR_TH]
    head = e.i[row, I_HEAD]
    for q in range(upto):
        st = e.steps[row, (head + q) % HISTORY]
        x, y, th = arc_step(x, y, th, st[1], st[2])
    return x, y, th


@njit(cache=True, error_model='numpy')
def _drop(e, row, n, fold):
    """Remove the n oldest steps (folded into the anchor when ``fold``)."""
    if n <= 0:
        return
    if fold:
        x, y, th = _fold(e, row, n)
        f = e.f[row]
        f[F_ANCHOR_X], f[F_ANCHOR_Y], f[F_ANCHOR_TH] = x, y, th
        f[F_ANCHOR_T] = e.steps[row, (e.i[row, I_HEAD] + n - 1) % HISTORY, 0]
    e.i[row, I_HEAD] = (e.i[row, I_HEAD] + n) % HISTORY
    e.i[row, I_COUNT] -= n


@njit(cache=True, error_model='numpy')
def _refold(e, row):
    x, y, th = _fold(e, row, e.i[row, I_COUNT])
    e.f[row, F_AXLE_X], e.f[row, F_AXLE_Y], e.f[row, F_TH] = x, y, th


# implements: S10, S10.1
@njit(cache=True, error_model='numpy')
def wheel_update_k(e, row, t, ql, qr, wl, wr, k):
    """One encoder sample (absolute wheel angles [rad], rates [rad/s]) taken at ``t`` [s].
    Returns False (counted) when rejected.
    """
    f, ints, cnt = e.f[row], e.i[row], e.counters[row]
    if not (math.isfinite(ql) and math.isfinite(qr) and math.isfinite(wl)
            and math.isfinite(wr) and math.isfinite(t)):
        cnt[C_NONFINITE] += 1
        return False
    v, w = k.r * 0.5 * (wr + wl), k.r * (wr - wl) / k.a
    if ints[I_HAS_Q] == 0:
        ints[I_HAS_Q] = 1
        f[F_QL], f[F_QR], f[F_Q_T], f[F_V], f[F_W], f[F_ODOM_T] = ql, qr, t, v, w, t
        cnt[C_ODOM] += 1
        return True
    dt = t - f[F_Q_T]
    if dt < 0.0:
        cnt[C_STALE] += 1
        return False
    dql, dqr = ql - f[F_QL], qr - f[F_QR]
    f[F_QL], f[F_QR], f[F_Q_T] = ql, qr, t
    if max(abs(dql), abs(dqr)) > k.max_rate * max(dt, 0.01) or max(abs(wl), abs(wr)) > k.max_rate:
        cnt[C_GLITCH] += 1  # resynchronised on this sample, the jump dropped
        return False
    f[F_V], f[F_W], f[F_ODOM_T] = v, w, t
    cnt[C_ODOM] += 1
    if ints[I_COUNT] == HISTORY:
        _drop(e, row, 1, ints[I_INIT] == 1)
    slot = e.steps[row, (ints[I_HEAD] + ints[I_COUNT]) % HISTORY]
    slot[0], slot[1], slot[2] = t, k.r * 0.5 * (dqr + dql), k.r * (dqr - dql) / k.a
    ints[I_COUNT] += 1
    if ints[I_INIT] == 0:  # before the first frame: keep history_s of steps for its replay
        old = 0
        while old < ints[I_COUNT] and e.steps[row, (ints[I_HEAD] + old) % HISTORY, 0] < (
                t - k.history_s):
            old += 1
        _drop(e, row, old, False)
        return True
    f[F_AXLE_X], f[F_AXLE_Y], f[F_TH] = arc_step(f[F_AXLE_X], f[F_AXLE_Y], f[F_TH], slot[1],
                                                 slot[2])
    old = 0
    while old < ints[I_COUNT] and e.steps[row, (ints[I_HEAD] + old) % HISTORY, 0] < (
            t - k.history_s):
        old += 1
    _drop(e, row, old, True)
    return True


@njit(cache=True, error_model='numpy')
def _initialize(e, row, t, x, y, th, k):
    """The first camera pose: anchor at its stamp, the steps recorded after it replayed."""
    f = e.f[row]
    old = 0
    while old < e.i[row, I_COUNT] and e.steps[row, (e.i[row, I_HEAD] + old) % HISTORY, 0] <= t:
        old += 1
    _drop(e, row, old, False)
    f[F_ANCHOR_T] = t
    f[F_ANCHOR_X], f[F_ANCHOR_Y], f[F_ANCHOR_TH] = x - k.d * math.cos(th), y - k.d * math.sin(
        th), th
    e.i[row, I_INIT] = 1
    f[F_CAMERA_T] = t
    f[F_OUT_T] = -np.inf
    _refold(e, row)
    e.counters[row, C_CAM] += 1


@njit(cache=True, error_model='numpy')
def camera_update_k(e, row, t, x, y, th, k):
    """Fuse a camera pose of p captured at ``t`` [s]; returns the index of its outcome in
    :data:`CAMERA_OUTCOMES`.
    """
    f, ints, cnt = e.f[row], e.i[row], e.counters[row]
    if not (math.isfinite(t) and math.isfinite(x) and math.isfinite(y) and math.isfinite(th)):
        cnt[C_NONFINITE] += 1
        return 3
    if ints[I_INIT] == 0:
        _initialize(e, row, t, x, y, th, k)
        return 0
    if t < f[F_ANCHOR_T] or t <= f[F_CAMERA_T]:
        cnt[C_STALE] += 1
        return 4
    before = 0  # steps wholly before t; the one spanning t is split
    while before < ints[I_COUNT] and e.steps[row, (ints[I_HEAD] + before) % HISTORY, 0] <= t:
        before += 1
    px, py, pth = _fold(e, row, before)
    split = False
    if before < ints[I_COUNT]:
        st = e.steps[row, (ints[I_HEAD] + before) % HISTORY]
        prev = (ints[I_HEAD] + before - 1) % HISTORY
        t0 = f[F_ANCHOR_T] if before == 0 else e.steps[row, prev, 0]
        if t0 < t:
            frac = (t - t0) / (st[0] - t0)
            px, py, pth = arc_step(px, py, pth, frac * st[1], frac * st[2])
            split = True
    ex = x - (px + k.d * math.cos(pth))
    ey = y - (py + k.d * math.sin(pth))
    eth = wrap(th - wrap(pth))
    outcome = 1
    gain = k.gain
    if math.hypot(ex, ey) > k.gate_m or abs(eth) > k.gate_rad:
        ints[I_GATED] += 1
        if ints[I_GATED] < k.relock:
            cnt[C_OUTLIER] += 1
            return 5
        outcome, gain = 2, 1.0
        cnt[C_RELOCK] += 1
    ints[I_GATED] = 0
    if split:
        st = e.steps[row, (ints[I_HEAD] + before) % HISTORY]
        prev = (ints[I_HEAD] + before - 1) % HISTORY
        t0 = f[F_ANCHOR_T] if before == 0 else e.steps[row, prev, 0]
        frac = (t - t0) / (st[0] - t0)
        st[1] *= 1.0 - frac
        st[2] *= 1.0 - frac
    _drop(e, row, before, False)
    cx = px + k.d * math.cos(pth) + gain * ex
    cy = py + k.d * math.sin(pth) + gain * ey
    cth = wrap(pth) + gain * eth
    f[F_ANCHOR_T] = t
    f[F_ANCHOR_X], f[F_ANCHOR_Y], f[F_ANCHOR_TH] = cx - k.d * math.cos(cth), cy - k.d * math.sin(
        cth), cth
    _refold(e, row)
    f[F_CAMERA_T] = t
    cnt[C_CAM] += 1
    return outcome


@njit(cache=True, error_model='numpy')
def state_at_k(e, row, t, k, out):
    """State (5,) of p -> ``out``, extrapolated with the latest (v, omega) to ``t`` (at most
    ``max_extrapolation_s`` past the newest odometry sample; never going back: never before
    that sample, nor before the time of a state it returned already).
    """
    f = e.f[row]
    v, w = f[F_V], f[F_W]
    dt = 0.0
    if math.isfinite(f[F_ODOM_T]):
        dt = min(max(0.0, max(t, f[F_OUT_T]) - f[F_ODOM_T]), k.max_extrapolation_s)
        f[F_OUT_T] = f[F_ODOM_T] + dt
    x, y, th = arc_step(f[F_AXLE_X], f[F_AXLE_Y], f[F_TH], v * dt, w * dt)
    out[0] = x + k.d * math.cos(th)
    out[1] = y + k.d * math.sin(th)
    out[2] = wrap(th)
    out[3] = v
    out[4] = w


class PoseEstimator:
    """One robot's S10.1 fusion with a Python API (tests, tools); the robot agent calls the
    kernels on its rows directly.
    """

    def __init__(self, params: EstimatorParams):
        self.p = params
        self._k = params.compiled()
        self._e = new_estimates(1)

    @property
    def initialized(self) -> bool:
        return bool(self._e.i[0, I_INIT])

    def initialize(self, pose_xyt, t_s: float) -> None:
        """Set the pose of p at ``t_s`` (drops the odometry history)."""
        pose = np.asarray(pose_xyt, dtype=float)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)) or not math.isfinite(t_s):
            raise ValueError(
                f'pose_xyt: expected 3 finite values and a finite time (got {pose}, {t_s})'
            )
        self._e.i[0, I_COUNT] = 0
        _initialize(self._e, 0, float(t_s), *map(float, pose), self._k)
        self._e.counters[0, C_CAM] -= 1

    def wheel_update(self, t_s: float, wheel_angle_rad, wheel_rate_radps) -> bool:
        """Add one encoder sample taken at ``t_s``; False (counted) when rejected."""
        try:
            ql, qr = (float(v) for v in wheel_angle_rad)
            wl, wr = (float(v) for v in wheel_rate_radps)
        except (TypeError, ValueError):
            self._e.counters[0, C_NONFINITE] += 1
            return False
        return bool(wheel_update_k(self._e, 0, float(t_s), ql, qr, wl, wr, self._k))

    def camera_update(self, t_s: float, pose_xyt) -> str:
        """Fuse a camera pose of p captured at ``t_s``; returns its outcome (a name of
        :data:`CAMERA_OUTCOMES`).
        """
        pose = np.asarray(pose_xyt, dtype=float).reshape(-1)
        if pose.shape != (3,):
            self._e.counters[0, C_NONFINITE] += 1
            return 'rejected_nonfinite'
        return CAMERA_OUTCOMES[camera_update_k(self._e, 0, float(t_s), *map(float, pose),
                                               self._k)]

    def state_at(self, t_s: float) -> np.ndarray:
        out = np.empty(5)
        state_at_k(self._e, 0, float(t_s), self._k, out)
        return out

    def state(self) -> np.ndarray:
        """(5,) at the newest odometry sample (or later: :meth:`state_at` never goes back)."""
        t = self._e.f[0, F_ODOM_T]
        return self.state_at(float(t) if math.isfinite(t) else 0.0)

    def pose(self) -> np.ndarray:
        return self.state()[:3]

    def camera_age_s(self, now_s: float) -> float:
        return float(now_s - self._e.f[0, F_CAMERA_T])

    @property
    def last_camera_s(self) -> float | None:
        t = self._e.f[0, F_CAMERA_T]
        return None if t == -np.inf else float(t)

    @property
    def odometry_time_s(self) -> float | None:
        t = self._e.f[0, F_ODOM_T]
        return None if not math.isfinite(t) else float(t)

    @property
    def counters(self) -> dict:
        return {name: int(v) for name, v in zip(COUNTERS, self._e.counters[0])}
