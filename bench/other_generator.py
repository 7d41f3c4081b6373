"""Random scenarios drawn by rules independent of the project's own generator.

    python bench/other_generator.py --out DIR --count N --seed S [--families column,merge,...]

writes ``DIR/00000-<name>.yaml`` ... (exactly N files; DIR is created and must be empty) and prints
one summary line: the files written per kind and the draws rejected, by kind and reason. The
same seed gives byte-identical files (file i depends on the seed, i and its kind only:
``numpy.random.default_rng([SALT, seed, i, draw])``). Exit 0 on success, 2 with one line on bad
arguments, 1 when a kind finds no acceptable draw in :data:`MAX_DRAWS`.

Its purpose is campaigns on scenarios the project's generator
(``ament_formation/core/scenario/families.py``: ``formation``, ``crossing``, ``two_teams``) would
not draw, so that the control law is not tuned to those families alone. Nothing is imported
from it; the project's loader is used only to validate the output (``parse_scenario``, the
simulation budget) and to read back the exact leader references for the feasibility checks.

Kinds
-----
column    one team of 1-7 robots in a single file (lateral jitter), an echelon (one diagonal arm)
          or an irregular cluster (Poisson-disk slots, >= 0.35 m apart); the leader follows a
          circular arc or an S-bend (waypoints on the arc's chords) or a long-wave sinusoid
          (k 0.8-1.8 rad/m); 1-4 obstacles centred *on* the leader's path or a follower's goal
          track at random arc lengths: static, rotating, oscillating across the path or
          drifting against the team
merge     2-3 teams (1-5 robots) approaching one point from within +-75 deg of a common exit
          direction (never head-on, never mirror-symmetric), at arrival times >= 4 s apart, then
          turning onto parallel exit lanes; 1-3 obstacles moving across a team's path timed to
          cross it while the team is there, sometimes a static or rotating island in the wedge
          between two approaches
gauntlet  one team (1-5 robots), sometimes a second one (1-3) in counter-flow or on a parallel
          lane, through a field of 4-9 small static or rotating ellipses (semi-axes 0.06-0.22 m,
          random orientation) scattered with a random minimum gap; straight, zig-zag or long-wave
          sinusoid routes
overtake  two teams in one corridor (straight or one dog-leg), the rear one 0.018-0.035 m/s
          faster, started behind and sent to rest beyond the front one's end: it must pass, on
          the move or parked; 0-2 long walls beside the corridor narrow it

How they differ from families.py: no line/column/wedge/V formation shapes (single file with
jitter, echelon, Poisson clusters, two-abreast box instead); graphs are stars, chains or random
trees (not nearest-nearer-to-leader); paths are arcs, S-bends, zig-zags, corridors and
long-wave sinusoids (not random-turn polylines or short sinusoids); obstacles sit on the path or
cross it at timed moments, oscillate across or along a path (not along x only), rotate up to
0.25 rad/s for small ones; robots start up to 0.12 m and 0.6 rad off their goals (not 3 cm and
0.2 rad); the disturbance bound is drawn within the design bound (0.05 m/s^2, 0.5 rad/s^2); the
floor is not the 3 x 2.5 m lab but the box of every goal track, start and detour plus a random
margin, corner at (0, 0) (1.3-8 m a side: these are campaigns for the simulator).

Feasibility rules (a failed run means the law failed, not the draw)
------------------------------------------------------------------
* speeds 0.03-0.065 m/s (what the project's scenarios use); ``duration_s`` is the slowest
  team's time to the end of its path plus 6-14 s at rest (sinusoids: drawn), about 40-135 s;
* robots start >= :data:`START_GAP_M` apart and outside every obstacle's protected region
  Q = 1.8 P (and outside merged obstacles' Q);
* the robots' goals when the paths end are >= :data:`GOAL_GAP_M` apart and outside every Q over
  :data:`GOAL_FREE_S` s after ``duration_s`` (a moving obstacle keeps moving);
* obstacles' boundaries move at most :data:`EDGE_SPEED_MPS` (drift + oscillation + rotation);
  their heading-test circles (1.15 r1) stay apart at all times (no obstacle merges);
* every goal track (leader reference + slot) keeps the body radius plus 0.05 m inside the floor;
* whatever the loader refuses (``ConfigError``) or the rules above refuse is drawn again and
  counted, never written; every file written is read back by ``load_scenario``.
"""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import dataclass, field
import math
from pathlib import Path
import sys

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ament_formation.core.scenario.loader import (  # noqa: E402
    check_sim_budget,
    ConfigError,
    load_scenario,
    parse_scenario,
)

KINDS = ('column', 'merge', 'gauntlet', 'overtake')
MAX_DRAWS = 400
SALT = 0x6F74686572  # keeps these streams apart from any other generator's [seed, index, draw]

BODY_RADIUS_M = 0.10
START_GAP_M = 0.30
GOAL_GAP_M = 0.35
GOAL_FREE_S = 60.0
EDGE_SPEED_MPS = 0.02
SPEED_MPS = (0.03, 0.065)
ACCEL_MPS2 = (0.015, 0.04)
SPACING_M = (0.35, 0.6)
SETTLE_S = (6.0, 14.0)
START_ERROR_M = (0.0, 0.12)
START_HEADING_RAD = (0.05, 0.6)
SEMI_MINOR_MIN_M = 0.06
LIMIT_CYCLE_SCALE = 1.1
PROTECTED_SCALE = 1.8
HEADING_SCALE = 1.15
FLOOR_KEEP_M = 0.05
DIGITS = 4


class Rejected(Exception):
    """A draw that breaks a rule; ``reason`` is a short key for the summary."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class Draw:
    """One draw's seeded random source."""

    def __init__(self, seed: int, index: int, draw: int):
        self.rng = np.random.default_rng([SALT, seed, index, draw])

    def uniform(self, lo: float, hi: float) -> float:
        return float(self.rng.uniform(lo, hi))

    def integer(self, lo: int, hi: int) -> int:
        return int(self.rng.integers(lo, hi + 1))

    def choice(self, options, weights=None):
        return options[int(self.rng.choice(len(options), p=weights))]

    def sign(self) -> float:
        return 1.0 if self.rng.random() < 0.5 else -1.0


