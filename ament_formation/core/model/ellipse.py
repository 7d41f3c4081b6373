"""Ellipse geometry (S6.2, S8): body coordinates and the ellipse function h, the first time a ray
enters an ellipse, whether a segment meets it, and the exact Euclidean signed distance of points to
its boundary (metrics, the live view).

An ellipse is (centre, orientation phi [rad], semi-axes r1, r2 [m]); z = p - centre. Scalar
functions are numba kernels (``@njit(cache=True)``) the automaton and the law call; the signed
distance is vectorised numpy.
"""

from __future__ import annotations

import math

from numba import njit
import numpy as np

INF = math.inf


@njit(cache=True, error_model='numpy', forceinline=True)
def ellipse_coords(zx, zy, phi, r1, r2):
    """Normalised body coordinates (U, W) = (u/r1, w/r2) of z (S6.2); h = U^2 + W^2 - 1."""
    c = math.cos(phi)
    s = math.sin(phi)
    return (c * zx + s * zy) / r1, (-s * zx + c * zy) / r2


# implements: S6.2
@njit(cache=True, error_model='numpy', forceinline=True)
def h_value(zx, zy, phi, r1, r2):
    """Ellipse function h = z^T A z - 1 of the ellipse (r1, r2, phi) (S6.2)."""
    u, w = ellipse_coords(zx, zy, phi, r1, r2)
    return u * u + w * w - 1.0


@njit(cache=True, error_model='numpy', forceinline=True)
def ray_time(zx, zy, vx, vy, phi, r1, r2):
    """Smallest lambda >= 0 with z + lambda v inside the ellipse (S8 heading test).

    0 when z is already inside, +inf when the ray misses. With v a velocity, lambda is a time [s].
    """
    u, w = ellipse_coords(zx, zy, phi, r1, r2)
    du, dw = ellipse_coords(vx, vy, phi, r1, r2)
    q0 = u * u + w * w - 1.0
    if q0 <= 0.0:
        return 0.0
    a = du * du + dw * dw
    if a <= 1e-24:
        return INF
    b = 2.0 * (u * du + w * dw)
    disc = b * b - 4.0 * a * q0
    if disc < 0.0:
        return INF
    lam = (-b - math.sqrt(disc)) / (2.0 * a)
    if lam < 0.0:
        return INF
    return lam


@njit(cache=True, error_model='numpy', forceinline=True)
def segment_hits(p0x, p0y, p1x, p1y, cx, cy, phi, r1, r2):
    """True when the segment [p0, p1] meets the ellipse (centre c) (S8.3 item 1)."""
    u0, w0 = ellipse_coords(p0x - cx, p0y - cy, phi, r1, r2)
    u1, w1 = ellipse_coords(p1x - cx, p1y - cy, phi, r1, r2)
    du = u1 - u0
    dw = w1 - w0
    a = du * du + dw * dw
    lam = 0.0
    if a > 1e-24:
        lam = -(u0 * du + w0 * dw) / a
        lam = min(1.0, max(0.0, lam))
    u = u0 + lam * du
    w = w0 + lam * dw
    return u * u + w * w <= 1.0


