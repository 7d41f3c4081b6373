"""Leader reference paths r(t) with closed-form derivatives (spec S4, S12).

Each path is a frozen dataclass with ``reference(t_s) -> (r, r_dot, r_ddot)``. ``t_s`` may be a
scalar (each result has shape (2,)) or an array of shape (T,) (each result (T, 2)), so a simulator
can tabulate the whole reference in one call. World frame, SI units: r [m], r_dot [m/s],
r_ddot [m/s^2].

* :class:`SinusoidPath` — y = A sin(k x) (rotated by ``heading_rad`` and shifted to ``start_m``),
  travelled at constant path speed v0 (S4 "Reference of the paper experiment"). The abscissa x_r(t)
  solves arc-length(x_r) = v0 t exactly (Gauss-Legendre arc length + Newton), and
  x_r' = v0 / sqrt(1 + a^2 cos^2(k x)), a = A k,
  x_r'' = v0 a^2 k cos(k x) sin(k x) x_r' / (1 + a^2 cos^2(k x))^{3/2},
  y_r' = a cos(k x) x_r',  y_r'' = -A k^2 sin(k x) x_r'^2 + a cos(k x) x_r''.
* :class:`LinePath` — constant velocity from ``start_m`` along ``heading_rad``.
* :class:`WaypointPath` — straight segments joined by circular arcs of radius v^2/a_max (so the
  acceleration never exceeds ``accel_mps2``; the path is C1), travelled at constant speed, then a
  constant deceleration a_max on the last segment to rest at the final waypoint.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Union

from numba import njit
import numpy as np

from ament_formation.core.errors import ConfigError, excerpt, MAX_MAGNITUDE

_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(48)


def _as_time(t_s):
    t = np.asarray(t_s, dtype=float)
    return t, t.ndim == 0


def _out(vec: np.ndarray, scalar: bool) -> np.ndarray:
    return vec[0] if scalar else vec


def _rotation(heading_rad: float) -> np.ndarray:
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return np.array([[c, -s], [s, c]])


# ------------------------------------------------------------------------------------------------
# Sinusoid (S4)
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SinusoidPath:
    """y = A sin(k x) in a frame at ``start_m`` turned by ``heading_rad``, at path speed v0 (S4).

    Parameters
    ----------
    start_m : (2,) world position of the curve's origin (x = 0) [m]
    amplitude_m : A [m] (>= 0)
    wavenumber_radpm : k [rad/m] (> 0)
    speed_mps : v0, constant speed along the curve [m/s] (> 0)
    heading_rad : direction of the curve's x axis in the world [rad]
    """

    start_m: tuple[float, float]
    amplitude_m: float
    wavenumber_radpm: float
    speed_mps: float
    heading_rad: float = 0.0

    def __post_init__(self) -> None:
        _check_vec2(self.start_m, 'start_m')
        _check_number(self.amplitude_m, 'amplitude_m', minimum=0.0)
        _check_number(self.wavenumber_radpm, 'wavenumber_radpm', positive=True)
        _check_number(self.speed_mps, 'speed_mps', positive=True)
        _check_number(self.heading_rad, 'heading_rad')

    # arc length from 0 to x of sqrt(1 + a^2 cos^2(k x)), a = A k: Gauss-Legendre on ceil(a) equal
    # panels of the part-period (one panel for a <= 1); the integrand's complex singularities lie
    # asinh(1/a)/k from the real axis, so steep curves need shorter panels to stay exact to ~1e-15
    def _panels(self) -> int:
        return max(1, math.ceil(self.amplitude_m * self.wavenumber_radpm))

    def _integral(self, length: np.ndarray) -> np.ndarray:
        """∫_0^length sqrt(1 + a^2 cos^2(k x)) dx, elementwise over ``length`` [m]."""
        k = self.wavenumber_radpm
        a = self.amplitude_m * k
        n = self._panels()
        width = np.asarray(length, dtype=float) / n
        total = 0.0
        vals = np.empty(width.shape + _GL_NODES.shape)  # in place: the same operations, no copies
        for j in range(n):
            np.multiply(width[..., None], j + 0.5 * (_GL_NODES + 1.0), out=vals)  # the nodes
            np.multiply(k, vals, out=vals)
            np.cos(vals, out=vals)
            np.multiply(a, vals, out=vals)
            np.square(vals, out=vals)
            np.add(1.0, vals, out=vals)
            np.sqrt(vals, out=vals)
            np.multiply(vals, _GL_WEIGHTS, out=vals)
            total = total + 0.5 * width * np.sum(vals, axis=-1)
        return total

    def _arc_length(self, x: np.ndarray) -> np.ndarray:
        period = 2.0 * math.pi / self.wavenumber_radpm
        n_periods = np.floor(x / period)
        frac = x - n_periods * period
        return n_periods * self._period_length() + self._integral(frac)

    def _period_length(self) -> float:
        return float(self._integral(np.asarray(2.0 * math.pi / self.wavenumber_radpm)))

    def abscissa(self, t_s) -> np.ndarray:
        """x_r(t) [m] in the curve frame: arc-length(x_r) = v0 t. Shape of ``t_s``."""
        t, _ = _as_time(t_s)
        s_target = self.speed_mps * t
        k = self.wavenumber_radpm
        a = self.amplitude_m * k
        mean_stretch = self._period_length() / (2.0 * math.pi / k)
        x = s_target / mean_stretch
        for _ in range(8):  # Newton on arc-length(x) - v0 t; quadratic from a close start
            step = (self._arc_length(x) - s_target) / np.sqrt(1.0 + (a * np.cos(k * x)) ** 2)
            x = x - step
            if np.all(np.abs(step) < 1e-14):
                break
        return x

    def reference(self, t_s):
        """(r, r_dot, r_ddot) at ``t_s`` [s]: each (2,) for a scalar time, (T, 2) for an array."""
        t, scalar = _as_time(t_s)
        t = np.atleast_1d(t)
        k = self.wavenumber_radpm
        amp = self.amplitude_m
        a = amp * k
        v0 = self.speed_mps
        x = self.abscissa(t)
        ckx, skx = np.cos(k * x), np.sin(k * x)
        den = 1.0 + (a * ckx) ** 2
        xd = v0 / np.sqrt(den)  # S4 x_r'
        xdd = v0 * a * a * k * ckx * skx * xd / den**1.5  # S4 x_r''
        y = amp * skx
        yd = a * ckx * xd  # S4 y_r'
        ydd = -amp * k * k * skx * xd * xd + a * ckx * xdd  # S4 y_r''
        rot = _rotation(self.heading_rad)
        r = np.stack([x, y], axis=-1) @ rot.T + np.asarray(self.start_m, dtype=float)
        r_dot = np.stack([xd, yd], axis=-1) @ rot.T
        r_ddot = np.stack([xdd, ydd], axis=-1) @ rot.T
        return _out(r, scalar), _out(r_dot, scalar), _out(r_ddot, scalar)


# ------------------------------------------------------------------------------------------------
# Line
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LinePath:
    """r(t) = start + v0 t (cos heading, sin heading)."""

    start_m: tuple[float, float]
    heading_rad: float
    speed_mps: float

    def __post_init__(self) -> None:
        _check_vec2(self.start_m, 'start_m')
        _check_number(self.heading_rad, 'heading_rad')
        _check_number(self.speed_mps, 'speed_mps', minimum=0.0)

    def reference(self, t_s):
        """(r, r_dot, r_ddot) at ``t_s`` [s]: each (2,) for a scalar time, (T, 2) for an array."""
        t, scalar = _as_time(t_s)
        if scalar:  # the same arithmetic on floats, without the (T, 2) arrays (control periods)
            t = float(t)
            vx = self.speed_mps * math.cos(self.heading_rad)
            vy = self.speed_mps * math.sin(self.heading_rad)
            x0, y0 = self.start_m
            return np.array([x0 + t * vx, y0 + t * vy]), np.array([vx, vy]), np.zeros(2)
        t = np.atleast_1d(t)
        vel = self.speed_mps * np.array([math.cos(self.heading_rad), math.sin(self.heading_rad)])
        r = np.asarray(self.start_m, dtype=float) + t[:, None] * vel
        r_dot = np.broadcast_to(vel, r.shape).copy()
        return _out(r, scalar), _out(r_dot, scalar), _out(np.zeros_like(r), scalar)


# ------------------------------------------------------------------------------------------------
# Waypoints with bounded acceleration
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class WaypointPath:
    """Polyline through ``points_m`` with corners rounded by arcs of radius v^2/a_max (C1 path,
    |r_ddot| <= a_max), travelled at ``speed_mps``, braking at a_max to rest at the last point.

    Parameters
    ----------
    points_m : (K, 2) waypoints [m], K >= 2, consecutive points distinct
    speed_mps : cruise speed v [m/s] (> 0)
    accel_mps2 : acceleration bound a_max [m/s^2] (> 0)
    """

    points_m: tuple[tuple[float, float], ...]
    speed_mps: float
    accel_mps2: float = 0.02
    _table: dict = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        _check_number(self.speed_mps, 'speed_mps', positive=True)
        _check_number(self.accel_mps2, 'accel_mps2', positive=True)
        pts = self.points_m
        if not isinstance(pts, (list, tuple)) or len(pts) < 2:
            raise ConfigError('must list at least 2 points [[x, y], ...]', 'points_m')
        for i, p in enumerate(pts):
            _check_vec2(p, f'points_m[{i}]')
        object.__setattr__(self, '_table', self._build())

    def _build(self) -> dict:
        pts = np.asarray(self.points_m, dtype=float)
        seg = np.diff(pts, axis=0)
        length = np.linalg.norm(seg, axis=1)
        for i, ell in enumerate(length):
            if ell < 1e-9:
                raise ConfigError(
                    f'repeats the previous point {pts[i].tolist()}', f'points_m[{i + 1}]'
                )
        unit = seg / length[:, None]
        radius = self.speed_mps**2 / self.accel_mps2
        # corner i (at pts[i], 1 <= i <= K-2): turn angle and tangent length R tan(|turn|/2)
        n_corner = len(pts) - 2
        turn = np.zeros(n_corner)
        tangent = np.zeros(n_corner)
        for c in range(n_corner):
            u_in, u_out = unit[c], unit[c + 1]
            ang = math.atan2(u_in[0] * u_out[1] - u_in[1] * u_out[0], float(u_in @ u_out))
            if abs(abs(ang) - math.pi) < 1e-9:
                raise ConfigError('the path reverses here (180 degree turn)', f'points_m[{c + 1}]')
            turn[c] = ang
            tangent[c] = radius * math.tan(abs(ang) / 2.0)
        # each segment must hold the tangent lengths at its ends (and the braking distance at the
        # end)
        brake = self.speed_mps**2 / (2.0 * self.accel_mps2)
        for i in range(len(length)):
            need = (tangent[i - 1] if i >= 1 else 0.0) + (tangent[i] if i < n_corner else 0.0)
            if i == len(length) - 1:
                need += brake
            if need > length[i] + 1e-12:
                raise ConfigError(
                    f'segment {i} -> {i + 1} is {length[i]:.3f} m long '
                    f'but needs {need:.3f} m to turn '
                    f'(radius v^2/a = {radius:.3f} m) '
                    f'and brake at accel_mps2 = {self.accel_mps2}; '
                    'space the points out, lower speed_mps or raise accel_mps2',
                    'points_m',
                )
        # primitives: (kind, s0, length, start point, direction / centre data)
        prims = []
        s = 0.0
        pos = pts[0].copy()
        for i in range(len(length)):
            t_in = tangent[i - 1] if i >= 1 else 0.0
            t_out = tangent[i] if i < n_corner else 0.0
            straight = length[i] - t_in - t_out
            prims.append(('line', s, straight, pos.copy(), unit[i].copy(), 0.0, 0.0))
            s += straight
            pos = pos + straight * unit[i]
            if i < n_corner and abs(turn[i]) > 1e-12:
                sign = math.copysign(1.0, turn[i])
                normal = sign * np.array([-unit[i][1], unit[i][0]])
                centre = pos + radius * normal
                start_ang = math.atan2(pos[1] - centre[1], pos[0] - centre[0])
                arc = radius * abs(turn[i])
                prims.append(('arc', s, arc, centre, np.zeros(2), start_ang, sign))
                s += arc
                pos = pts[i + 1] + t_out * unit[i + 1]
        return {
            'prims': prims,
            'total': s,
            'radius': radius,
            'brake_s': s - brake,
            't_brake': (s - brake) / self.speed_mps,
            't_end': (s - brake) / self.speed_mps + self.speed_mps / self.accel_mps2,
        }

    @property
    def length_m(self) -> float:
        """Total path length [m]."""
        return float(self._table['total'])

    @property
    def arrival_time_s(self) -> float:
        """Time at which the reference comes to rest on the last waypoint [s]."""
        return float(self._table['t_end'])

    def _progress(self, t: np.ndarray):
        """Arc length s(t), s_dot, s_ddot: cruise at v, then brake at a_max to rest."""
        tab = self._table
        v, acc = self.speed_mps, self.accel_mps2
        tb = tab['t_brake']
        tau = np.clip(t - tb, 0.0, v / acc)
        cruise = t <= tb
        s = np.where(cruise, v * t, tab['brake_s'] + v * tau - 0.5 * acc * tau * tau)
        s_dot = np.where(cruise, v, v - acc * tau)
        braking = (~cruise) & (t < tab['t_end'])
        s_ddot = np.where(braking, -acc, 0.0)
        return s, s_dot, s_ddot

    def reference(self, t_s):
        """(r, r_dot, r_ddot) at ``t_s`` [s]: each (2,) for a scalar time, (T, 2) for an array.

        Before t = 0 the reference moves back along the first segment at speed v. A scalar time
        equal (bit for bit) to the previous one's reuses its result (copies): a control period asks
        it of a leader's controller, its neighbours and the coordinator.
        """
        t, scalar = _as_time(t_s)
        if not scalar:
            return self._reference_rows(t)
        key = t.tobytes()
        memo = self._table.get('memo')
        if memo is None or memo[0] != key:
            r, r_dot, r_ddot = self._reference_rows(np.atleast_1d(t))
            memo = self._table['memo'] = (key, r[0], r_dot[0], r_ddot[0])
        return memo[1].copy(), memo[2].copy(), memo[3].copy()

    def _reference_rows(self, t: np.ndarray):
        """(r, r_dot, r_ddot), each (T, 2), at the times ``t`` (T,) [s]."""
        t = np.atleast_1d(t)
        s, s_dot, s_ddot = self._progress(t)
        prims = self._table['prims']
        starts = np.array([p[1] for p in prims])
        idx = np.clip(np.searchsorted(starts, s, side='right') - 1, 0, len(prims) - 1)
        r = np.zeros((t.size, 2))
        tang = np.zeros((t.size, 2))
        curv_vec = np.zeros((t.size, 2))  # kappa * normal (points to the centre)
        radius = self._table['radius']
        for j, (kind, s0, ell, p0, direction, ang0, sign) in enumerate(prims):
            sel = idx == j
            if not np.any(sel):
                continue
            ds = s[sel] - s0
            if kind == 'line':
                r[sel] = p0 + ds[:, None] * direction
                tang[sel] = direction
            else:
                ang = ang0 + sign * ds / radius
                radial = np.stack([np.cos(ang), np.sin(ang)], axis=-1)
                r[sel] = p0 + radius * radial
                tang[sel] = sign * np.stack([-np.sin(ang), np.cos(ang)], axis=-1)
                curv_vec[sel] = -radial / radius
        r_dot = s_dot[:, None] * tang
        r_ddot = s_ddot[:, None] * tang + (s_dot**2)[:, None] * curv_vec
        return r, r_dot, r_ddot


Path = Union[SinusoidPath, LinePath, WaypointPath]


@dataclass(frozen=True)
class HeldPath:
    """A leader path that stops at ``t_end_s``: r(t) of ``path`` up to t_end_s, then r(t_end_s)
    with zero velocity and acceleration (the reference steps to rest; the S4 feedback brings the
    robot there). ``formation sweep`` holds every path at the scenario's end to tell a robot still
    catching up from one that never reaches its goal (core/sim/campaign.py ``stuck``).
    """

    path: object
    t_end_s: float

    def reference(self, t_s):
        """(r, r_dot, r_ddot) at ``t_s`` [s]: each (2,) for a scalar time, (T, 2) for an array."""
        t, scalar = _as_time(t_s)
        if scalar:
            if float(t) <= self.t_end_s:
                return self.path.reference(float(t))
            r, r_dot, r_ddot = self.path.reference(self.t_end_s)
            return np.asarray(r, dtype=float), np.zeros_like(r_dot), np.zeros_like(r_ddot)
        t = np.atleast_1d(t)
        r, r_dot, r_ddot = (
            np.array(v, dtype=float).reshape(-1, 2)
            for v in self.path.reference(np.minimum(t, self.t_end_s))
        )
        late = t > self.t_end_s
        r_dot[late] = 0.0
        r_ddot[late] = 0.0
        return r, r_dot, r_ddot


_PATH_KEYS = {
    'sinusoid': (
        {'start_m', 'amplitude_m', 'wavenumber_radpm', 'speed_mps'},
        {'heading_rad', 'stop_s'},
    ),
    'line': ({'start_m', 'heading_rad', 'speed_mps'}, {'stop_s'}),
    'waypoints': ({'points_m', 'speed_mps'}, {'accel_mps2', 'stop_s'}),
}


_SCALAR_KEYS = {'amplitude_m', 'wavenumber_radpm', 'speed_mps', 'heading_rad', 'accel_mps2'}


class TabulatedReference:
    """A leader path's (r, r_dot, r_ddot) at scalar times from a table (the control period's cost).

    The sinusoid's r(t) inverts an arc-length integral by Newton iterations
    (:meth:`SinusoidPath.reference`): about 0.15 ms per call, more than a robot's whole control
    period should cost on a small board. Here the path is evaluated once per ``chunk_s`` of time on
    a grid of ``step_s`` (one vectorised call), and a time in between is the quintic Hermite
    interpolation from (r, r_dot, r_ddot) at the two nodes (:func:`quintic_hermite_k`, the one the
    simulator uses). Times before 0 or past ``max_nodes`` grid nodes go to the path itself.
    """

    def __init__(
        self, path, step_s: float = 0.01, chunk_s: float = 10.0, max_nodes: int = 400_000
    ):
        self.path = path
        self.step_s = float(step_s)
        self._chunk = max(2, int(round(chunk_s / step_s)))
        self._max = int(max_nodes)
        self._tab = np.zeros((0, 6))  # rows [x, y, x_dot, y_dot, x_ddot, y_ddot] at t = j step_s

    def _extend(self, upto: int) -> None:
        n0 = len(self._tab)
        n1 = min(self._max, max(upto + 1, n0 + self._chunk))
        r, rd, rdd = self.path.reference(np.arange(n0, n1) * self.step_s)
        rows = np.concatenate(
            [np.asarray(v, dtype=float).reshape(-1, 2) for v in (r, rd, rdd)], axis=1
        )
        self._tab = np.concatenate([self._tab, rows])

    def reference(self, t_s: float):
        """(r (2,), r_dot (2,), r_ddot (2,)) at scalar ``t_s`` [s]."""
        t = float(t_s)
        h = self.step_s
        u = t / h
        j = int(u) if u >= 0.0 else -1
        if j < 0 or j + 1 >= self._max:
            return self.path.reference(t)
        if j + 1 >= len(self._tab):
            self._extend(j + 1)
        out = np.empty(6)
        tabulated_reference_k(self._tab, j, u - j, h, out)
        return out[0:2], out[2:4], out[4:6]


@njit(cache=True, error_model='numpy', forceinline=True)
def quintic_hermite_k(s, h, p0, v0, a0, p1, v1, a1):
    """Quintic Hermite interpolation on one interval of length ``h`` [s] at the fraction ``s`` in
    [0, 1] from the value, first and second derivative at both ends (p0, v0, a0) and (p1, v1, a1):
    (value, derivative, second derivative); exact at the nodes, C2, error ~ h^6 max|p^(6)|.
    """
    s2 = s * s
    s3 = s2 * s
    s4 = s3 * s
    s5 = s4 * s
    b0 = 1.0 - 10.0 * s3 + 15.0 * s4 - 6.0 * s5
    b1 = s - 6.0 * s3 + 8.0 * s4 - 3.0 * s5
    b2 = 0.5 * s2 - 1.5 * s3 + 1.5 * s4 - 0.5 * s5
    b3 = 0.5 * s3 - s4 + 0.5 * s5
    b4 = -4.0 * s3 + 7.0 * s4 - 3.0 * s5
    b5 = 10.0 * s3 - 15.0 * s4 + 6.0 * s5
    d0 = -30.0 * s2 + 60.0 * s3 - 30.0 * s4
    d1 = 1.0 - 18.0 * s2 + 32.0 * s3 - 15.0 * s4
    d2 = s - 4.5 * s2 + 6.0 * s3 - 2.5 * s4
    d3 = 1.5 * s2 - 4.0 * s3 + 2.5 * s4
    d4 = -12.0 * s2 + 28.0 * s3 - 15.0 * s4
    d5 = -d0
    e0 = -60.0 * s + 180.0 * s2 - 120.0 * s3
    e1 = -36.0 * s + 96.0 * s2 - 60.0 * s3
    e2 = 1.0 - 9.0 * s + 18.0 * s2 - 10.0 * s3
    e3 = 3.0 * s - 12.0 * s2 + 10.0 * s3
    e4 = -24.0 * s + 84.0 * s2 - 60.0 * s3
    e5 = -e0
    v0 = v0 * h
    a0 = a0 * h * h
    v1 = v1 * h
    a1 = a1 * h * h
    r = b0 * p0 + b1 * v0 + b2 * a0 + b3 * a1 + b4 * v1 + b5 * p1
    rd = (d0 * p0 + d1 * v0 + d2 * a0 + d3 * a1 + d4 * v1 + d5 * p1) / h
    rdd = (e0 * p0 + e1 * v0 + e2 * a0 + e3 * a1 + e4 * v1 + e5 * p1) / (h * h)
    return r, rd, rdd


@njit(cache=True, error_model='numpy', forceinline=True)
def tabulated_reference_k(tab, j, s, h, out):
    """(r, r_dot, r_ddot) -> ``out`` (6,) at fraction ``s`` of interval ``j`` of a reference table
    ``tab`` (rows [x, y, x_dot, y_dot, x_ddot, y_ddot] every ``h`` seconds), by
    :func:`quintic_hermite_k` per axis.
    """
    for q in range(2):
        r, rd, rdd = quintic_hermite_k(
            s,
            h,
            tab[j, q],
            tab[j, 2 + q],
            tab[j, 4 + q],
            tab[j + 1, q],
            tab[j + 1, 2 + q],
            tab[j + 1, 4 + q],
        )
        out[q] = r
        out[2 + q] = rd
        out[4 + q] = rdd


def fast_reference(path):
    """``path`` itself when its reference is cheap (line, waypoints: closed form), else a
    :class:`TabulatedReference` of it (the sinusoid). None stays None.
    """
    if isinstance(path, HeldPath):
        return HeldPath(fast_reference(path.path), path.t_end_s)
    if not isinstance(path, SinusoidPath):
        return path
    return TabulatedReference(path)


def path_from_config(cfg) -> Path:
    """Build a path from its scenario mapping (docs/design.md §5).

    For example ``{type: line, start_m: [0, 0],
    heading_rad: 0, speed_mps: 0.05}``; with ``stop_s`` (any type) the path stops there and rests
    (:class:`HeldPath`). Raises ConfigError naming the key (relative to the path).
    """
    path = _path_from_config(cfg)
    stop = cfg.get('stop_s')
    if stop is None:
        return path
    _check_number(stop, 'stop_s', minimum=0.0)
    return HeldPath(path, float(stop))


def _path_from_config(cfg) -> Path:
    if not isinstance(cfg, dict):
        raise ConfigError(f"must be a mapping with a 'type' key (got {type(cfg).__name__})")
    if 'type' not in cfg:
        raise ConfigError(f'missing required key (one of {sorted(_PATH_KEYS)})', 'type')
    kind = cfg['type']
    if not isinstance(kind, str) or kind not in _PATH_KEYS:
        raise ConfigError(
            f'unknown path type {excerpt(kind)} (expected one of {sorted(_PATH_KEYS)})', 'type'
        )
    required, optional = _PATH_KEYS[kind]
    keys = set(cfg) - {'type'}
    for key in sorted(keys - required - optional):
        raise ConfigError(
            f'unknown key for a {kind} path (allowed: {sorted(required | optional)})', key
        )
    for key in sorted(required - keys):
        raise ConfigError(f'missing required key of a {kind} path', key)
    args = {k: cfg[k] for k in keys}
    for key in sorted(keys & _SCALAR_KEYS):
        _check_number(args[key], key)
    if kind == 'sinusoid':
        return SinusoidPath(
            start_m=_vec2(args['start_m'], 'start_m'),
            amplitude_m=float(args['amplitude_m']),
            wavenumber_radpm=float(args['wavenumber_radpm']),
            speed_mps=float(args['speed_mps']),
            heading_rad=float(args.get('heading_rad', 0.0)),
        )
    if kind == 'line':
        return LinePath(
            start_m=_vec2(args['start_m'], 'start_m'),
            heading_rad=float(args['heading_rad']),
            speed_mps=float(args['speed_mps']),
        )
    pts = args['points_m']
    if not isinstance(pts, (list, tuple)):
        raise ConfigError('must be a list of [x, y] points [m]', 'points_m')
    return WaypointPath(
        points_m=tuple(_vec2(p, f'points_m[{i}]') for i, p in enumerate(pts)),
        speed_mps=float(args['speed_mps']),
        accel_mps2=float(args.get('accel_mps2', 0.02)),
    )


# ------------------------------------------------------------------------------------------------
# small validators (ConfigError naming the field)
# ------------------------------------------------------------------------------------------------


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_number(
    value, name: str, *, positive: bool = False, minimum: float | None = None
) -> None:
    if not _is_number(value):
        raise ConfigError(f'must be a number (got {excerpt(value)})', name)
    if not math.isfinite(value):
        raise ConfigError(f'must be finite (got {excerpt(value)})', name)
    if abs(value) > MAX_MAGNITUDE:
        raise ConfigError(f'must be within +-{MAX_MAGNITUDE:g} (got {excerpt(value)})', name)
    if positive and not value > 0:
        raise ConfigError(f'must be > 0 (got {excerpt(value)})', name)
    if minimum is not None and value < minimum:
        raise ConfigError(f'must be >= {minimum} (got {excerpt(value)})', name)


def _check_vec2(value, name: str) -> None:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ConfigError(f'must be a pair [x, y] (got {excerpt(value)})', name)
    for v in value:
        if not _is_number(v) or not math.isfinite(v):
            raise ConfigError(f'must hold two finite numbers (got {excerpt(value)})', name)
        if abs(v) > MAX_MAGNITUDE:
            raise ConfigError(f'must be within +-{MAX_MAGNITUDE:g} (got {excerpt(value)})', name)


def _vec2(value, name: str) -> tuple[float, float]:
    _check_vec2(value, name)
    return float(value[0]), float(value[1])
