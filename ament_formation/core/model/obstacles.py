"""Obstacle motion: prohibited ellipses P_j whose centre and orientation move in time (S6.1).

A centre moves with constant velocity plus an optional sinusoidal oscillation; the orientation
turns at a constant rate. States for all M obstacles at time t come back as arrays, so the
vectorised field code never loops over obstacles in Python.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass
import math

from numba import njit
import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.model.ellipse import (
    boundary_points,
    BOUNDARY_SAMPLES,
    convex_hull,
    ellipses_overlap,
    enclosing_ellipse,
    overlap_one,
    points_inside,
    UNIT_CIRCLE,
)


@dataclass(frozen=True)
class ObstacleSpec:
    """One obstacle: the prohibited region P_j of the controlled point (footprint included)."""

    name: str
    center_m: tuple[float, float]
    semi_axes_m: tuple[float, float]  # (r1, r2) of P_j, r1 >= r2 > 0 after normalisation
    orientation_rad: float = 0.0  # phi_j(0)
    velocity_mps: tuple[float, float] = (0.0, 0.0)
    angular_velocity_radps: float = 0.0
    oscillation_amplitude_m: tuple[float, float] = (0.0, 0.0)  # centre += A sin(2 pi t / T)
    oscillation_period_s: float = 0.0  # 0: no oscillation

    def __post_init__(self) -> None:
        if not self.name or not isinstance(self.name, str):
            raise ConfigError('must be a non-empty string', 'name')
        r1, r2 = self.semi_axes_m
        if not (math.isfinite(r1) and math.isfinite(r2) and r1 > 0 and r2 > 0):
            raise ConfigError(
                f'semi-axes must be finite and > 0 m (got {list(self.semi_axes_m)})', 'semi_axes_m'
            )
        if (
            any(a != 0.0 for a in self.oscillation_amplitude_m)
            and not self.oscillation_period_s > 0
        ):
            raise ConfigError(
                'must be > 0 s when an oscillation amplitude is set', 'oscillation_period_s'
            )

    @property
    def moves(self) -> bool:
        return any(v != 0.0 for v in self.velocity_mps) or any(
            a != 0.0 for a in self.oscillation_amplitude_m
        )

    @property
    def rotates(self) -> bool:
        return self.angular_velocity_radps != 0.0


@dataclass(frozen=True)
class ObstacleStates:
    """All M obstacles at one instant. Shapes: (M, 2) or (M,); world frame, SI units."""

    center_m: np.ndarray  # (M, 2) x~_j
    velocity_mps: np.ndarray  # (M, 2) x~dot_j
    accel_mps2: np.ndarray  # (M, 2) x~ddot_j
    phi_rad: np.ndarray  # (M,)   phi_j
    phi_dot_radps: np.ndarray  # (M,)
    phi_ddot_radps2: np.ndarray  # (M,)
    semi_axes_m: np.ndarray  # (M, 2) (r1, r2) of P_j


ObstacleSnapshot = namedtuple(
    'ObstacleSnapshot', ['c', 'v', 'a', 'phi', 'phi_dot', 'phi_ddot', 'axes', 'static']
)
ObstacleSnapshot.__doc__ = """All M obstacles at one instant as the compiled law and decision read
them: ``c``, ``v``, ``a`` (M, 2) centre [m], velocity [m/s], acceleration [m/s^2]; ``phi``,
``phi_dot``, ``phi_ddot`` (M,) orientation [rad] and its rates [rad/s, rad/s^2]; ``axes`` (M, 2)
semi-axes of P [m]; ``static`` (M,) bool, neither moving nor rotating (S8.2 keeps the sense).
"""


class ObstacleField:
    """Vectorised motion of a fixed set of obstacles."""

    def __init__(self, specs: tuple[ObstacleSpec, ...] | list[ObstacleSpec]):
        self.specs = tuple(specs)
        self.names = tuple(s.name for s in self.specs)
        (
            self._c0,
            self._v,
            self._amp,
            self._w,
            self._phi0,
            self._phidot,
            self._axes,
            self._static,
        ) = obstacle_arrays(self.specs)

    def __len__(self) -> int:
        return len(self.specs)

    @property
    def axes(self) -> np.ndarray:
        """(M, 2) semi-axes of P [m] (read-only use)."""
        return self._axes

    @property
    def static(self) -> np.ndarray:
        """(M,) bool: neither moving nor rotating."""
        return self._static

    def buffers(self) -> tuple:
        """Fresh (centre, velocity, acceleration (M, 2); phi, phi_dot, phi_ddot (M,)) arrays for
        :meth:`fill`.
        """
        m = len(self.specs)
        return (np.empty((m, 2)), np.empty((m, 2)), np.empty((m, 2))) + (
            np.empty(m),
            np.empty(m),
            np.empty(m),
        )

    def fill(self, t_s: float, out: tuple) -> tuple:
        """The motion at ``t_s`` [s] written into ``out`` (from :meth:`buffers`); returns it."""
        obstacle_states(
            float(t_s), self._c0, self._v, self._amp, self._w, self._phi0, self._phidot, *out
        )
        return out

    def at(self, t_s: float) -> ObstacleStates:
        """States of every obstacle at time ``t_s`` [s] (:func:`obstacle_states`)."""
        oc, ov, oa, ophi, ophid, ophidd = self.fill(t_s, self.buffers())
        return ObstacleStates(
            center_m=oc,
            velocity_mps=ov,
            accel_mps2=oa,
            phi_rad=ophi,
            phi_dot_radps=ophid,
            phi_ddot_radps2=ophidd,
            semi_axes_m=self._axes.copy(),
        )


MERGE_REACH = 2.5  # an enclosing ellipse stays inside 2.5 P of its members (section 18)


# implements: S13.3
def avoided_as_one(
    specs, heading_scale: float, limit_cycle_scale: float, starts=()
) -> tuple[tuple[ObstacleSpec, ...], tuple]:
    """The obstacles the law avoids: S13 #3's design rule applied (docs/law-changes.md §18).

    Two obstacles whose heading-test ellipses I = rho_in P (``heading_scale``) overlap leave no
    lane a robot could follow: their limit cycles lead into each other's emergency ellipses and
    a robot between them flips from one to the other. Such obstacles are replaced by one static
    ellipse enclosing both (the minimum-area one), repeatedly, unless

    * the enclosing ellipse reaches beyond :data:`MERGE_REACH` times a member's P (a merge
      would close floor the robots need: a T of a long bar and a small disc, a chain of
      obstacles across the floor), or
    * a robot's controlled point starts (``starts``, (K, 2) [m]) inside its limit cycle
      L = rho_L P (``limit_cycle_scale``): the law pushes a point inside L outwards, and
      between the members that could be through one of them.

    Only obstacles whose region stays in place merge: a static one, or one rotating about a
    fixed centre (its region over time: the disc of radius r1). Moving obstacles never merge.

    Returns (specs, members): the specs in the order of their first member (an unmerged
    obstacle is its own spec; a merged one is static and named ``A+B``: a scenario's names
    never hold a '+'), and for each the indices of the given specs it stands for.
    """
    specs = tuple(specs)
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    regions = []  # [members, centre, phi, semi-axes, parts, hulls] of those that may merge
    region_of = [-1] * len(specs)  # per spec: its region, -1 when it moves
    for j, o in enumerate(specs):
        if not o.moves:
            r1, r2 = o.semi_axes_m
            axes = (max(r1, r2), max(r1, r2)) if o.rotates else (r1, r2)
            part = (np.asarray(o.center_m, float), float(o.orientation_rad), axes)
            region_of[j] = len(regions)
            regions.append([(j,), *part, [part], _outline([part])])
    alive = set(range(len(regions)))
    pairs = _overlapping(regions, sorted(alive), sorted(alive), heading_scale)
    while pairs:
        a, b = min(pairs)
        pairs.discard((a, b))
        region = _merged(regions[a], regions[b], limit_cycle_scale, starts)
        if region is None:
            continue  # refused; it stays refused while neither changes
        regions[a] = region
        alive.discard(b)
        region_of = [a if r == b else r for r in region_of]
        pairs = {q for q in pairs if a not in q and b not in q}
        pairs |= _overlapping(regions, [a], sorted(alive - {a}), heading_scale)
    law, members, seen = [], [], set()
    for j, r in enumerate(region_of):
        idx = (j,) if r < 0 else tuple(sorted(regions[r][0]))
        if r >= 0 and r in seen:
            continue  # a merged obstacle's later member
        seen.add(r)
        members.append(idx)
        if len(idx) == 1:
            law.append(specs[j])
            continue
        _, centre, phi, axes = regions[r][:4]
        law.append(
            ObstacleSpec(
                '+'.join(specs[i].name for i in idx),
                (float(centre[0]), float(centre[1])),
                (float(axes[0]), float(axes[1])),
                float(phi),
            )
        )
    return tuple(law), tuple(members)


def _overlapping(regions, rows_a, rows_b, heading_scale: float) -> set:
    """{(a, b) with a < b}: the regions of ``rows_a`` and ``rows_b`` whose I's overlap
    (bounding circles cull the pairs first).
    """
    qa, qb = np.meshgrid(np.asarray(rows_a, int), np.asarray(rows_b, int), indexing='ij')
    qa, qb = qa.ravel(), qb.ravel()
    keep = qa != qb
    qa, qb = np.minimum(qa, qb)[keep], np.maximum(qa, qb)[keep]
    if not len(qa):
        return set()
    c = np.array([r[1] for r in regions])
    reach = heading_scale * np.array([max(r[3]) for r in regions])
    near = np.linalg.norm(c[qa] - c[qb], axis=1) <= reach[qa] + reach[qb]
    qa, qb = qa[near], qb[near]
    if not len(qa):
        return set()
    phi = np.array([r[2] for r in regions])
    axes = heading_scale * np.array([r[3] for r in regions])
    hit = ellipses_overlap(c[qa], phi[qa], axes[qa], c[qb], phi[qb], axes[qb])
    return {(int(x), int(y)) for x, y in zip(qa[hit], qb[hit])}


def _merged(first, second, limit_cycle_scale: float, starts):
    """The region ([members, centre, phi, semi-axes, member parts, outline]) enclosing two
    regions, or None when :func:`avoided_as_one` does not admit it.
    """
    parts = first[4] + second[4]
    (coarse, dense) = hulls = _outline([first[5], second[5]])
    centre, phi, (r1, r2) = enclosing_ellipse(coarse, contain=dense)
    grow = 1.0 / math.cos(math.pi / BOUNDARY_SAMPLES)  # the true boundary between two samples
    axes = (r1 * grow, r2 * grow)
    if len(starts) and _inside(starts, (centre, phi, axes), limit_cycle_scale).any():
        return None
    outline = boundary_points(centre, phi, axes)[0]
    if not _near_any(outline, parts, MERGE_REACH).all():
        return None
    return [first[0] + second[0], centre, phi, axes, parts, hulls]


def _outline(pieces) -> tuple:
    """(coarse, dense): the convex hulls of 32 and of BOUNDARY_SAMPLES boundary points of
    ``pieces``, each a part (centre, phi, semi-axes) or the outline of a region: what an
    enclosing ellipse must hold, without the interior points that only slow it down.
    """
    coarse, dense = [], []
    for piece in pieces:
        if len(piece) == 2:
            coarse.append(piece[0])
            dense.append(piece[1])
        else:
            coarse.append(boundary_points(*piece, n=32)[0])
            dense.append(boundary_points(*piece)[0])
    return convex_hull(np.concatenate(coarse)), convex_hull(np.concatenate(dense))


def _near_any(pts, parts, scale: float) -> np.ndarray:
    """(S,) bool: which ``pts`` (S, 2) lie in any of the ellipses ``parts`` (centre, phi,
    semi-axes) scaled by ``scale``.
    """
    centres = np.array([p[0] for p in parts], float)
    phis = np.array([p[1] for p in parts], float)
    axes = scale * np.array([p[2] for p in parts], float)
    hit = points_inside(np.broadcast_to(pts, (len(parts), *pts.shape)), centres, phis, axes)
    return hit.any(axis=0)


def _inside(pts, part, scale: float) -> np.ndarray:
    """(S,) bool: which ``pts`` (S, 2) lie in the ellipse ``part`` (centre, phi, semi-axes)
    scaled by ``scale``.
    """
    centre, phi, axes = part
    scaled = scale * np.asarray(axes, float)[None]
    return points_inside(pts[None], np.asarray(centre)[None], np.array([phi]), scaled)[0]


def obstacle_arrays(obs) -> tuple:
    """Motion parameters of obstacle specs for :func:`obstacle_states`: (c0 (M, 2), v (M, 2),
    oscillation amplitude (M, 2), oscillation rate w (M,) [rad/s], phi0 (M,), phi_dot (M,),
    semi-axes of P (M, 2), static (M,) bool).
    """
    obs = tuple(obs)
    m = len(obs)
    c0 = np.array([o.center_m for o in obs], dtype=float).reshape(m, 2)
    vel = np.array([o.velocity_mps for o in obs], dtype=float).reshape(m, 2)
    amp = np.array([o.oscillation_amplitude_m for o in obs], dtype=float).reshape(m, 2)
    period = np.array([o.oscillation_period_s for o in obs], dtype=float)
    omega = np.where(period > 0, 2 * np.pi / np.where(period > 0, period, 1.0), 0.0)
    phi0 = np.array([o.orientation_rad for o in obs], dtype=float)
    phid = np.array([o.angular_velocity_radps for o in obs], dtype=float)
    axes = np.array([o.semi_axes_m for o in obs], dtype=float).reshape(m, 2)
    static = np.array([not (o.moves or o.rotates) for o in obs], dtype=np.bool_)
    return c0, vel, amp, omega, phi0, phid, axes, static


# implements: S6.1
@njit(cache=True, error_model='numpy', forceinline=True)
def obstacle_states(t, c0, vel, amp, omega, phi0, phid, oc, ov, oa, ophi, ophid, ophidd):
    """Centre, velocity, acceleration, orientation and rates of every obstacle at t
    (into the outputs).

    Motion model of :class:`ament_formation.core.model.obstacles.ObstacleField`: c = c0 + v t + A
    sin(w
    t),
    phi = phi0 + phi_dot t.
    """
    for j in range(c0.shape[0]):
        s = math.sin(omega[j] * t)
        c = math.cos(omega[j] * t)
        for q in range(2):
            oc[j, q] = c0[j, q] + vel[j, q] * t + amp[j, q] * s
            ov[j, q] = vel[j, q] + amp[j, q] * omega[j] * c
            oa[j, q] = -amp[j, q] * omega[j] * omega[j] * s
        ophi[j] = phi0[j] + phid[j] * t
        ophid[j] = phid[j]
        ophidd[j] = 0.0


def first_overlaps(times, c0, vel, amp, omega, phi0, phid, axes, pairs) -> np.ndarray:
    """For each pair (a, b) of ``pairs`` (P, 2) of obstacles (motion of :func:`obstacle_arrays`,
    region semi-axes ``axes`` (M, 2)): the index of the first of ``times`` (T,) [s] at which
    their regions overlap (:func:`~ament_formation.core.model.ellipse.ellipses_overlap`), -1
    if never. The instants where their bounding circles are apart are not sampled.
    """
    out = np.full(len(pairs), -1, dtype=np.int64)
    if len(pairs):
        _first_overlaps(
            np.asarray(times, float), c0, vel, amp, omega, phi0, phid, np.asarray(axes, float),
            np.asarray(pairs, np.int64), *UNIT_CIRCLE, out,
        )  # fmt: skip
    return out


@njit(cache=True, error_model='numpy')
def _first_overlaps(times, c0, vel, amp, omega, phi0, phid, axes, pairs, cos_t, sin_t, out):
    ca, cb = np.empty(2), np.empty(2)
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        reach = max(axes[a, 0], axes[a, 1]) + max(axes[b, 0], axes[b, 1])
        for k in range(times.shape[0]):
            t = times[k]
            sa, sb = math.sin(omega[a] * t), math.sin(omega[b] * t)
            for q in range(2):
                ca[q] = c0[a, q] + vel[a, q] * t + amp[a, q] * sa
                cb[q] = c0[b, q] + vel[b, q] * t + amp[b, q] * sb
            if math.hypot(ca[0] - cb[0], ca[1] - cb[1]) > reach:
                continue
            pa, pb = phi0[a] + phid[a] * t, phi0[b] + phid[b] * t
            if overlap_one(
                ca, math.cos(pa), math.sin(pa), axes[a], cb, math.cos(pb), math.sin(pb),
                axes[b], cos_t, sin_t,
            ):  # fmt: skip
                out[p] = k
                break


@njit(cache=True, error_model='numpy')
def obstacle_pairs(p, oc, radius):
    """(robot row, obstacle row) of every obstacle j whose centre is within ``radius[j]`` [m] of
    robot p in x and in y (a square), by a uniform grid of the obstacles (near-linear in N + M):
    p (N, 2), oc (M, 2) -> (P, 2) int.
    """
    n, m = p.shape[0], oc.shape[0]
    out = np.empty((max(16, 4 * n), 2), dtype=np.int64)
    if n == 0 or m == 0:
        return out[:0]
    cell = max(radius.max(), 1e-6)
    x0, y0 = oc[:, 0].min(), oc[:, 1].min()
    ix = np.empty(m, dtype=np.int64)
    iy = np.empty(m, dtype=np.int64)
    for j in range(m):
        ix[j] = int((oc[j, 0] - x0) / cell)
        iy[j] = int((oc[j, 1] - y0) / cell)
    nx, ny = ix.max() + 1, iy.max() + 1
    if nx * ny > 16 * m + 4096:  # sparse, huge arena: one row of cells per x
        ny = 1
        iy[:] = 0
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    for j in range(m):
        start[ix[j] * ny + iy[j] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    members = np.empty(m, dtype=np.int64)
    for j in range(m):
        c = ix[j] * ny + iy[j]
        members[fill[c]] = j
        fill[c] += 1
    cnt = 0
    for i in range(n):
        cx0 = int(math.floor((p[i, 0] - x0) / cell))
        cy0 = int(math.floor((p[i, 1] - y0) / cell)) if ny > 1 else 0
        for cx in range(max(0, cx0 - 1), min(nx, cx0 + 2)):
            for cy in range(max(0, cy0 - 1), min(ny, cy0 + 2)):
                c = cx * ny + cy
                for q in range(start[c], start[c + 1]):
                    j = members[q]
                    if abs(p[i, 0] - oc[j, 0]) <= radius[j] and abs(
                            p[i, 1] - oc[j, 1]) <= radius[j]:
                        if cnt >= out.shape[0]:
                            grown = np.empty((2 * out.shape[0], 2), dtype=np.int64)
                            grown[:cnt] = out[:cnt]
                            out = grown
                        out[cnt, 0] = i
                        out[cnt, 1] = j
                        cnt += 1
    return out[:cnt]