def _distance_first_quadrant(y0, y1, e0, e1, iterations=200):
    """Eberly's robust point-ellipse distance for y0, y1 >= 0, e0 >= e1 > 0 (vectorised)."""
    # y1 > 0 and y0 > 0: bisection on the root s of F(s) = (r0 z0/(s + r0))^2 + (z1/(s + 1))^2 - 1
    z0 = y0 / e0
    z1 = y1 / e1
    g = z0 * z0 + z1 * z1 - 1.0
    r0 = (e0 / e1) ** 2
    n0 = r0 * z0
    s0 = z1 - 1.0
    s1 = np.where(g < 0.0, 0.0, np.hypot(n0, z1) - 1.0)
    s = 0.5 * (s0 + s1)
    tiny = np.finfo(float).eps
    for it in range(iterations):
        s = 0.5 * (s0 + s1)
        ratio0 = n0 / (s + r0)
        ratio1 = z1 / (s + 1.0)
        val = ratio0 * ratio0 + ratio1 * ratio1 - 1.0
        pos = val > 0.0
        s0 = np.where(pos, s, s0)
        s1 = np.where(pos, s1, s)
        if it % 8 == 7 and not np.any(s1 - s0 > 2.0 * tiny * np.maximum(np.abs(s), 1.0)):
            break  # every bracket has collapsed to rounding level
    s = 0.5 * (s0 + s1)
    x0 = r0 * y0 / (s + r0)
    x1 = y1 / (s + 1.0)
    general = np.hypot(x0 - y0, x1 - y1)
    general = np.where(g == 0.0, 0.0, general)
    # y1 > 0, y0 == 0: nearest point (0, e1)
    on_minor = np.abs(y1 - e1)
    # y1 == 0
    numer0 = e0 * y0
    denom0 = e0 * e0 - e1 * e1
    inner = numer0 < denom0
    xde0 = np.where(inner, numer0 / np.where(denom0 > 0, denom0, 1.0), 1.0)
    xa = e0 * xde0
    xb = e1 * np.sqrt(np.maximum(1.0 - xde0 * xde0, 0.0))
    on_major = np.where(inner, np.hypot(xa - y0, xb), np.abs(y0 - e0))
    return np.where(y1 > 0.0, np.where(y0 > 0.0, general, on_minor), on_major)


def signed_distance_to_ellipse(points, center, phi, r1, r2):
    """Exact Euclidean signed distance of ``points`` (K, 2) to the ellipse boundary, < 0 inside.

    ``center`` (2,) or (K, 2), ``phi`` [rad] and semi-axes ``r1``, ``r2`` [m] scalars or (K,).
    Not the algebraic h: the true distance to the nearest boundary point. Returns (K,) [m].
    """
    points = np.asarray(points, dtype=float)
    z = points - np.asarray(center, dtype=float)
    k = z.shape[0]
    phi = np.broadcast_to(np.asarray(phi, dtype=float), (k,))
    r1 = np.broadcast_to(np.asarray(r1, dtype=float), (k,))
    r2 = np.broadcast_to(np.asarray(r2, dtype=float), (k,))
    c, s = np.cos(phi), np.sin(phi)
    u = c * z[:, 0] + s * z[:, 1]
    w = -s * z[:, 0] + c * z[:, 1]
    swap = r2 > r1  # make e0 >= e1 along the first coordinate
    e0 = np.where(swap, r2, r1)
    e1 = np.where(swap, r1, r2)
    y0 = np.abs(np.where(swap, w, u))
    y1 = np.abs(np.where(swap, u, w))
    with np.errstate(divide='ignore', invalid='ignore'):
        dist = _distance_first_quadrant(y0, y1, e0, e1)
    inside = (y0 / e0) ** 2 + (y1 / e1) ** 2 < 1.0
    return np.where(inside, -dist, dist)


def ellipse_outline(semi_axes_m, n: int = 64) -> np.ndarray:
    """(n + 1, 2) closed polyline [m] of the ellipse with semi-axes (r1, r2) in its own frame
    (major axis r1 along x; the first point is repeated at the end).
    """
    t = np.linspace(0.0, 2.0 * np.pi, n + 1)
    out = np.stack((semi_axes_m[0] * np.cos(t), semi_axes_m[1] * np.sin(t)), axis=1)
    out[-1] = out[0]
    return out


BOUNDARY_SAMPLES = 256  # points per ellipse of the sampled region tests below


def boundary_points(center, phi, semi_axes, n: int = BOUNDARY_SAMPLES) -> np.ndarray:
    """(K, n, 2) points on the boundaries of K ellipses: centres (K, 2) [m], orientations (K,)
    [rad], semi-axes (K, 2) [m].
    """
    c, phi, axes = np.atleast_2d(center), np.atleast_1d(phi), np.atleast_2d(semi_axes)
    ang = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    u = axes[:, 0:1] * np.cos(ang)
    w = axes[:, 1:2] * np.sin(ang)
    cp, sp = np.cos(phi)[:, None], np.sin(phi)[:, None]
    return np.stack([c[:, 0:1] + cp * u - sp * w, c[:, 1:2] + sp * u + cp * w], axis=-1)


