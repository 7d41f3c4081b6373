"""Pose estimate of one robot's controlled point from wheel odometry and delayed camera poses
(S10).

Between camera frames the pose is propagated with the wheel encoders (exact arc per step, S2.2
kinematics (16)-(18) for constant v, omega over the step). Each camera pose carries its capture
stamp; it is compared with the estimate *at that stamp* (kept in a short history of odometry
steps), the innovation is applied there with a complementary gain, and the steps recorded since are
re-applied, so a frame that arrives 100 ms late corrects the pose it saw, not the current one.
Non-finite inputs are rejected and counted; camera poses far from the prediction are gated out,
unless several in a row disagree (then the estimator re-locks onto the camera).

Conventions: pose (3,) [x_m, y_m, theta_rad] of the controlled point p (distance d ahead of the
axle midpoint); state (5,) [x_m, y_m, theta_rad, v_mps, omega_radps]; wheel arrays (2,)
[left, right]; times [s] on one clock (the node's).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math

import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.params import RobotParams


def wrap_angle(a):
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class EstimatorParams:
    """Geometry and tuning of the S10 fusion."""

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
        for name in (
            'wheel_radius_m',
            'axle_length_m',
            'com_offset_m',
            'gate_position_m',
            'gate_heading_rad',
            'history_s',
            'max_wheel_speed_radps',
        ):
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
        return cls(
            wheel_radius_m=robot.wheel_radius_m,
            axle_length_m=robot.axle_length_m,
            com_offset_m=robot.com_offset_m,
            **tuning,
        )


def wheel_to_body(dq_rad, r_m: float, a_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Wheel increments (or rates) (..., 2) [left, right] -> (forward (...), yaw (...)).

    forward = r (q_R + q_L) / 2, yaw = r (q_R - q_L) / a (S2.2 wheel-centre speeds v -+ L omega).
    """
    dq = np.asarray(dq_rad, dtype=float)
    return r_m * 0.5 * (dq[..., 1] + dq[..., 0]), r_m * (dq[..., 1] - dq[..., 0]) / a_m


def fold_steps(axle_xy, theta: float, ds, dth) -> tuple[np.ndarray, np.ndarray]:
    """Apply K body-frame steps (ds (K,) [m], dth (K,) [rad]) to an axle-midpoint pose.

    Exact arcs (constant curvature per step): chord = ds sinc(dth / 2) along theta + dth / 2.
    Returns (axle positions (K, 2), headings (K,)) after each step.
    """
    ds = np.asarray(ds, dtype=float)
    dth = np.asarray(dth, dtype=float)
    th_end = theta + np.cumsum(dth)
    th_mid = th_end - 0.5 * dth
    chord = ds * np.sinc(dth / (2.0 * np.pi))  # np.sinc(x) = sin(pi x) / (pi x)
    steps = np.stack([chord * np.cos(th_mid), chord * np.sin(th_mid)], axis=-1)
    return np.asarray(axle_xy, dtype=float) + np.cumsum(steps, axis=0), th_end


def arc_step(
    x: float, y: float, theta: float, ds: float, dth: float
) -> tuple[float, float, float]:
    """One step of :func:`fold_steps` in scalars (the per-sample path: no array overhead)."""
    h = 0.5 * dth
    chord = ds * (math.sin(h) / h if abs(h) > 1e-9 else 1.0 - h * h / 6.0)
    th_mid = theta + h
    return x + chord * math.cos(th_mid), y + chord * math.sin(th_mid), theta + dth


def fold_to_end(axle_xy, theta: float, steps) -> tuple[np.ndarray, float]:
    """The end pose of :func:`fold_steps` for a few ``_Step`` (a scalar loop: the estimator folds
    the handful of odometry steps between camera frames, where arrays cost more than they save).
    Returns (axle position (2,), heading [rad]).
    """
    x, y, th = float(axle_xy[0]), float(axle_xy[1]), float(theta)
    for step in steps:
        x, y, th = arc_step(x, y, th, step.ds_m, step.dth_rad)
    return np.array([x, y]), th


@dataclass
class EstimatorCounters:
    """What the estimator accepted and rejected (for diagnostics)."""

    odometry: int = 0
    camera_accepted: int = 0
    rejected_nonfinite: int = 0
    rejected_outlier: int = 0
    rejected_stale: int = 0
    rejected_glitch: int = 0
    relocks: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class _Step:
    t_s: float  # end time of the step
    ds_m: float
    dth_rad: float


