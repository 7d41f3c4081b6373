"""The floor's edges, in one place (docs/control-law.md S16).

A scenario may declare its floor (``floor: {x_m, y_m}``); :class:`LawParams` carries its four
edges (infinite when undeclared). The law meets the floor three ways, all here:

* S16.1 the edges are walls of the braking barrier (:func:`floor_edges`, read by
  core/control/safety.py);
* S16.2 a rotation sense whose limit-cycle arc to the goal would pass closer to an edge than a
  body radius plus the barrier gap is not chosen when the other sense's arc does not
  (:func:`floor_side`, at an obstacle entry, at a reversal of the progress monitor, and on
  the obstacle when the floor has closed the way ahead since the entry);
* S16.3 a mutual pair's drift target keeps the circle the pair turns on inside the floor
  (:func:`drift_off_edges`).
"""

from __future__ import annotations

import math

from numba import njit

from ament_formation.core.control.limit_cycle import anomaly

TWO_PI = 2.0 * math.pi


@njit(cache=True, error_model='numpy', forceinline=True)
def floor_edges(px, py, rb, prm):
    """S16.1: the four edges seen from a body of radius ``rb`` about p: ((gap [m], inward normal
    x, y), ...) (gaps infinite without a floor).
    """
    return (
        (px - prm.floor_x_min_m - rb, 1.0, 0.0),
        (prm.floor_x_max_m - px - rb, -1.0, 0.0),
        (py - prm.floor_y_min_m - rb, 0.0, 1.0),
        (prm.floor_y_max_m - py - rb, 0.0, -1.0),
    )


@njit(cache=True, error_model='numpy', forceinline=True)
def has_floor(prm):
    """Whether the scenario declares a floor (its edges are finite)."""
    return math.isfinite(prm.floor_x_max_m)


@njit(cache=True, error_model='numpy', forceinline=True)
def near_floor(px, py, rb, prm):
    """Whether the body (radius ``rb`` about p) is within ``safety_range_m`` of an edge."""
    g = min(
        px - prm.floor_x_min_m,
        prm.floor_x_max_m - px,
        py - prm.floor_y_min_m,
        prm.floor_y_max_m - py,
    )
    return g - rb < prm.safety_range_m


@njit(cache=True, error_model='numpy', forceinline=True)
def _arc_leaves(cx, cy, phi, big_r1, big_r2, psi0, dpsi, clear, prm):
    """Whether the limit cycle's arc from anomaly ``psi0`` over ``dpsi`` (signed) passes closer
    than ``clear`` to an edge (16 samples per turn, ends included).
    """
    c = math.cos(phi)
    s = math.sin(phi)
    m = max(2, int(abs(dpsi) / TWO_PI * 16.0) + 2)
    for q in range(m + 1):
        psi = psi0 + dpsi * q / m
        u = big_r1 * math.cos(psi)
        w = big_r2 * math.sin(psi)
        x = cx + c * u - s * w
        y = cy + s * u + c * w
        if (
            x - clear < prm.floor_x_min_m
            or x + clear > prm.floor_x_max_m
            or y - clear < prm.floor_y_min_m
            or y + clear > prm.floor_y_max_m
        ):
            return True
    return False


@njit(cache=True, error_model='numpy', forceinline=True)
def cycle_inside(cx, cy, phi, big_r1, big_r2, clear, prm):
    """Whether the whole limit cycle L = (big_r1, big_r2) about c keeps ``clear`` from every
    edge, by a bound: a point c + R(phi) (u, w) with |u| <= big_r1, |w| <= big_r2 lies within
    |cos phi| big_r1 + |sin phi| big_r2 of c in x (and alike in y), and a relative 1e-9 covers
    the rounding of :func:`_arc_leaves`'s samples. True: no arc of L leaves the floor (so
    :func:`floor_side` keeps the sense, the other way open); False says nothing.
    """
    c = abs(math.cos(phi))
    s = abs(math.sin(phi))
    bx = c * big_r1 + s * big_r2
    by = s * big_r1 + c * big_r2
    tol = 1e-9 * (1.0 + abs(cx) + abs(cy) + bx + by + clear)
    return (
        cx - bx - clear - tol >= prm.floor_x_min_m
        and cx + bx + clear + tol <= prm.floor_x_max_m
        and cy - by - clear - tol >= prm.floor_y_min_m
        and cy + by + clear + tol <= prm.floor_y_max_m
    )


# implements: S16
@njit(cache=True, error_model='numpy', forceinline=True)
def floor_side(sense, px, py, gx, gy, cx, cy, phi, big_r1, big_r2, clear, prm):
    """S16.2: the sense that keeps to the floor on the limit cycle L = (big_r1, big_r2) about c:
    ``sense``, unless its arc from p to the goal g passes closer than ``clear`` to an edge while
    the other sense's arc does not. Returns (sense, other_open): ``other_open`` tells whether the
    arc in the other sense keeps to the floor.
    """
    psi_a = anomaly(px - cx, py - cy, phi, big_r1, big_r2)
    psi_g = anomaly(gx - cx, gy - cy, phi, big_r1, big_r2)
    ccw = (psi_g - psi_a) % TWO_PI
    arc = ccw if sense > 0.0 else ccw - TWO_PI
    other = arc - TWO_PI if sense > 0.0 else arc + TWO_PI
    own_leaves = _arc_leaves(cx, cy, phi, big_r1, big_r2, psi_a, arc, clear, prm)
    other_leaves = _arc_leaves(cx, cy, phi, big_r1, big_r2, psi_a, other, clear, prm)
    if own_leaves and not other_leaves:
        return -sense, True
    return sense, not other_leaves or own_leaves


@njit(cache=True, error_model='numpy', inline='always')
def _off(w, lo, hi, cap, push_m):
    """A drift component ``w`` with room ``lo`` toward the lower edge and ``hi`` toward the upper
    one (< 0: the circle crosses that edge): away from a crossed edge, never toward it.
    """
    if lo < 0.0 and hi >= 0.0:
        return max(w, 0.0, min(cap, -lo * cap / push_m))
    if hi < 0.0 and lo >= 0.0:
        return min(w, 0.0, -min(cap, -hi * cap / push_m))
    return w


@njit(cache=True, error_model='numpy', forceinline=True)
def drift_off_edges(wx, wy, mx, my, room, cap, prm):
    """S16.3: a pair's drift target (wx, wy) [m/s] with the pair's centre (mx, my) needing
    ``room`` [m] to each edge: a component toward a crossed edge is dropped and one away from it
    added (cap x deficit / ``floor_push_m``, at most ``cap``).
    """
    wx = _off(wx, mx - room - prm.floor_x_min_m, prm.floor_x_max_m - room - mx, cap,
              prm.floor_push_m)
    wy = _off(wy, my - room - prm.floor_y_min_m, prm.floor_y_max_m - room - my, cap,
              prm.floor_push_m)
    return wx, wy