def points_inside(pts, c, phi, axes) -> np.ndarray:
    """(K, S) bool: which of ``pts`` (K, S, 2) lie in the K ellipses (centres (K, 2), phi (K,),
    semi-axes (K, 2)).
    """
    z = pts - c[:, None, :]
    cp, sp = np.cos(phi)[:, None], np.sin(phi)[:, None]
    u = cp * z[..., 0] + sp * z[..., 1]
    w = -sp * z[..., 0] + cp * z[..., 1]
    return (u / axes[:, 0:1]) ** 2 + (w / axes[:, 1:2]) ** 2 <= 1.0


def ellipses_overlap(c1, phi1, axes1, c2, phi2, axes2) -> np.ndarray:
    """Whether two ellipses (closed regions) intersect, for K pairs at once.

    Parameters: centres (K, 2) [m], orientations (K,) [rad], semi-axes (K, 2) [m].
    Exact up to the boundary sampling (:data:`BOUNDARY_SAMPLES` points per ellipse): overlap iff
    a boundary point of one lies inside the other or one centre lies inside the other (the
    points and tests of :func:`boundary_points` and :func:`points_inside`, in a kernel that
    stops at the first point inside).
    Returns (K,) bool.
    """
    c1, c2 = np.atleast_2d(np.asarray(c1, float)), np.atleast_2d(np.asarray(c2, float))
    phi1, phi2 = np.atleast_1d(np.asarray(phi1, float)), np.atleast_1d(np.asarray(phi2, float))
    axes1 = np.atleast_2d(np.asarray(axes1, float))
    axes2 = np.atleast_2d(np.asarray(axes2, float))
    k = max(len(c1), len(c2), len(phi1), len(phi2), len(axes1), len(axes2))
    c1, c2 = np.broadcast_to(c1, (k, 2)), np.broadcast_to(c2, (k, 2))
    phi1, phi2 = np.broadcast_to(phi1, (k,)), np.broadcast_to(phi2, (k,))
    axes1, axes2 = np.broadcast_to(axes1, (k, 2)), np.broadcast_to(axes2, (k, 2))
    out = np.empty(k, dtype=np.bool_)
    _overlap_kernel(
        c1, np.cos(phi1), np.sin(phi1), axes1, c2, np.cos(phi2), np.sin(phi2), axes2,
        *UNIT_CIRCLE, out,
    )  # fmt: skip
    return out


_ANGLES = np.linspace(0.0, 2 * np.pi, BOUNDARY_SAMPLES, endpoint=False)
UNIT_CIRCLE = (np.cos(_ANGLES), np.sin(_ANGLES))  # as boundary_points computes them


@njit(cache=True, error_model='numpy')
def _inside_one(x, y, c, cp, sp, axes) -> bool:
    """Whether (x, y) lies in the ellipse (centre c, cos/sin of its orientation, semi-axes)."""
    z0, z1 = x - c[0], y - c[1]
    u = cp * z0 + sp * z1
    w = -sp * z0 + cp * z1
    return (u / axes[0]) ** 2 + (w / axes[1]) ** 2 <= 1.0


@njit(cache=True, error_model='numpy')
def _boundary_inside(c1, cp1, sp1, axes1, c2, cp2, sp2, axes2, cos_t, sin_t) -> bool:
    """Whether a boundary sample of ellipse 1 lies in ellipse 2."""
    for i in range(cos_t.shape[0]):
        u = axes1[0] * cos_t[i]
        w = axes1[1] * sin_t[i]
        if _inside_one(c1[0] + cp1 * u - sp1 * w, c1[1] + sp1 * u + cp1 * w, c2, cp2, sp2, axes2):
            return True
    return False


