"""Random scenarios in declared families, for Monte Carlo campaigns (`formation sweep`).

Every scenario is drawn from a seeded generator (``numpy.random.default_rng([seed, index])``: the
same seed and index give the same scenario on any machine) and is physically feasible by the rules
of :class:`Rules`, then checked by the project's own validator (:func:`parse_scenario`). A draw the
validator refuses (for example two limit cycles that would overlap) is drawn again from the next
sub-seed; :func:`generate` reports how many draws it took.

Families
--------
formation   one team of 2-8 robots in a line, column, wedge or V behind a leader on a line,
            sinusoid or waypoint path at 0.03-0.065 m/s, among 0-5 static, moving and
            rotating obstacles placed on the team's way
crossing    2-4 one-robot teams crossing near one point from different directions (waypoint paths
            that end at rest on the far side), with 0-2 obstacles near the crossing point
two_teams   two formations of 2-4 robots whose paths cross, with 0-2 obstacles near the crossing

Feasibility rules (:class:`Rules`)
----------------------------------
* every formation goal (leader reference + slot) keeps the body radius plus ``edge_margin_m`` from
  the floor's edge for the whole run, and every robot starts within ``start_error_m`` of its goal;
* slots are at least ``spacing_m[0]`` apart (more than the robots' keep-out circle), and so are
  the goals where robots of different teams come to rest when the paths end (two teams may not
  be asked to end on top of each other: without this rule 95 of the 666 two-team scenarios of
  seed 1 asked two robots to rest closer than their two bodies, 0.2 m);
* obstacles are slower than a robot can out-run: the fastest point of the boundary of P (drift,
  oscillation and rotation together) moves at most ``obstacle_speed_max_mps``;
* no robot starts inside an obstacle's protected region Q (``protected_scale`` P);
* the scenario declares its floor (``floor:``): leaving it fails the run.

:func:`perturb` gives seeded variations of a given scenario instead (start poses, obstacle
geometry, disturbance seed), checked by the same validator.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.model.paths import path_from_config
from ament_formation.core.params import AvoidanceParams, RobotParams
from ament_formation.core.scenario.loader import parse_scenario, scenario_to_mapping

FAMILIES = ('formation', 'crossing', 'two_teams')
SHAPES = ('line', 'column', 'wedge', 'v')
MAX_DRAWS = 200  # draws of one scenario before giving up (a rule set nothing satisfies)


@dataclass(frozen=True)
class Rules:
    """What a generated scenario may be (SI units; the floor is the issue's 3 x 2.5 m lab)."""

    floor_x_m: tuple[float, float] = (0.0, 3.0)
    floor_y_m: tuple[float, float] = (0.0, 2.5)
    edge_margin_m: float = 0.05
    speed_mps: tuple[float, float] = (0.03, 0.065)
    duration_s: tuple[float, float] = (25.0, 60.0)
    min_duration_s: float = 15.0
    robots: tuple[int, int] = (2, 8)
    spacing_m: tuple[float, float] = (0.35, 0.5)
    obstacles: tuple[int, int] = (0, 5)
    crossing_robots: tuple[int, int] = (2, 4)
    crossing_obstacles: tuple[int, int] = (0, 2)
    team_robots: tuple[int, int] = (2, 4)
    semi_major_m: tuple[float, float] = (0.10, 0.35)
    semi_minor_min_m: float = 0.06
    obstacle_speed_max_mps: float = 0.02
    start_error_m: float = 0.03
    start_heading_error_rad: float = 0.2
    settle_s: float = 10.0  # crossings: time at rest at the end of the paths
    disturbance_bound: tuple[float, float] = (0.05, 0.5)


_ROBOT = RobotParams()
_AVOID = AvoidanceParams()


class Draw:
    """One draw's random source and the floor box its goals must stay in."""

    def __init__(self, rng: np.random.Generator, rules: Rules):
        self.rng = rng
        self.rules = rules
        keep = _ROBOT.body_radius_m + rules.edge_margin_m
        self.lo = np.array([rules.floor_x_m[0] + keep, rules.floor_y_m[0] + keep])
        self.hi = np.array([rules.floor_x_m[1] - keep, rules.floor_y_m[1] - keep])

    def uniform(self, pair) -> float:
        return float(self.rng.uniform(pair[0], pair[1]))

    def integer(self, pair) -> int:
        return int(self.rng.integers(pair[0], pair[1] + 1))


# ------------------------------------------------------------------------------------------------
# Formations: slots and graphs
# ------------------------------------------------------------------------------------------------


def formation_slots(shape: str, n: int, spacing: float, heading: float) -> np.ndarray:
    """(n, 2) world-frame slots of a team of ``n`` (row 0 = the leader at 0) for a team heading
    ``heading`` [rad]: line (side by side), column (one behind the other), wedge (a filled
    triangle, rows of 2, 3, ... behind the leader) or v (two arms).
    """
    fwd = np.array([math.cos(heading), math.sin(heading)])
    left = np.array([-fwd[1], fwd[0]])
    local = [(0.0, 0.0)]
    row = 1
    while len(local) < n:
        if shape == 'line':
            k = (len(local) + 1) // 2
            local.append((0.0, k if len(local) % 2 else -k))
        elif shape == 'column':
            local.append((-len(local), 0.0))
        elif shape == 'v':
            k = (len(local) + 1) // 2
            local.append((-k, k if len(local) % 2 else -k))
        elif shape == 'wedge':
            for j in range(row + 1):
                if len(local) < n:
                    local.append((-row, j - 0.5 * row))
            row += 1
        else:
            raise ValueError(f'unknown formation shape {shape!r} (one of {SHAPES})')
    return np.asarray([spacing * (a * fwd + b * left) for a, b in local])


def tree_edges(slots: np.ndarray, ids: list[int], rng, redundant: float = 0.3) -> list:
    """[parent, child] edges: each follower's parent is the nearest robot nearer to the leader
    (by slot); with probability ``redundant`` a second, redundant parent for S9 rewiring.
    """
    order = np.argsort(np.linalg.norm(slots, axis=1), kind='stable')
    edges = []
    for k in range(1, len(order)):
        child = order[k]
        earlier = order[:k]
        dist = np.linalg.norm(slots[earlier] - slots[child], axis=1)
        near = earlier[np.argsort(dist, kind='stable')]
        edges.append([ids[near[0]], ids[child]])
        if len(near) > 1 and rng.random() < redundant:
            edges.append([ids[near[1]], ids[child]])
    return edges


# ------------------------------------------------------------------------------------------------
# Leader paths
# ------------------------------------------------------------------------------------------------


def _leader_path(d: Draw, kind: str, heading: float, speed: float, duration: float) -> dict:
    if kind == 'line':
        return {'type': 'line', 'start_m': [0.0, 0.0], 'heading_rad': heading, 'speed_mps': speed}
    if kind == 'sinusoid':
        k = d.uniform((2.0, 5.0))
        amp = d.uniform((0.05, min(0.25, 0.8 / k)))
        return {
            'type': 'sinusoid',
            'start_m': [0.0, 0.0],
            'amplitude_m': amp,
            'wavenumber_radpm': k,
            'speed_mps': speed,
            'heading_rad': heading,
        }
    points, angle = [np.zeros(2)], heading
    remaining = speed * duration * 1.2
    while remaining > 0.0 and len(points) < 6:
        length = max(min(d.uniform((0.5, 1.2)), remaining), 0.4) if len(points) > 1 else 0.5
        points.append(points[-1] + length * np.array([math.cos(angle), math.sin(angle)]))
        remaining -= length
        angle += d.uniform((-1.4, 1.4))
    return {
        'type': 'waypoints',
        'points_m': [[float(x), float(y)] for x, y in points],
        'speed_mps': speed,
    }


def _goals(path_cfg: dict, slots: np.ndarray, duration: float) -> np.ndarray:
    """(T, n, 2) formation goals every 0.25 s of [0, duration] for a leader path at the origin."""
    t = np.linspace(0.0, duration, max(int(duration / 0.25), 2) + 1)
    ref, _, _ = path_from_config(path_cfg).reference(t)
    return np.asarray(ref)[:, None, :] + slots[None, :, :]


def _shift(cfg: dict, offset: np.ndarray) -> dict:
    cfg = dict(cfg)
    if cfg['type'] == 'waypoints':
        cfg['points_m'] = [
            [x + float(offset[0]), y + float(offset[1])] for x, y in cfg['points_m']
        ]
    else:
        cfg['start_m'] = [float(offset[0]), float(offset[1])]
    return cfg


def _fit(d: Draw, path_cfg: dict, slots: np.ndarray, duration: float):
    """Shorten ``duration`` until every goal fits on the floor, then place the team at random where
    it fits: (path_cfg moved, goals (T, n, 2), duration) or None when it never fits.
    """
    while duration >= d.rules.min_duration_s:
        goals = _goals(path_cfg, slots, duration)
        lo, hi = goals.reshape(-1, 2).min(0), goals.reshape(-1, 2).max(0)
        room = (d.hi - d.lo) - (hi - lo)
        if np.all(room >= 0.0):
            offset = d.lo - lo + d.rng.uniform(0.0, 1.0, 2) * room
            return _shift(path_cfg, offset), goals + offset, duration
        duration *= 0.8
    return None


def _team(d: Draw, ids: list[int], heading: float, path_kind: str, duration: float):
    """A team's robots (mappings), edges and goals (T, n, 2), or None when it does not fit."""
    n = len(ids)
    shape = SHAPES[int(d.rng.integers(len(SHAPES)))] if n > 1 else 'line'
    slots = formation_slots(shape, n, d.uniform(d.rules.spacing_m), heading)
    speed = d.uniform(d.rules.speed_mps)
    fitted = _fit(d, _leader_path(d, path_kind, heading, speed, duration), slots, duration)
    if fitted is None:
        return None
    path_cfg, goals, duration = fitted
    robots = []
    for k, rid in enumerate(ids):
        robots.append(_robot(d, rid, goals[0, k], heading, slots[k], path_cfg if k == 0 else None))
    return robots, tree_edges(slots, ids, d.rng), goals, duration, shape


def _robot(d: Draw, rid: int, goal0, heading: float, slot, path_cfg) -> dict:
    err = d.rng.normal(0.0, d.rules.start_error_m / 2.0, 2).clip(
        -d.rules.start_error_m, d.rules.start_error_m
    )
    theta = heading + d.uniform(
        (-d.rules.start_heading_error_rad, d.rules.start_heading_error_rad)
    )
    item = {
        'id': rid,
        'slot_m': [float(slot[0]), float(slot[1])],
        'initial_pose': [float(goal0[0] + err[0]), float(goal0[1] + err[1]), float(theta)],
        'marker_id': rid,
    }
    if path_cfg is not None:
        item.update(leader=True, path=path_cfg, slot_m=[0.0, 0.0])
    return item


# ------------------------------------------------------------------------------------------------
# Obstacles
# ------------------------------------------------------------------------------------------------


def _obstacle(d: Draw, name: str, center) -> dict:
    """A static, moving or rotating obstacle at ``center`` whose boundary is no faster than
    ``obstacle_speed_max_mps``.
    """
    r1 = d.uniform(d.rules.semi_major_m)
    r2 = d.uniform((d.rules.semi_minor_min_m, r1))
    item = {
        'name': name,
        'center_m': [float(center[0]), float(center[1])],
        'semi_axes_m': [r1, r2],
        'orientation_rad': d.uniform((-math.pi, math.pi)),
    }
    vmax = d.rules.obstacle_speed_max_mps
    kind = d.rng.choice(['static', 'moving', 'rotating'], p=[0.5, 0.25, 0.25])
    if kind == 'moving':
        budget = d.uniform((0.3, 1.0)) * vmax
        drift = d.uniform((0.0, budget))
        angle = d.uniform((-math.pi, math.pi))
        item['velocity_mps'] = [drift * math.cos(angle), drift * math.sin(angle)]
        if d.rng.random() < 0.5 and budget - drift > 1e-3:
            period = d.uniform((15.0, 30.0))
            amp = min(0.06, (budget - drift) * period / (2.0 * math.pi))
            item['oscillation'] = {'amplitude_m': [amp, 0.0], 'period_s': period}
    elif kind == 'rotating':
        omega = d.uniform((0.3, 1.0)) * min(0.1, vmax / r1)
        item['angular_velocity_radps'] = omega if d.rng.random() < 0.5 else -omega
    return item


def _outside_q(item: dict, points: np.ndarray) -> bool:
    """Whether every point (K, 2) lies outside Q = protected_scale P of the obstacle at t = 0."""
    c, phi = np.asarray(item['center_m']), item['orientation_rad']
    r1, r2 = np.asarray(item['semi_axes_m']) * _AVOID.protected_scale
    z = np.atleast_2d(points) - c
    u = math.cos(phi) * z[:, 0] + math.sin(phi) * z[:, 1]
    w = -math.sin(phi) * z[:, 0] + math.cos(phi) * z[:, 1]
    return bool(np.all((u / r1) ** 2 + (w / r2) ** 2 > 1.0))


def _add_obstacles(d: Draw, mapping: dict, count: int, near) -> None:
    """Add up to ``count`` obstacles, each centred by ``near()`` (a point), kept only when no robot
    starts inside its Q and the validator accepts the scenario with it (limit cycles apart).
    """
    starts = np.asarray([r['initial_pose'][:2] for r in mapping['robots']])
    obstacles = mapping.setdefault('obstacles', [])
    for _ in range(4 * count):
        if len(obstacles) >= count:
            break
        item = _obstacle(d, f'O{len(obstacles) + 1}', near())
        if not _outside_q(item, starts):
            continue
        obstacles.append(item)
        try:
            parse_scenario(mapping)
        except ConfigError:
            obstacles.pop()


# ------------------------------------------------------------------------------------------------
# Families
# ------------------------------------------------------------------------------------------------


def _base(d: Draw, name: str, duration: float) -> dict:
    r = d.rules
    return {
        'name': name,
        'duration_s': round(float(duration), 3),
        'floor': {'x_m': list(r.floor_x_m), 'y_m': list(r.floor_y_m)},
        'disturbance': {
            'accel_bound': list(r.disturbance_bound),
            'seed': int(d.rng.integers(0, 2**31 - 1)),
        },
        'robots': [],
        'graph': {'edges': []},
        'obstacles': [],
    }


def _formation(d: Draw, name: str) -> dict | None:
    n = d.integer(d.rules.robots)
    heading = d.uniform((-math.pi, math.pi))
    kind = ('line', 'sinusoid', 'waypoints')[int(d.rng.integers(3))]
    team = _team(d, list(range(n)), heading, kind, d.uniform(d.rules.duration_s))
    if team is None:
        return None
    robots, edges, goals, duration, shape = team
    mapping = _base(d, f'{name}-{shape}-{kind}', duration)
    mapping['robots'], mapping['graph']['edges'] = robots, edges
    steps = goals.shape[0]

    def near():
        t = int(d.rng.integers(int(0.25 * steps), max(int(0.85 * steps), int(0.25 * steps) + 1)))
        return goals[t, int(d.rng.integers(goals.shape[1]))] + d.rng.normal(0.0, 0.1, 2)

    _add_obstacles(d, mapping, d.integer(d.rules.obstacles), near)
    return mapping


def _ray_to_edge(d: Draw, point, angle: float) -> float:
    """Distance from ``point`` along ``angle`` to the edge of the goal box."""
    u = np.array([math.cos(angle), math.sin(angle)])
    out = math.inf
    for k in range(2):
        if abs(u[k]) > 1e-9:
            edge = d.hi[k] if u[k] > 0 else d.lo[k]
            out = min(out, (edge - point[k]) / u[k])
    return max(out, 0.0)


def _crossing(d: Draw, name: str) -> dict | None:
    k = d.integer(d.rules.crossing_robots)
    mid = 0.5 * (d.lo + d.hi)
    cross = mid + d.rng.uniform(-0.3, 0.3, 2) * (d.hi - d.lo)
    first = d.uniform((-math.pi, math.pi))
    robots, longest = [], 0.0
    for i in range(k):
        come_from = first + 2.0 * math.pi * i / k + d.uniform((-0.3, 0.3))
        heading = come_from + math.pi
        lateral = d.uniform((-0.1, 0.1)) * np.array([-math.sin(heading), math.cos(heading)])
        through = cross + lateral
        back, ahead = _ray_to_edge(d, through, come_from), _ray_to_edge(d, through, heading)
        back, ahead = min(back, 1.2), min(ahead, 1.2)
        if back < 0.4 or ahead < 0.4:
            return None
        start = through + back * np.array([math.cos(come_from), math.sin(come_from)])
        end = through + ahead * np.array([math.cos(heading), math.sin(heading)])
        speed = d.uniform(d.rules.speed_mps)
        path = {
            'type': 'waypoints',
            'points_m': [[float(start[0]), float(start[1])], [float(end[0]), float(end[1])]],
            'speed_mps': speed,
        }
        robots.append(_robot(d, i, start, heading, (0.0, 0.0), path))
        longest = max(longest, (back + ahead) / speed + speed / 0.02)
    mapping = _base(d, f'{name}-{k}', longest + d.rules.settle_s)
    mapping['robots'] = robots
    _add_obstacles(
        d, mapping, d.integer(d.rules.crossing_obstacles), lambda: cross + d.rng.normal(0, 0.15, 2)
    )
    return mapping


def _two_teams(d: Draw, name: str) -> dict | None:
    duration = d.uniform(d.rules.duration_s)
    first = d.uniform((-math.pi, math.pi))
    headings = (first, first + math.copysign(d.uniform((1.0, 2.2)), d.rng.random() - 0.5))
    robots, edges, goal_sets, next_id = [], [], [], 0
    for heading in headings:
        n = d.integer(d.rules.team_robots)
        team = _team(d, list(range(next_id, next_id + n)), heading, 'line', duration)
        if team is None:
            return None
        team_robots, team_edges, goals, duration_t, _shape = team
        duration = min(duration, duration_t)
        robots += team_robots
        edges += team_edges
        goal_sets.append(goals)
        next_id += n
    mapping = _base(d, f'{name}-{len(robots)}', duration)
    mapping['robots'], mapping['graph']['edges'] = robots, edges
    starts = np.asarray([r['initial_pose'][:2] for r in robots])
    gap = np.linalg.norm(starts[:, None] - starts[None], axis=2) + np.eye(len(starts)) * 9.0
    if gap.min() < 2.0 * _ROBOT.body_radius_m + _AVOID.agent_keepout_margin_m + 0.05:
        return None
    mid = 0.5 * (goal_sets[0][len(goal_sets[0]) // 2, 0] + goal_sets[1][len(goal_sets[1]) // 2, 0])
    _add_obstacles(
        d, mapping, d.integer(d.rules.crossing_obstacles), lambda: mid + d.rng.normal(0, 0.2, 2)
    )
    return mapping


_BUILDERS = {'formation': _formation, 'crossing': _crossing, 'two_teams': _two_teams}


def resting_gap_m(scenario) -> float:
    """The smallest distance between the goals of two robots of different teams when the paths
    end (each leader's reference at ``duration_s`` plus the slot offset; inf for one team).
    """
    end = {}
    for r in scenario.robots:
        if r.path is not None:
            end[r.id] = np.asarray(r.path.reference(scenario.duration_s)[0], dtype=float)
    teams: dict[int, list] = {}
    for r in scenario.robots:
        lead = scenario.team_leader(r.id)
        if lead in end:
            goal = end[lead] + scenario.slot(r.id) - scenario.slot(lead)
            teams.setdefault(lead, []).append(goal)
    gap = math.inf
    groups = [np.asarray(g) for g in teams.values()]
    for a in range(len(groups)):
        for b in range(a + 1, len(groups)):
            d = np.linalg.norm(groups[a][:, None] - groups[b][None], axis=2)
            gap = min(gap, float(d.min()))
    return gap


def generate(family: str, seed: int, index: int, rules: Rules = Rules()) -> tuple[dict, int]:
    """Scenario ``index`` of ``family`` for campaign ``seed``: (mapping, draws it took). The
    mapping is accepted by :func:`parse_scenario`. ValueError for an unknown family; RuntimeError
    when no draw of :data:`MAX_DRAWS` satisfies the rules.
    """
    if family not in _BUILDERS:
        raise ValueError(f'unknown family {family!r} (one of {", ".join(FAMILIES)})')
    for draw in range(MAX_DRAWS):
        d = Draw(np.random.default_rng([seed, index, draw]), rules)
        mapping = _BUILDERS[family](d, f'{family}-s{seed}-{index}')
        if mapping is None:
            continue
        try:
            scenario = parse_scenario(mapping)
        except ConfigError:
            continue
        if resting_gap_m(scenario) < rules.spacing_m[0]:
            continue
        return mapping, draw + 1
    raise RuntimeError(f'{family}: no scenario satisfied the rules in {MAX_DRAWS} draws')


def perturb(scenario, seed: int, index: int, scale: float = 1.0) -> tuple[dict, int]:
    """A seeded variation ``index`` of a validated ``scenario``: start positions moved by up to
    5 cm and headings by 0.2 rad, obstacle centres by 5 cm, semi-axes by 10 %, orientations by
    0.2 rad (all times ``scale``), a new disturbance seed; (mapping, draws), like :func:`generate`.
    """
    base = scenario_to_mapping(scenario)
    for draw in range(MAX_DRAWS):
        rng = np.random.default_rng([seed, index, draw])
        mapping = scenario_to_mapping(scenario)
        mapping['name'] = f'{base["name"]}-p{seed}-{index}'
        mapping['disturbance']['seed'] = int(rng.integers(0, 2**31 - 1))
        for r in mapping['robots']:
            x, y, th = r['initial_pose']
            dx, dy = rng.uniform(-0.05, 0.05, 2) * scale
            pose = (x + dx, y + dy, th + rng.uniform(-0.2, 0.2) * scale)
            r['initial_pose'] = [float(v) for v in pose]  # plain floats: the mapping is YAML
        for o in mapping['obstacles']:
            o['center_m'] = [
                float(v) for v in np.asarray(o['center_m']) + rng.uniform(-0.05, 0.05, 2) * scale
            ]
            o['semi_axes_m'] = [
                float(v * (1.0 + rng.uniform(-0.1, 0.1) * scale)) for v in o['semi_axes_m']
            ]
            o['orientation_rad'] = float(o['orientation_rad'] + rng.uniform(-0.2, 0.2) * scale)
        try:
            parse_scenario(mapping)
        except ConfigError:
            continue
        return mapping, draw + 1
    raise RuntimeError(
        f'{base["name"]}: no perturbation passed the validator in {MAX_DRAWS} draws'
    )