# ------------------------------------------------------------------------------------------------
# Plane geometry
# ------------------------------------------------------------------------------------------------


def _unit(angle: float) -> np.ndarray:
    return np.array([math.cos(angle), math.sin(angle)])


def _left(vec) -> np.ndarray:
    return np.array([-vec[1], vec[0]])


def _angle(vec) -> float:
    return math.atan2(vec[1], vec[0])


def _cumlen(points: np.ndarray) -> np.ndarray:
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def _point_at(points: np.ndarray, s: float):
    """Position and unit tangent of the polyline ``points`` at arc length ``s`` (clipped)."""
    cum = _cumlen(points)
    s = min(max(s, 0.0), cum[-1])
    k = min(int(np.searchsorted(cum, s, side='right')) - 1, len(points) - 2)
    seg = points[k + 1] - points[k]
    length = float(np.linalg.norm(seg))
    return points[k] + (s - cum[k]) / length * seg, seg / length


def _cut(points: np.ndarray, s_a: float, s_b: float) -> np.ndarray:
    """The part of a polyline between arc lengths ``s_a`` < ``s_b`` (its vertices kept)."""
    cum = _cumlen(points)
    inner = [points[k] for k in range(len(points)) if s_a + 1e-6 < cum[k] < s_b - 1e-6]
    return np.asarray([_point_at(points, s_a)[0], *inner, _point_at(points, s_b)[0]])


def _dense(points: np.ndarray, step: float = 0.02) -> np.ndarray:
    out = []
    for a, b in zip(points[:-1], points[1:]):
        n = max(1, math.ceil(float(np.linalg.norm(b - a)) / step))
        out.extend(a + (b - a) * f for f in np.arange(n) / n)
    out.append(points[-1])
    return np.asarray(out)


def _turtle(start, heading: float, moves, chord: float = 0.2) -> np.ndarray:
    """Vertices of turtle ``moves`` from ``start``: ('line', length), ('turn', angle) or
    ('arc', radius, signed angle; left positive), the arcs cut into chords of at most ``chord``.
    """
    points = [np.asarray(start, dtype=float)]
    for move in moves:
        if move[0] == 'line':
            points.append(points[-1] + move[1] * _unit(heading))
        elif move[0] == 'turn':
            heading += move[1]
        else:
            _, radius, angle = move
            n = max(1, math.ceil(radius * abs(angle) / chord))
            step = angle / n
            for _ in range(n):
                heading += 0.5 * step
                length = 2.0 * radius * math.sin(0.5 * abs(step))
                points.append(points[-1] + length * _unit(heading))
                heading += 0.5 * step
    return np.asarray(points)


def _sine_track(start, heading: float, amp: float, k: float, length: float) -> np.ndarray:
    """Dense points of y = amp sin(k x) turned by ``heading`` from ``start``, ``length`` m long."""
    x = np.linspace(0.0, length, max(int(length / 0.01), 2) + 1)  # arc length >= x
    c, s = math.cos(heading), math.sin(heading)
    y = amp * np.sin(k * x)
    pts = np.stack([c * x - s * y, s * x + c * y], axis=1) + np.asarray(start, dtype=float)
    return _cut(pts, 0.0, length)


def _extent(slots: np.ndarray, axis) -> tuple[float, float]:
    """How far the slots reach ahead of and behind the leader along ``axis``."""
    along = slots @ np.asarray(axis)
    return float(along.max()), float(-along.min())


# ------------------------------------------------------------------------------------------------
# Obstacles
# ------------------------------------------------------------------------------------------------


@dataclass
class Obstacle:
    """An elliptical prohibited region P whose centre drifts and oscillates and which turns."""

    name: str
    centre: np.ndarray
    axes: tuple[float, float]
    phi: float = 0.0
    vel: np.ndarray = field(default_factory=lambda: np.zeros(2))
    omega: float = 0.0
    amp: np.ndarray = field(default_factory=lambda: np.zeros(2))
    period: float = 0.0

    @classmethod
    def from_spec(cls, spec) -> Obstacle:
        """From a validated ObstacleSpec (the loader's)."""
        return cls(
            spec.name,
            np.asarray(spec.center_m, dtype=float),
            tuple(spec.semi_axes_m),
            spec.orientation_rad,
            np.asarray(spec.velocity_mps, dtype=float),
            spec.angular_velocity_radps,
            np.asarray(spec.oscillation_amplitude_m, dtype=float),
            spec.oscillation_period_s,
        )

    @property
    def still(self) -> bool:
        return not (np.any(self.vel) or np.any(self.amp) or self.omega)

    @property
    def drifts(self) -> bool:
        return bool(np.any(self.vel) or np.any(self.amp))

    @property
    def reach(self) -> float:
        return max(self.axes)

    def centres(self, times) -> np.ndarray:
        t = np.atleast_1d(np.asarray(times, dtype=float))
        c = self.centre + t[:, None] * self.vel
        if self.period > 0.0:
            c = c + np.sin(2.0 * math.pi * t / self.period)[:, None] * self.amp
        return c

    def inside(self, points, t: float, scale: float) -> np.ndarray:
        """Which of ``points`` (K, 2) lie inside ``scale`` P at time ``t``."""
        z = np.atleast_2d(points) - self.centres(t)[0]
        phi = self.phi + self.omega * t
        u = math.cos(phi) * z[:, 0] + math.sin(phi) * z[:, 1]
        w = -math.sin(phi) * z[:, 0] + math.cos(phi) * z[:, 1]
        return (u / (scale * self.axes[0])) ** 2 + (w / (scale * self.axes[1])) ** 2 < 1.0

    def mapping(self) -> dict:
        item = {
            'name': self.name,
            'center_m': [float(v) for v in self.centre],
            'semi_axes_m': [float(v) for v in self.axes],
            'orientation_rad': float(math.remainder(self.phi, 2.0 * math.pi)),
        }
        if np.any(self.vel):
            item['velocity_mps'] = [float(v) for v in self.vel]
        if self.omega:
            item['angular_velocity_radps'] = float(self.omega)
        if self.period > 0.0:
            item['oscillation'] = {
                'amplitude_m': [float(v) for v in self.amp],
                'period_s': float(self.period),
            }
        return item