@njit(cache=True, error_model='numpy')
def _half_width(nx, ny, cp, sp, axes) -> float:
    """The support of an ellipse (orientation cos/sin, semi-axes) along the unit (nx, ny),
    about its centre: sqrt(n' A n), A = R diag(r1^2, r2^2) R'.
    """
    u = cp * nx + sp * ny
    w = -sp * nx + cp * ny
    return math.sqrt((axes[0] * u) ** 2 + (axes[1] * w) ** 2)


@njit(cache=True, error_model='numpy')
def _separated(c1, cp1, sp1, axes1, c2, cp2, sp2, axes2) -> bool:
    """Whether a line separates the two ellipses, tried along the line of centres and each
    one's axes: then no point of one lies in the other (a proof, never a guess; False only
    means not shown).
    """
    dx, dy = c2[0] - c1[0], c2[1] - c1[1]
    d = math.hypot(dx, dy)
    gap = 1e-12 * (1.0 + d)  # rounding of the sums below
    if d > 0.0:
        nx, ny = dx / d, dy / d
        if d > _half_width(nx, ny, cp1, sp1, axes1) + _half_width(nx, ny, cp2, sp2, axes2) + gap:
            return True
    for nx, ny in ((cp1, sp1), (-sp1, cp1), (cp2, sp2), (-sp2, cp2)):
        along = abs(nx * dx + ny * dy)
        if along > _half_width(nx, ny, cp1, sp1, axes1) + _half_width(
            nx, ny, cp2, sp2, axes2
        ) + gap:
            return True
    return False


@njit(cache=True, error_model='numpy')
def _overlap_kernel(c1, cp1, sp1, axes1, c2, cp2, sp2, axes2, cos_t, sin_t, out):
    """:func:`ellipses_overlap`'s test for each of K pairs, into ``out`` (K,). Pairs a line
    separates are not sampled.
    """
    for k in range(out.shape[0]):
        out[k] = overlap_one(
            c1[k], cp1[k], sp1[k], axes1[k], c2[k], cp2[k], sp2[k], axes2[k], cos_t, sin_t
        )


@njit(cache=True, error_model='numpy')
def overlap_one(c1, cp1, sp1, axes1, c2, cp2, sp2, axes2, cos_t, sin_t) -> bool:
    """:func:`ellipses_overlap` for one pair in a kernel: centres (2,), cos and sin of the
    orientations, semi-axes (2,), the unit circle's samples (``UNIT_CIRCLE``).
    """
    if _separated(c1, cp1, sp1, axes1, c2, cp2, sp2, axes2):
        return False
    return (
        _inside_one(c1[0], c1[1], c2, cp2, sp2, axes2)
        or _inside_one(c2[0], c2[1], c1, cp1, sp1, axes1)
        or _boundary_inside(c1, cp1, sp1, axes1, c2, cp2, sp2, axes2, cos_t, sin_t)
        or _boundary_inside(c2, cp2, sp2, axes2, c1, cp1, sp1, axes1, cos_t, sin_t)
    )


@njit(cache=True, error_model='numpy')
def _inverse3(x):
    """The inverse of a 3 x 3 matrix (cofactors)."""
    out = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            r1, r2 = (c + 1) % 3, (c + 2) % 3
            c1, c2 = (r + 1) % 3, (r + 2) % 3
            out[r, c] = x[r1, c1] * x[r2, c2] - x[r1, c2] * x[r2, c1]
    det = x[0, 0] * out[0, 0] + x[0, 1] * out[1, 0] + x[0, 2] * out[2, 0]
    return out / det