# implements: S10
class PoseEstimator:
    """S10 fusion for one robot (see module docstring)."""

    def __init__(self, params: EstimatorParams):
        self.p = params
        self.counters = EstimatorCounters()
        self._anchor_t: float | None = None  # time of the anchor pose
        self._anchor_axle = np.zeros(2)
        self._anchor_th = 0.0
        self._steps: deque[_Step] = deque()
        self._axle = np.zeros(2)  # current (end of odometry) axle pose
        self._th = 0.0
        self._last_q: tuple[float, float] | None = None  # wheel angles [left, right]
        self._last_q_t: float | None = None
        self._rates = np.zeros(2)  # [v_mps, omega_radps] from the wheel rates
        self._odom_t: float | None = None  # time of the newest odometry sample
        self.last_camera_s: float | None = None  # capture stamp of the newest accepted frame
        self._rejected_in_row = 0
        self._pending: list[_Step] = []  # steps before the first camera pose

    # ---------------------------------------------------------------- geometry
    def _to_axle(self, pose) -> np.ndarray:
        d = self.p.com_offset_m
        return np.array([pose[0] - d * math.cos(pose[2]), pose[1] - d * math.sin(pose[2])])

    def _to_point(self, axle, th) -> np.ndarray:
        d = self.p.com_offset_m
        return np.array(
            [axle[0] + d * math.cos(th), axle[1] + d * math.sin(th), float(wrap_angle(th))]
        )

    @property
    def initialized(self) -> bool:
        """True once a pose is known (first camera frame or initialize())."""
        return self._anchor_t is not None

    def initialize(self, pose_xyt, t_s: float) -> None:
        """Set the pose of p at ``t_s`` (drops the odometry history)."""
        pose = np.asarray(pose_xyt, dtype=float)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)) or not math.isfinite(t_s):
            raise ValueError(
                f'pose_xyt: expected 3 finite values and a finite time (got {pose}, {t_s})'
            )
        self._anchor_t = float(t_s)
        self._anchor_axle = self._to_axle(pose)
        self._anchor_th = float(pose[2])
        self._steps.clear()
        self._axle, self._th = self._anchor_axle.copy(), self._anchor_th
        self.last_camera_s = float(t_s)

    # ---------------------------------------------------------------- odometry
    def wheel_update(self, t_s: float, wheel_angle_rad, wheel_rate_radps) -> bool:
        """Add one encoder sample (absolute wheel angles [rad], rates [rad/s]) taken at ``t_s``.

        Returns False (and counts why) when the sample was rejected.
        """
        if (
            type(wheel_angle_rad) is tuple
            and type(wheel_rate_radps) is tuple
            and len(wheel_angle_rad) == 2
            and len(wheel_rate_radps) == 2
        ):  # two pairs of numbers (the bridge's samples): no arrays
            ql, qr = float(wheel_angle_rad[0]), float(wheel_angle_rad[1])
            wl, wr = float(wheel_rate_radps[0]), float(wheel_rate_radps[1])
        else:
            q = np.asarray(wheel_angle_rad, dtype=float)
            w = np.asarray(wheel_rate_radps, dtype=float)
            if q.shape != (2,) or w.shape != (2,):
                self.counters.rejected_nonfinite += 1
                return False
            ql, qr = q.tolist()
            wl, wr = w.tolist()
        if not all(map(math.isfinite, (ql, qr, wl, wr, t_s))):
            self.counters.rejected_nonfinite += 1
            return False
        r, a = self.p.wheel_radius_m, self.p.axle_length_m
        t_s = float(t_s)
        if self._last_q is None:
            self._last_q, self._last_q_t = (ql, qr), t_s
            self._rates = np.array([r * 0.5 * (wr + wl), r * (wr - wl) / a])
            self._odom_t = t_s
            self.counters.odometry += 1
            return True
        dt = t_s - self._last_q_t
        if dt < 0.0:
            self.counters.rejected_stale += 1
            return False
        dql, dqr = ql - self._last_q[0], qr - self._last_q[1]
        # samples batched under one stamp (dt = 0) are fine; the jump test allows >= 10 ms of
        # motion
        wmax = self.p.max_wheel_speed_radps
        if max(abs(dql), abs(dqr)) > wmax * max(dt, 0.01) or max(abs(wl), abs(wr)) > wmax:
            self.counters.rejected_glitch += 1
            self._last_q, self._last_q_t = (ql, qr), t_s  # resynchronise, drop the jump
            return False
        self._last_q, self._last_q_t = (ql, qr), t_s
        step = _Step(t_s, r * 0.5 * (dqr + dql), r * (dqr - dql) / a)  # wheel_to_body, scalars
        self._rates = np.array([r * 0.5 * (wr + wl), r * (wr - wl) / a])
        self._odom_t = t_s
        self.counters.odometry += 1
        if self._anchor_t is None:
            self._pending.append(step)
            cutoff = t_s - self.p.history_s
            while self._pending and self._pending[0].t_s < cutoff:
                self._pending.pop(0)
            return True
        self._steps.append(step)
        x, y, self._th = arc_step(
            float(self._axle[0]), float(self._axle[1]), self._th, step.ds_m, step.dth_rad
        )
        self._axle = np.array([x, y])
        self._trim(t_s)
        return True

    def _trim(self, now_s: float) -> None:
        """Fold steps older than the history window into the anchor."""
        cutoff = now_s - self.p.history_s
        old = []
        while self._steps and self._steps[0].t_s < cutoff:
            old.append(self._steps.popleft())
        if old:
            self._anchor_axle, self._anchor_th = fold_to_end(
                self._anchor_axle, self._anchor_th, old
            )
            self._anchor_t = old[-1].t_s

    # ---------------------------------------------------------------- camera
    def _split_at(self, t_s: float) -> tuple[list[_Step], list[_Step]]:
        """Steps up to ``t_s`` and after it; the step spanning t_s is split proportionally."""
        before, after = [], []
        prev_t = self._anchor_t
        for s in self._steps:
            if s.t_s <= t_s:
                before.append(s)
            elif prev_t < t_s:
                f = (t_s - prev_t) / (s.t_s - prev_t)
                before.append(_Step(t_s, f * s.ds_m, f * s.dth_rad))
                after.append(_Step(s.t_s, (1 - f) * s.ds_m, (1 - f) * s.dth_rad))
            else:
                after.append(s)
            prev_t = s.t_s
        return before, after

    def camera_update(self, t_s: float, pose_xyt) -> str:
        """Fuse a camera pose of p captured at ``t_s``.

        Returns one of "initialized", "accepted", "relocked", "rejected_nonfinite",
        "rejected_stale", "rejected_outlier".
        """
        pose = np.asarray(pose_xyt, dtype=float)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)) or not math.isfinite(t_s):
            self.counters.rejected_nonfinite += 1
            return 'rejected_nonfinite'
        if self._anchor_t is None:
            self._initialize_from_camera(t_s, pose)
            return 'initialized'
        if t_s < self._anchor_t or (self.last_camera_s is not None and t_s <= self.last_camera_s):
            self.counters.rejected_stale += 1
            return 'rejected_stale'
        before, after = self._split_at(t_s)
        axle_c, th_c = fold_to_end(self._anchor_axle, self._anchor_th, before)
        predicted = self._to_point(axle_c, th_c)
        innov = pose - predicted
        innov[2] = float(wrap_angle(innov[2]))
        outcome = 'accepted'
        gain = self.p.camera_gain
        if (
            np.hypot(innov[0], innov[1]) > self.p.gate_position_m
            or abs(innov[2]) > self.p.gate_heading_rad
        ):
            self._rejected_in_row += 1
            if self._rejected_in_row < self.p.relock_after:
                self.counters.rejected_outlier += 1
                return 'rejected_outlier'
            outcome, gain = 'relocked', 1.0
            self.counters.relocks += 1
        self._rejected_in_row = 0
        corrected = predicted + gain * innov
        self._anchor_t = float(t_s)
        self._anchor_axle = self._to_axle(corrected)
        self._anchor_th = float(corrected[2])
        self._steps = deque(after)
        self._refold()
        self.last_camera_s = float(t_s)
        self.counters.camera_accepted += 1
        return outcome

    def _initialize_from_camera(self, t_s: float, pose: np.ndarray) -> None:
        pending = [s for s in self._pending if s.t_s > t_s]
        self._pending = []
        self.initialize(pose, t_s)
        self._steps = deque(pending)
        self._refold()
        self.counters.camera_accepted += 1

    def _refold(self) -> None:
        self._axle, self._th = fold_to_end(self._anchor_axle, self._anchor_th, self._steps)

    # ---------------------------------------------------------------- output
    def pose(self) -> np.ndarray:
        """(3,) pose of p at the newest odometry sample."""
        return self._to_point(self._axle, self._th)

    def state(self) -> np.ndarray:
        """(5,) [x_m, y_m, theta_rad, v_mps, omega_radps] at the newest odometry sample."""
        return np.concatenate([self.pose(), self._rates])

    def state_at(self, t_s: float) -> np.ndarray:
        """(5,) state extrapolated with the latest (v, omega) to ``t_s`` (at most
        ``max_extrapolation_s`` past the newest odometry sample; never backwards).
        """
        if self._odom_t is None:
            return self.state()
        dt = min(max(0.0, t_s - self._odom_t), self.p.max_extrapolation_s)
        v, w = self._rates.tolist()
        x, y, th = arc_step(float(self._axle[0]), float(self._axle[1]), self._th, v * dt, w * dt)
        d = self.p.com_offset_m
        return np.array(
            [
                x + d * math.cos(th),
                y + d * math.sin(th),
                (th + math.pi) % (2.0 * math.pi) - math.pi,
                v,
                w,
            ]
        )

    def camera_age_s(self, now_s: float) -> float:
        """Time since the capture stamp of the newest accepted camera pose (inf if none)."""
        return math.inf if self.last_camera_s is None else now_s - self.last_camera_s

    @property
    def odometry_time_s(self) -> float | None:
        return self._odom_t