def _size(d: Draw, r1_range) -> tuple[float, float]:
    r1 = d.uniform(*r1_range)
    return r1, d.uniform(SEMI_MINOR_MIN_M, r1) if r1 > SEMI_MINOR_MIN_M else r1


def _obstacle(d: Draw, name: str, centre, r1_range, motion: str, direction=None) -> Obstacle:
    """An obstacle at ``centre``: static, rotating, oscillating along ``direction``, or drifting
    along it; its boundary moves at most a random fraction of :data:`EDGE_SPEED_MPS`.
    """
    axes = _size(d, r1_range)
    obs = Obstacle(name, np.asarray(centre, dtype=float), axes, d.uniform(-math.pi, math.pi))
    budget = EDGE_SPEED_MPS * d.uniform(0.35, 1.0)
    if motion == 'rotating':
        obs.omega = d.sign() * min(0.25, budget / axes[0])
    elif motion == 'oscillating':
        amp = d.uniform(0.04, 0.18)
        obs.amp = amp * np.asarray(direction)
        obs.period = 2.0 * math.pi * amp / budget
    elif motion == 'drifting':
        obs.vel = budget * np.asarray(direction)
    return obs


# ------------------------------------------------------------------------------------------------
# Teams: slots, graphs, robots
# ------------------------------------------------------------------------------------------------

LAYOUTS = ('single_file', 'echelon', 'cluster', 'box')