@njit(cache=True, error_model='numpy')
def _mvee_weights(pts, tol, max_iter):
    """The weights u (S,) of Khachiyan's algorithm with Todd-Yildirim away steps for the
    minimum-volume ellipse of ``pts`` (S, 2): stops when every lifted point's m is within a
    factor 1 +- ``tol`` of 3 on the support.
    """
    s = pts.shape[0]
    q = np.ones((3, s))
    q[0, :] = pts[:, 0]
    q[1, :] = pts[:, 1]
    u = np.full(s, 1.0 / s)
    m = np.empty(s)
    for _ in range(max_iter):
        x = np.zeros((3, 3))  # sum of u q q' (no BLAS in the kernels)
        for i in range(s):
            for r in range(3):
                for c in range(3):
                    x[r, c] += u[i] * q[r, i] * q[c, i]
        xi = _inverse3(x)
        for i in range(s):
            acc = 0.0
            for r in range(3):
                for c in range(3):
                    acc += q[r, i] * xi[r, c] * q[c, i]
            m[i] = acc
        up, down = 0, -1
        for i in range(s):
            if m[i] > m[up]:
                up = i
            if u[i] > 0.0 and (down < 0 or m[i] < m[down]):
                down = i
        grow, shrink = m[up] / 3.0 - 1.0, 1.0 - m[down] / 3.0
        if max(grow, shrink) <= tol:
            break
        if grow >= shrink:  # towards the farthest point
            j, step = up, (m[up] - 3.0) / (3.0 * (m[up] - 1.0))
        else:  # away from the nearest supporting point
            j = down
            step = max((m[down] - 3.0) / (3.0 * (m[down] - 1.0)), -u[j] / (1.0 - u[j]))
        u *= 1.0 - step
        u[j] += step
        for i in range(s):
            if u[i] < 0.0:
                u[i] = 0.0
    return u


@njit(cache=True, error_model='numpy')
def _hull_chain(pts, out):
    """Andrew's monotone chain over ``pts`` (S, 2) sorted by x, then y: the hull's vertices,
    counter-clockwise, written to ``out`` (2 S, 2); returns how many. Duplicate and collinear
    points are dropped.
    """
    s = pts.shape[0]
    k = 0
    for half in range(2):
        first = k
        for n in range(s):
            i = n if half == 0 else s - 1 - n
            px, py = pts[i, 0], pts[i, 1]
            while k - first >= 2:
                ax, ay = out[k - 2, 0], out[k - 2, 1]
                bx, by = out[k - 1, 0], out[k - 1, 1]
                if (bx - ax) * (py - ay) - (by - ay) * (px - ax) > 0.0:
                    break
                k -= 1
            out[k, 0], out[k, 1] = px, py
            k += 1
        k -= 1  # each half's last point is the other's first
    return k


def convex_hull(points) -> np.ndarray:
    """The vertices of the convex hull of ``points`` (S, 2), counter-clockwise (Andrew's
    monotone chain).
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    pts = pts[np.lexsort((pts[:, 1], pts[:, 0]))]  # by x, then y
    if len(pts) >= 3:
        out = np.empty((2 * len(pts), 2))
        k = _hull_chain(pts, out)
        if k >= 3:
            return out[:k].copy()
        pts = out[:k]  # the two ends of a line (twice the same point when all are)
    return np.unique(pts, axis=0)


def enclosing_ellipse(points, tol: float = 1e-5, max_iter: int = 100_000, contain=None):
    """The minimum-area ellipse enclosing ``points`` (S, 2) [m] (Khachiyan's algorithm with the
    Todd-Yildirim away steps, to relative accuracy ``tol``), as (centre (2,), orientation [rad],
    semi-axes (r1 >= r2)), scaled so every point, and every point of ``contain`` (K, 2) when
    given, lies inside.
    """
    pts = np.asarray(points, dtype=float)
    if len(pts) > 8:
        pts = convex_hull(pts)  # the same ellipse; interior points only slow the iteration
    u = _mvee_weights(pts, tol, max_iter)
    c = pts.T @ u
    cov = (pts.T * u) @ pts - np.outer(c, c)
    a = np.linalg.inv(cov) / 2.0  # {x : (x - c)' A (x - c) <= 1}
    z = (pts if contain is None else np.concatenate([pts, contain])) - c
    a /= max(1.0, float(np.max(np.einsum('si,ij,sj->s', z, a, z))))  # every point inside
    evals, evecs = np.linalg.eigh(a)  # ascending: the first is the major axis
    r1, r2 = 1.0 / np.sqrt(evals)
    phi = math.atan2(evecs[1, 0], evecs[0, 0])
    return c, phi, (float(r1), float(r2))