def _slots(d: Draw, layout: str, n: int, spacing: float, heading: float) -> np.ndarray:
    """(n, 2) world-frame slots (row 0: the leader, at 0) at least ``spacing`` apart."""
    fwd, left = _unit(heading), _left(_unit(heading))
    slots = [np.zeros(2)]
    if layout == 'single_file':
        for k in range(1, n):
            slots.append(-k * spacing * fwd + d.uniform(-0.08, 0.08) * left)
    elif layout == 'echelon':
        beta, side = d.uniform(0.5, 1.1), d.sign()
        arm = -math.cos(beta) * fwd + side * math.sin(beta) * left
        slots.extend(k * spacing * arm for k in range(1, n))
    elif layout == 'box':
        across = spacing * d.uniform(1.0, 1.3) * d.sign() * left
        behind = spacing * d.uniform(1.0, 1.4) * fwd
        slots.extend(-(k // 2) * behind - (k % 2) * across for k in range(1, n))
    else:
        slots = _cluster(d, n, spacing, fwd, left)
    slots = np.asarray(slots)
    gaps = np.linalg.norm(slots[:, None] - slots[None], axis=2) + 9.0 * np.eye(n)
    if gaps.min() < SPACING_M[0] - 1e-9:
        raise Rejected('no_fit')
    return slots


def _cluster(d: Draw, n: int, spacing: float, fwd, left) -> list:
    """Poisson-disk slots in a disc behind (and partly beside) the leader."""
    radius = spacing * (0.6 * math.sqrt(n) + 0.1) * d.uniform(1.0, 1.25)
    centre = -radius * d.uniform(0.3, 1.0) * fwd + d.uniform(-0.3, 0.3) * radius * left
    slots = [np.zeros(2)]
    for _ in range(400 * n):
        if len(slots) == n:
            return slots
        p = centre + radius * math.sqrt(d.rng.random()) * _unit(d.uniform(-math.pi, math.pi))
        if all(np.linalg.norm(p - q) >= spacing for q in slots):
            slots.append(p)
    if len(slots) < n:
        raise Rejected('no_fit')
    return slots


def _edges(d: Draw, ids: list[int], slots: np.ndarray) -> list[list[int]]:
    """[parent, child] edges: a star, a chain or a random tree rooted at the leader (row 0),
    followers taken by distance from the leader; then redundant parents (reverse edges too).
    """
    order = [int(k) for k in np.argsort(np.linalg.norm(slots, axis=1), kind='stable')]
    style = d.choice(('star', 'chain', 'random'))
    edges = []
    for pos in range(1, len(order)):
        if style == 'star':
            parent = order[0]
        elif style == 'chain':
            parent = order[pos - 1]
        else:
            parent = order[d.integer(0, pos - 1)]
        edges.append([ids[parent], ids[order[pos]]])
    for child in range(1, len(ids)):
        if len(ids) < 3 or d.rng.random() >= 0.3:
            continue
        extra = [ids[d.integer(0, len(ids) - 1)], ids[child]]
        if extra[0] != extra[1] and extra not in edges:
            edges.append(extra)
    return edges


@dataclass
class Plan:
    """The scenario being drawn: robots, graph, obstacles, and what the obstacle rules check."""

    kind: str
    robots: list = field(default_factory=list)
    edges: list = field(default_factory=list)
    starts: list = field(default_factory=list)
    ends: list = field(default_factory=list)
    obstacles: list = field(default_factory=list)
    duration: float = 0.0
    start_error_m: float = 0.0
    start_heading_rad: float = 0.0

    def add_team(self, d: Draw, cfg: dict, track: np.ndarray, slots: np.ndarray) -> None:
        """A team whose leader follows ``cfg`` (``track``: its dense polyline, to its end)."""
        ids = list(range(len(self.robots), len(self.robots) + len(slots)))
        heading = _angle(track[1] - track[0])
        for k, rid in enumerate(ids):
            start = self._start(d, track[0] + slots[k])
            theta = heading + d.uniform(-self.start_heading_rad, self.start_heading_rad)
            item = {'id': rid}
            if k == 0:
                item.update(leader=True, path=cfg)
            item['slot_m'] = [float(v) for v in slots[k]]
            item['initial_pose'] = [float(start[0]), float(start[1]), theta]
            item['marker_id'] = rid
            self.robots.append(item)
        self.edges += _edges(d, ids, slots)
        self.ends.extend(track[-1] + slots)

    def _start(self, d: Draw, goal) -> np.ndarray:
        for _ in range(30):
            offset = self.start_error_m * math.sqrt(d.rng.random())
            p = goal + offset * _unit(d.uniform(-math.pi, math.pi))
            if all(np.linalg.norm(p - q) >= START_GAP_M + 0.01 for q in self.starts):
                self.starts.append(p)
                return p
        raise Rejected('start_gap')

    def fits(self, obs: Obstacle, gap: float = 0.02) -> bool:
        """Whether ``obs`` spares every start and end goal (Q) and keeps ``gap`` between its
        heading-test circle and every other obstacle's, at all times.
        """
        if obs.inside(np.asarray(self.starts), 0.0, PROTECTED_SCALE).any():
            return False
        ends = np.asarray(self.ends)
        later = self.duration + np.arange(0.0, GOAL_FREE_S + 0.01, 0.5)
        if any(obs.inside(ends, t, PROTECTED_SCALE).any() for t in later):
            return False
        times = np.arange(0.0, self.duration + GOAL_FREE_S + 1.0, 1.0)
        for other in self.obstacles:
            apart = np.linalg.norm(obs.centres(times) - other.centres(times), axis=1)
            if apart.min() < HEADING_SCALE * (obs.reach + other.reach) + gap:
                return False
        return True

    def place(self, obs: Obstacle, gap: float = 0.02) -> bool:
        if self.fits(obs, gap):
            self.obstacles.append(obs)
            return True
        return False


def _plan(d: Draw, kind: str) -> Plan:
    error, heading = d.uniform(*START_ERROR_M), d.uniform(*START_HEADING_RAD)
    return Plan(kind, start_error_m=error, start_heading_rad=heading)


def _layout(d: Draw, n: int) -> str:
    return d.choice(LAYOUTS) if n > 2 else d.choice(('single_file', 'echelon', 'cluster'))


def _waypoints(points: np.ndarray, speed: float, accel: float) -> dict:
    return {
        'type': 'waypoints',
        'points_m': [[float(x), float(y)] for x, y in points],
        'speed_mps': speed,
        'accel_mps2': accel,
    }


def _sinusoid(heading: float, amp: float, k: float, speed: float) -> dict:
    return {
        'type': 'sinusoid',
        'start_m': [0.0, 0.0],
        'amplitude_m': amp,
        'wavenumber_radpm': k,
        'speed_mps': speed,
        'heading_rad': heading,
    }


def _arrival(points: np.ndarray, speed: float, accel: float) -> float:
    """When a waypoint reference comes to rest (corners cut short: an upper bound)."""
    return float(_cumlen(points)[-1]) / speed + 0.5 * speed / accel


# ------------------------------------------------------------------------------------------------
# Kinds
# ------------------------------------------------------------------------------------------------


def _bend_moves(d: Draw, shape: str, length: float, speed: float, accel: float) -> list:
    """Turtle moves of a lead-in, one arc ('arc') or two opposite ones ('s_bend'), a run-out."""
    lead = d.uniform(0.15, 0.4)
    tail = max(d.uniform(0.3, 0.5), speed**2 / (2.0 * accel) + 0.12)
    bend = length - lead - tail
    if bend < 0.4:
        raise Rejected('no_fit')
    side = d.sign()
    if shape == 'arc':
        radius = min(max(bend / d.uniform(0.8, 2.6), 0.5), 3.0)
        return [('line', lead), ('arc', radius, side * bend / radius), ('line', tail)]
    first, second = d.uniform(0.5, 1.4), d.uniform(0.5, 1.4)
    straight = d.uniform(0.0, 0.25) * bend
    radius = min(max((bend - straight) / (first + second), 0.5), 3.0)
    scale = (bend - straight) / (radius * (first + second))
    moves = [('line', lead), ('arc', radius, side * first * scale)]
    if straight > 0.05:
        moves.append(('line', straight))
    return moves + [('arc', radius, -side * second * scale), ('line', tail)]


def _column(d: Draw, plan: Plan) -> str:
    n = d.integer(1, 7)
    speed, settle = d.uniform(*SPEED_MPS), d.uniform(*SETTLE_S)
    heading, shape = d.uniform(-math.pi, math.pi), d.choice(('arc', 's_bend', 'long_sine'))
    plan.duration = d.uniform(40.0, 90.0)
    if shape == 'long_sine':
        amp, k = d.uniform(0.1, 0.35), d.uniform(0.8, 1.8)
        cfg = _sinusoid(heading, amp, k, speed)
        track = _sine_track((0.0, 0.0), heading, amp, k, speed * plan.duration)
    else:
        accel = d.uniform(*ACCEL_MPS2)
        moves = _bend_moves(d, shape, speed * (plan.duration - settle), speed, accel)
        points = _turtle((0.0, 0.0), heading, moves)
        cfg, track = _waypoints(points, speed, accel), _dense(points)
        plan.duration = _arrival(points, speed, accel) + settle
    layout = d.choice(('single_file', 'echelon', 'cluster'))
    slots = _slots(d, layout, n, d.uniform(*SPACING_M), _angle(track[1] - track[0]))
    plan.add_team(d, cfg, track, slots)
    motions = ('static', 'rotating', 'oscillating', 'drifting')
    for j in range(d.integer(1, 4)):
        for _ in range(25):
            follower = n > 1 and d.rng.random() < 0.35  # else on the leader's own path
            target = track + (slots[d.integer(1, n - 1)] if follower else 0.0)
            point, tangent = _point_at(target, d.uniform(0.25, 0.85) * _cumlen(target)[-1])
            normal = _left(tangent)
            motion = d.choice(motions, [0.4, 0.25, 0.2, 0.15])
            direction = normal if motion == 'oscillating' else -tangent
            obs = _obstacle(
                d, f'{motion[0].upper()}{j + 1}', point + d.rng.normal(0.0, 0.05) * normal,
                (0.08, 0.4), motion, direction,
            )
            if d.rng.random() < 0.3:  # a wall across the path
                obs.phi = _angle(normal) if obs.axes[0] >= obs.axes[1] else _angle(tangent)
            if plan.place(obs):
                break
    if not plan.obstacles:
        raise Rejected('no_fit')
    return f'{shape}-{layout if n > 1 else "solo"}{n}-{len(plan.obstacles)}obs'


def _approach_angles(d: Draw, m: int) -> list[float]:
    """``m`` deviations from the exit direction in +-1.3 rad, >= 0.45 rad apart, not a set
    symmetric about the exit direction.
    """
    for _ in range(200):
        angles = sorted(d.uniform(-1.3, 1.3) for _ in range(m))
        spread = min(b - a for a, b in zip(angles, angles[1:]))
        mirror = max(abs(a + b) for a, b in zip(angles, reversed(angles)))
        if spread >= 0.45 and mirror >= 0.15:
            return [angles[k] for k in d.rng.permutation(m)]
    raise Rejected('no_fit')


def _merge(d: Draw, plan: Plan) -> str:
    m = d.choice((2, 3), [0.6, 0.4])
    exit_dir = d.uniform(-math.pi, math.pi)
    deviations = _approach_angles(d, m)
    gaps = [0.0] + [d.uniform(4.0, 14.0) for _ in range(m - 1)]
    arrivals = d.uniform(14.0, 30.0) + np.cumsum(gaps)
    lane_width = d.uniform(0.6, 1.0)
    lanes = [(rank - 0.5 * (m - 1)) * lane_width for rank in d.rng.permutation(m)]
    teams, finish, meet_times = [], [], []
    for i in range(m):
        speed, accel = d.uniform(*SPEED_MPS), d.uniform(*ACCEL_MPS2)
        approach = min(max(speed * arrivals[i], 0.6), 2.4)
        towards = exit_dir + deviations[i]
        meet = d.rng.normal(0.0, 0.08, 2)
        lane = meet + lanes[i] * _left(_unit(exit_dir))  # the lane's entry, past the meeting
        lane = lane + max(0.3, abs(lanes[i]) * d.uniform(0.8, 1.4)) * _unit(exit_dir)
        end = lane + d.uniform(0.4, 1.0) * _unit(exit_dir)
        points = np.asarray([meet - approach * _unit(towards), meet, lane, end])
        teams.append((_waypoints(points, speed, accel), _dense(points), speed, towards))
        finish.append(_arrival(points, speed, accel))
        meet_times.append(approach / speed)
    if np.diff(sorted(meet_times)).min() < 4.0:  # clipped approaches: two arrivals too close
        raise Rejected('no_fit')
    plan.duration = max(finish) + d.uniform(*SETTLE_S)
    sizes = [d.integer(1, 5 if m == 2 else 3) for _ in range(m)]
    for (cfg, track, _speed, towards), n in zip(teams, sizes):
        plan.add_team(d, cfg, track, _slots(d, _layout(d, n), n, d.uniform(*SPACING_M), towards))
    for j in range(d.integer(1, 3)):
        for _ in range(25):
            if plan.place(_crossing(d, f'X{j + 1}', teams[d.integer(0, m - 1)])):
                break
    if d.rng.random() < 0.4:
        pair = sorted(deviations)[:2]
        where = d.uniform(0.45, 0.8) * _unit(exit_dir + math.pi + 0.5 * sum(pair))
        plan.place(_obstacle(d, 'I1', where, (0.1, 0.3), d.choice(('static', 'rotating'))))
    if not plan.obstacles:
        raise Rejected('no_fit')
    return f'{m}teams-{"-".join(str(n) for n in sizes)}-{len(plan.obstacles)}obs'


def _crossing(d: Draw, name: str, team) -> Obstacle:
    """An obstacle that crosses ``team``'s path at a time the team's leader is there."""
    _cfg, track, speed, _towards = team
    moving_s = float(_cumlen(track)[-1]) / speed
    when = d.uniform(0.35, 1.0) * moving_s
    point, tangent = _point_at(track, speed * when)
    across = _left(tangent) * d.sign()
    angle = _angle(across) + d.uniform(-0.4, 0.4)
    budget = EDGE_SPEED_MPS * d.uniform(0.4, 1.0)
    drift = budget * d.uniform(0.6, 1.0)
    start = point - drift * when * _unit(angle)
    obs = Obstacle(name, start, _size(d, (0.1, 0.3)), d.uniform(-math.pi, math.pi))
    obs.vel = drift * _unit(angle)
    if budget - drift > 0.002 and d.rng.random() < 0.5:  # and sways along the path
        amp = d.uniform(0.03, 0.06)
        obs.amp, obs.period = amp * tangent, 2.0 * math.pi * amp / (budget - drift)
    return obs


def _zigzag_moves(d: Draw, length: float, speed: float, accel: float) -> list:
    """Turtle moves of straight legs alternating +-alpha about the route's heading."""
    alpha, side = d.uniform(0.25, 0.6), d.sign()
    corner = speed**2 / accel * math.tan(alpha)  # a vertex turns 2 alpha
    leg = (max(0.35, 2.0 * corner + 0.05), max(0.7, 2.0 * corner + 0.25))
    moves, total = [('turn', side * alpha)], 0.0
    while total < length:
        ell = d.uniform(*leg)
        moves += [('line', ell), ('turn', -2.0 * side * alpha)]
        side, total = -side, total + ell
    tail = corner + speed**2 / (2.0 * accel) + 0.1
    return moves + [('line', max(tail, 0.3))]


def _gauntlet(d: Draw, plan: Plan) -> str:
    heading, settle = d.uniform(-math.pi, math.pi), d.uniform(*SETTLE_S)
    speed, accel = d.uniform(*SPEED_MPS), d.uniform(*ACCEL_MPS2)
    length = min(d.uniform(1.8, 3.6), speed * (95.0 - settle))
    route = d.choice(('straight', 'zigzag', 'long_sine'))
    along, normal = _unit(heading), _left(_unit(heading))
    if route == 'zigzag':
        points = _turtle((0.0, 0.0), heading, _zigzag_moves(d, length, speed, accel))
    else:
        points = np.asarray([[0.0, 0.0], length * along])
    finish = [length / speed if route == 'long_sine' else _arrival(points, speed, accel)]
    second = d.choice(('none', 'counter', 'parallel'), [0.4, 0.35, 0.25])
    offset = d.sign() * d.uniform(0.5, 1.0) * normal
    if second != 'none':
        speed2, accel2 = d.uniform(*SPEED_MPS), d.uniform(*ACCEL_MPS2)
        points2 = (points[::-1] if second == 'counter' else points) + offset
        finish.append(_arrival(points2, speed2, accel2))
    plan.duration = max(finish) + settle
    if route == 'long_sine':
        amp, k = d.uniform(0.08, 0.25), d.uniform(1.0, 2.0)
        cfg = _sinusoid(heading, amp, k, speed)
        track = _sine_track((0.0, 0.0), heading, amp, k, speed * plan.duration)
    else:
        cfg, track = _waypoints(points, speed, accel), _dense(points)
    n = d.integer(1, 5)
    slots = _slots(d, _layout(d, n), n, d.uniform(*SPACING_M), _angle(track[1] - track[0]))
    plan.add_team(d, cfg, track, slots)
    lateral = [float(v) for v in slots @ normal]
    if second != 'none':
        n2 = d.integer(1, 3)
        track2 = _dense(points2)
        heading2 = _angle(track2[1] - track2[0])
        slots2 = _slots(d, _layout(d, n2), n2, d.uniform(*SPACING_M), heading2)
        plan.add_team(d, _waypoints(points2, speed2, accel2), track2, slots2)
        lateral += [float(v) for v in slots2 @ normal + offset @ normal]
    width = (min(lateral + [0.0]) - 0.65, max(lateral + [0.0]) + 0.65)
    gap = d.uniform(0.1, 0.4)
    count = d.integer(4, 9)
    for _ in range(60 * count):
        if len(plan.obstacles) >= count:
            break
        centre = d.uniform(0.22, 0.82) * length * along + d.uniform(*width) * normal
        motion = d.choice(('static', 'rotating'))
        plan.place(_obstacle(d, f'G{len(plan.obstacles) + 1}', centre, (0.07, 0.22), motion), gap)
    if len(plan.obstacles) < 3:
        raise Rejected('no_fit')
    return f'{route}-{second}-{len(plan.robots)}r-{len(plan.obstacles)}obs'


def _overtake(d: Draw, plan: Plan) -> str:
    heading = d.uniform(-math.pi, math.pi)
    along = _unit(heading)
    slow = d.uniform(0.03, 0.042)
    fast = d.uniform(slow + 0.018, min(slow + 0.035, SPEED_MPS[1]))
    n_front, n_rear = d.integer(1, 4), d.integer(1, 4)
    front = _slots(d, _layout(d, n_front), n_front, d.uniform(*SPACING_M), heading)
    rear = _slots(d, _layout(d, n_rear), n_rear, d.uniform(*SPACING_M), heading)
    head_start = _extent(rear, along)[0] + d.uniform(0.4, 0.9) + _extent(front, along)[1]
    settle = d.uniform(*SETTLE_S)
    catch_up = head_start / (fast - slow)  # the rear leader reaches the front leader's start
    if catch_up / 0.85 + settle > 105.0:
        raise Rejected('no_fit')
    run = min(catch_up / d.uniform(0.4, 0.7), 105.0 - settle)
    front_len = slow * run * d.uniform(0.6, 1.0)
    beyond = head_start + front_len + _extent(front, along)[0] + d.uniform(0.4, 0.7)
    rear_len = max(fast * run, beyond + _extent(rear, along)[1])
    dogleg = d.rng.random() < 0.6
    if dogleg:
        bend_at = d.uniform(head_start + 0.3, max(head_start + 0.3, 0.65 * rear_len))
        turn = d.sign() * d.uniform(0.3, 0.9)
        moves = [('line', bend_at), ('turn', turn), ('line', rear_len - bend_at + 0.2)]
    else:
        moves = [('line', rear_len + 0.2)]
    corridor = _turtle((0.0, 0.0), heading, moves)
    lane = d.uniform(-0.3, 0.3) * _left(along)
    accel_front, accel_rear = d.uniform(*ACCEL_MPS2), d.uniform(*ACCEL_MPS2)
    front_pts = _cut(corridor, head_start, head_start + front_len)
    rear_pts = _cut(corridor, 0.0, rear_len) + lane
    plan.duration = max(
        _arrival(front_pts, slow, accel_front), _arrival(rear_pts, fast, accel_rear)
    ) + settle
    plan.add_team(d, _waypoints(front_pts, slow, accel_front), _dense(front_pts), front)
    plan.add_team(d, _waypoints(rear_pts, fast, accel_rear), _dense(rear_pts), rear)
    for j in range(d.integer(0, 2)):
        for _ in range(25):
            point, tangent = _point_at(corridor, d.uniform(head_start + 0.3, 0.85 * rear_len))
            centre = point + d.sign() * d.uniform(0.45, 0.75) * _left(tangent)
            axes = (d.uniform(0.15, 0.35), d.uniform(0.06, 0.12))
            wall = Obstacle(f'B{j + 1}', centre, axes, _angle(tangent))
            if plan.place(wall):
                break
    shape = 'dogleg' if dogleg else 'straight'
    return f'{shape}-{n_front}front-{n_rear}rear-{len(plan.obstacles)}obs'


BUILDERS = {'column': _column, 'merge': _merge, 'gauntlet': _gauntlet, 'overtake': _overtake}


# ------------------------------------------------------------------------------------------------
# Validation, floor, feasibility
# ------------------------------------------------------------------------------------------------


def _validator_reason(err: ConfigError) -> str:
    text = str(err)
    keys = (
        ('limit cycles', 'limit_cycles'),
        ('prohibited region', 'start_in_P'),
        ('prohibited circle', 'start_keepout'),
        ('to turn', 'waypoint_corner'),
        ('reverses', 'waypoint_reversal'),
        ('repeats the previous', 'waypoint_repeat'),
        ('not on the floor', 'start_off_floor'),
        ('budget', 'sim_budget'),
        ('sinusoid asks', 'sinusoid_accel'),
    )
    return 'validator:' + next((key for words, key in keys if words in text), 'other')


def _validate(mapping: dict):
    """The loader's Scenario of ``mapping`` within `formation sim`'s budget, or Rejected."""
    try:
        scenario = parse_scenario(mapping)
        check_sim_budget(scenario, 0.001, 0.01)
    except ConfigError as err:
        raise Rejected(_validator_reason(err)) from None
    return scenario


def _goal_tracks(scenario, times: np.ndarray) -> np.ndarray:
    """(T, n, 2) goals (leader reference + slot offset) at ``times``, exact from the loader."""
    refs, out = {}, []
    for r in scenario.robots:
        lead = scenario.robot(scenario.team_leader(r.id))
        if lead.id not in refs:
            refs[lead.id] = np.asarray(lead.path.reference(times)[0]).reshape(-1, 2)
        out.append(refs[lead.id] + scenario.slot(r.id) - scenario.slot(lead.id))
    return np.stack(out, axis=1)


def _times(duration: float) -> np.ndarray:
    return np.linspace(0.0, duration, max(int(duration / 0.25), 2) + 1)


def _floor_box(scenario, d: Draw) -> tuple[np.ndarray, np.ndarray]:
    """Corners of a floor holding every goal track and start (body + margin) and the detours
    round every obstacle near them (its limit cycle plus a body), with a random margin a side.
    """
    times = _times(scenario.duration_s)
    goals = _goal_tracks(scenario, times)
    keep = BODY_RADIUS_M + FLOOR_KEEP_M
    starts = np.asarray([r.initial_pose[:2] for r in scenario.robots])
    points = np.concatenate([goals.reshape(-1, 2), starts])
    lo, hi = points.min(axis=0) - keep, points.max(axis=0) + keep
    for spec in scenario.obstacles:
        obs = Obstacle.from_spec(spec)
        centres = obs.centres(times)
        detour = LIMIT_CYCLE_SCALE * obs.reach + BODY_RADIUS_M + FLOOR_KEEP_M
        near = np.linalg.norm(goals - centres[:, None], axis=2).min(axis=1) <= detour + 0.5
        if not obs.drifts:
            near[:] = True
        if near.any():
            lo = np.minimum(lo, centres[near].min(axis=0) - detour)
            hi = np.maximum(hi, centres[near].max(axis=0) + detour)
    margin = d.rng.uniform(0.05, 0.3, 4)
    return lo - margin[:2], hi + margin[2:]


def _infeasible(scenario) -> str | None:
    """The first feasibility rule ``scenario`` breaks (a short key), or None."""
    n = len(scenario.robots)
    starts = np.asarray([r.initial_pose[:2] for r in scenario.robots])
    if n > 1 and _min_gap(starts) < START_GAP_M:
        return 'start_gap'
    q = scenario.avoidance.protected_scale
    raw = [Obstacle.from_spec(o) for o in scenario.obstacles]
    merged = [Obstacle.from_spec(o) for o in scenario.avoided_obstacles() if '+' in o.name]
    if any(o.inside(starts, 0.0, q).any() for o in raw + merged):
        return 'start_in_q'
    goals = _goal_tracks(scenario, _times(scenario.duration_s))
    floor, keep = scenario.floor, BODY_RADIUS_M + FLOOR_KEEP_M
    lo = np.array([floor.x_m[0], floor.y_m[0]]) + keep
    hi = np.array([floor.x_m[1], floor.y_m[1]]) - keep
    if np.any(goals < lo) or np.any(goals > hi):
        return 'floor'
    end = goals[-1]
    if n > 1 and _min_gap(end) < GOAL_GAP_M:
        return 'goal_gap'
    later = scenario.duration_s + np.arange(0.0, GOAL_FREE_S + 0.01, 0.5)
    for obs in raw + merged:
        for t in later[:1] if obs.still else later:
            if obs.inside(end, t, q).any():
                return 'goal_in_q'
    return None


def _min_gap(points: np.ndarray) -> float:
    gaps = np.linalg.norm(points[:, None] - points[None], axis=2) + 1e9 * np.eye(len(points))
    return float(gaps.min())


# ------------------------------------------------------------------------------------------------
# Writing
# ------------------------------------------------------------------------------------------------


def _rounded(value):
    """``value`` with every float rounded to :data:`DIGITS` decimals (plain Python types)."""
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_rounded(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return round(float(value), DIGITS) + 0.0  # no -0.0
    return value


def _shifted(mapping: dict, offset: np.ndarray) -> dict:
    """``mapping`` with every position moved by ``offset`` (starts, paths, obstacles)."""
    dx, dy = (float(v) for v in offset)
    for r in mapping['robots']:
        x, y, theta = r['initial_pose']
        r['initial_pose'] = [x + dx, y + dy, theta]
        path = r.get('path')
        if path is None:
            continue
        if path['type'] == 'waypoints':
            path['points_m'] = [[x + dx, y + dy] for x, y in path['points_m']]
        else:
            path['start_m'] = [path['start_m'][0] + dx, path['start_m'][1] + dy]
    for o in mapping['obstacles']:
        o['center_m'] = [o['center_m'][0] + dx, o['center_m'][1] + dy]
    return mapping


def _draft(d: Draw, plan: Plan, name: str) -> dict:
    return {
        'name': name,
        'duration_s': plan.duration,
        'floor': None,
        'disturbance': {
            'accel_bound': [d.uniform(0.0, 0.05), d.uniform(0.0, 0.5)],
            'seed': d.integer(0, 2**31 - 2),
        },
        'robots': plan.robots,
        'graph': {'edges': plan.edges},
        'obstacles': [o.mapping() for o in plan.obstacles],
        'avoidance': {'limit_cycle_scale': LIMIT_CYCLE_SCALE, 'protected_scale': PROTECTED_SCALE},
    }


def _finish(d: Draw, draft: dict) -> str:
    """YAML text of ``draft`` on a floor of its own with its corner at (0, 0), validated as
    written and checked against the feasibility rules (Rejected otherwise).
    """
    scenario = _validate(_rounded(draft))
    lo, hi = _floor_box(scenario, d)
    lo = np.round(lo, 3)
    mapping = _shifted(_rounded(draft), -lo)
    size = np.round(hi - lo, 3)
    mapping['floor'] = {'x_m': [0.0, float(size[0])], 'y_m': [0.0, float(size[1])]}
    text = yaml.safe_dump(_rounded(mapping), sort_keys=False, default_flow_style=None, width=99)
    reason = _infeasible(_validate(yaml.safe_load(text)))
    if reason:
        raise Rejected(reason)
    return text


def generate(kind: str, seed: int, index: int) -> tuple[str, str, Counter]:
    """Scenario ``index`` of ``kind`` for ``seed``: (name, YAML text, rejected draws by reason).
    RuntimeError when no draw of :data:`MAX_DRAWS` is accepted.
    """
    rejected: Counter = Counter()
    for draw in range(MAX_DRAWS):
        d = Draw(seed, index, draw)
        plan = _plan(d, kind)
        try:
            detail = BUILDERS[kind](d, plan)
            name = f'{kind}-s{seed}-{index}-{detail}'
            text = _finish(d, _draft(d, plan, name))
        except Rejected as why:
            rejected[why.reason] += 1
            continue
        header = (
            f'# {kind} scenario from bench/other_generator.py (seed {seed}, index {index}, '
            f'draw {draw}): rules in its docstring\n'
        )
        return name, header + text, rejected
    top = ', '.join(f'{k} {v}' for k, v in rejected.most_common(3))
    raise RuntimeError(f'{kind}: no draw of {MAX_DRAWS} met the rules for index {index} ({top})')


# ------------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------------


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (exit status 2)."""

    def error(self, message):
        sys.stderr.write(f'{self.prog}: error: {message}\n')
        sys.exit(2)


def _arguments(argv):
    p = _Parser(prog='other_generator.py', description=__doc__.split('\n\n')[0])
    p.add_argument('--out', required=True, metavar='DIR', help='directory to write (empty or new)')
    p.add_argument('--count', required=True, type=int, metavar='N', help='files (1-99999)')
    p.add_argument('--seed', required=True, type=int, metavar='S', help='campaign seed (>= 0)')
    p.add_argument(
        '--families', default=','.join(KINDS), metavar='A,B',
        help=f'kinds of this generator, in turn by index (default {",".join(KINDS)})',
    )
    args = p.parse_args(argv)
    if not 1 <= args.count <= 99999:
        p.error(f'--count must be 1-99999 (got {args.count})')
    if args.seed < 0:
        p.error(f'--seed must be >= 0 (got {args.seed})')
    kinds = [k.strip() for k in args.families.split(',') if k.strip()]
    unknown = [k for k in kinds if k not in BUILDERS]
    if not kinds or unknown:
        what = f'unknown kind {unknown[0]!r}' if unknown else 'no kind given'
        p.error(f'--families: {what} (known: {", ".join(KINDS)})')
    if len(set(kinds)) < len(kinds):
        p.error(f'--families lists a kind twice ({args.families})')
    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        p.error(f'--out {out} exists and is not an empty directory')
    args.kinds = kinds
    return args, p


def _summary(out: Path, written: Counter, rejected: dict) -> str:
    kinds = ', '.join(f'{k} {n}' for k, n in written.items())
    parts = []
    for label, pick in (('validator', True), ('generator rules', False)):
        items = [
            (kind, reason.split(':', 1)[-1], n)
            for kind, reasons in rejected.items()
            for reason, n in sorted(reasons.items())
            if reason.startswith('validator:') == pick
        ]
        detail = ', '.join(f'{kind} {reason} {n}' for kind, reason, n in items)
        parts.append(f'{label} {sum(n for *_, n in items)}' + (f' ({detail})' if detail else ''))
    total = sum(written.values())
    return f'wrote {total} files to {out} ({kinds}); rejected draws: {"; ".join(parts)}'


def main(argv=None) -> int:
    args, parser = _arguments(argv)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        parser.error(f'--out {out}: {err.strerror}')
    written: Counter = Counter()
    rejected = {kind: Counter() for kind in args.kinds}
    for index in range(args.count):
        kind = args.kinds[index % len(args.kinds)]
        try:
            name, text, reasons = generate(kind, args.seed, index)
        except RuntimeError as err:
            print(f'other_generator.py: {err}', file=sys.stderr)
            return 1
        target = out / f'{index:05d}-{name}.yaml'
        target.write_text(text, encoding='utf-8')
        try:
            load_scenario(target)  # what a campaign reads
        except ConfigError as err:
            print(f'other_generator.py: written file does not load: {err}', file=sys.stderr)
            return 1
        written[kind] += 1
        rejected[kind].update(reasons)
    print(_summary(out, written, rejected))
    return 0


if __name__ == '__main__':
    sys.exit(main())
