"""Scenario files (docs/design.md §5): load a YAML scenario, validate it completely, strictly.

Every problem raises :class:`ConfigError` whose one-line text names the file, the field (a path
such
as ``robots[1].slot_m`` or ``obstacles[0].semi_axes_m``) and the problem. Checks:

* structure: unknown keys at every level, missing required keys, wrong types (booleans are not
  numbers), NaN/inf, duplicate YAML keys, malformed YAML;
* values: robot parameters (S2.3), gains (S3), avoidance scales (S6.1), positive semi-axes,
  positive duration, known path types;
* identities: duplicate robot ids, marker ids and obstacle names; edges between known robots,
  no self-loops or repeated edges;
* teams (S1, S9): each weakly connected component of the graph has exactly one leader, every robot
  is reachable from its team leader, leaders have a path and followers do not, a leader's slot is
  0;
* geometry at start: no robot inside a prohibited region P_j, no two robots closer than the agent
  prohibited circle R_i + R_k + margin (S7);
* geometry over the run: the limit cycles L_j = rho_L P_j of two obstacles never overlap
  (S13 #3), checked exactly for static pairs and sampled every ``_OVERLAP_STEP_S`` for moving ones;
* the optional ``expect:`` block (what a run of the scenario must achieve, checked by
  core/metrics.check_run after `formation sim` and `formation run`): known keys, robot ids of the
  scenario, limits of the right sign, ranges with min <= max.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, fields
import difflib
from functools import cached_property
import math
import re

import numpy as np
import yaml

from ament_formation.core.config_files import (  # noqa: F401 - limits named here too
    MAX_NESTING,
    MAX_YAML_NODES,
    parse_user_yaml,
    read_user_text,
)
from ament_formation.core.errors import ConfigError, excerpt, MAX_MAGNITUDE
from ament_formation.core.model.obstacles import (
    avoided_as_one,
    first_overlaps,
    obstacle_arrays,
    ObstacleField,
    ObstacleSpec,
)
from ament_formation.core.model.paths import Path, path_from_config, SinusoidPath
from ament_formation.core.params import AvoidanceParams, ControlGains, RobotParams

_OVERLAP_STEP_S = 0.25
_NAME_RE = re.compile(r'[A-Za-z0-9_.\-]+')
MAX_NAME_CHARS = 100  # a scenario's or an obstacle's name (titles, legends, CSV columns)

# Bounded input (docs/scenarios.md "Limits"): what a scenario may ask of the machine. A file over
# these limits is refused in one line before any large allocation.
MAX_FILE_BYTES = 1_000_000  # a scenario file (the shipped ones are under 5 kB)
MAX_ROBOTS = 1024
MAX_OBSTACLES = 256  # the limit-cycle overlap check is pairwise
# the limit-cycle check of obstacles that move: pairs that may meet x instants (a few s)
MAX_OBSTACLE_PAIR_SAMPLES = 1e7
MAX_DURATION_S = 86_400.0
MAX_INTEGER = 2**31 - 1
MAX_IMAGE_PX = 8192
# what `formation sim` (and a sweep) may run: about 10 s and well under 1 GB on a 2-core machine
SIM_BUDGET = {
    'robot_steps': 1e7,  # duration / dt x robots (the compiled loop: about 1e6 robot-steps/s)
    'robot_samples': 1e6,  # duration / record period x robots (about 0.6 kB each in memory)
    'pair_samples': 5e6,  # robot pairs x record samples (the metrics' pairwise distances)
    # obstacles: each one's motion is evaluated every step (about 5e7/s; each robot's law checks
    # only the ones within its reach, from lists rebuilt every decision); every obstacle is
    # recorded (memory) and written to obstacles.csv at every record sample
    'obstacle_steps': 1e8,
    'obstacle_samples': 1e6,
    # camera sensing (--sensing): each robot's controller, estimator and camera model run at
    # their real rates in Python, about 0.03 s of CPU per robot-second
    'sensed_robot_seconds': 1000.0,
}


# ------------------------------------------------------------------------------------------------
# Dataclasses
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RobotSpec:
    """One robot of a scenario.

    initial_pose : (x_m, y_m, theta_rad) of the controlled point p and the heading at t = 0
    slot_m : (2,) formation slot c_i relative to its team leader, world frame (S1; leader: 0)
    """

    id: int  # noqa: A003
    params: RobotParams
    initial_pose: tuple[float, float, float]
    slot_m: tuple[float, float]
    leader: bool
    path: Path | None
    marker_id: int


@dataclass(frozen=True)
class DisturbanceSpec:
    """Bound of the smooth disturbance g (S2.3):
    accel_bound = (g1_bar [m/s^2], g2_bar [rad/s^2]).
    """

    accel_bound: tuple[float, float] = (0.0, 0.0)
    seed: int = 0


@dataclass(frozen=True)
class CameraSpec:
    """The simulated overhead camera."""

    fps: float = 30.0
    width_px: int = 640
    height_px: int = 480


@dataclass(frozen=True)
class FloorSpec:
    """The floor the robots drive on: x_m = (x_min, x_max), y_m = (y_min, y_max) [m], world frame.

    A run in which a robot's body (the circle of ``body_radius_m`` around p) crosses the floor's
    edge fails its ``on_floor`` check (core/sim/metrics.check_run).
    """

    x_m: tuple[float, float]
    y_m: tuple[float, float]


@dataclass(frozen=True)
class ExpectSpec:
    """What a run of the scenario must achieve (the ``expect:`` block; docs/scenarios.md), besides
    the checks every run gets (complete, no prohibited entry, no contact). Per-robot limits are
    ``((robot_id, value), ...)`` in robot order; an empty tuple or None means "not checked".

    settled_rms_max_m : formation_rms_settled_m <= limit [m] (a run without a settled window fails)
    final_error_max_m : final_error_m <= limit [m]
    avoidance_entries : ((robot_id, (min, max)), ...): avoidance_entries in [min, max]
    min_clearance_m : metrics min_clearance_m >= this [m] (signed distance of p to every P_j)
    min_inter_robot_distance_m : metrics min_inter_robot_distance_m >= this [m]
    """

    settled_rms_max_m: tuple[tuple[int, float], ...] = ()
    final_error_max_m: tuple[tuple[int, float], ...] = ()
    avoidance_entries: tuple[tuple[int, tuple[int, int]], ...] = ()
    min_clearance_m: float | None = None
    min_inter_robot_distance_m: float | None = None

    @property
    def empty(self) -> bool:
        return not (
            self.settled_rms_max_m
            or self.final_error_max_m
            or self.avoidance_entries
            or self.min_clearance_m is not None
            or self.min_inter_robot_distance_m is not None
        )


@dataclass(frozen=True)
class Scenario:
    """A validated scenario. ``edges`` are (parent, child) pairs: child may receive parent's
    state.
    """

    name: str
    duration_s: float
    robots: tuple[RobotSpec, ...]
    edges: tuple[tuple[int, int], ...]
    obstacles: tuple[ObstacleSpec, ...]
    disturbance: DisturbanceSpec = field(default_factory=DisturbanceSpec)
    avoidance: AvoidanceParams = field(default_factory=AvoidanceParams)
    control: ControlGains = field(default_factory=ControlGains)
    camera: CameraSpec = field(default_factory=CameraSpec)
    expect: ExpectSpec = field(default_factory=ExpectSpec)
    source: str | None = None
    floor: FloorSpec | None = None

    @property
    def robot_ids(self) -> tuple[int, ...]:
        return tuple(r.id for r in self.robots)

    @property
    def leaders(self) -> tuple[int, ...]:
        return tuple(r.id for r in self.robots if r.leader)

    def robot(self, robot_id: int) -> RobotSpec:
        """The RobotSpec with this id (KeyError when absent)."""
        return self._by_id[robot_id]

    def slot(self, robot_id: int) -> np.ndarray:
        """c_i (2,) [m]."""
        return np.asarray(self._by_id[robot_id].slot_m, dtype=float)

    def team_leader(self, robot_id: int) -> int:
        """Id of the leader whose team the robot belongs to (the leader of its graph component)."""
        return self._team_leader[robot_id]

    def avoided_obstacles(self) -> tuple[ObstacleSpec, ...]:
        """The obstacles the law avoids: :attr:`obstacles`, with those too close to pass
        between replaced by one enclosing ellipse (spec S13 #3, docs/law-changes.md §18;
        :func:`avoided_as_one`). The simulators, the robot's controller and the coordinator
        all avoid these; metrics, records and views keep :attr:`obstacles`.
        """
        return self._avoided[0]

    @cached_property
    def _avoided(self) -> tuple:
        av = self.avoidance
        starts = [r.initial_pose[:2] for r in self.robots]
        return avoided_as_one(self.obstacles, av.heading_scale, av.limit_cycle_scale, starts)

    @cached_property
    def _by_id(self) -> dict[int, RobotSpec]:
        return {r.id: r for r in self.robots}

    @cached_property
    def _team_leader(self) -> dict[int, int]:
        return _components_leader(self.robot_ids, self.edges, set(self.leaders))


def _components_leader(ids, edges, leaders) -> dict[int, int]:
    """Leader of each robot's weakly connected component (assumes exactly one per component)."""
    out: dict[int, int] = {}
    for comp in _weak_components(ids, edges):
        lead = [v for v in comp if v in leaders]
        for v in comp:
            out[v] = lead[0] if lead else None
    return out


def _weak_components(ids, edges) -> list[list[int]]:
    adj = {i: set() for i in ids}
    for u, v in edges:
        adj[u].add(v)
        adj[v].add(u)
    seen: set[int] = set()
    comps = []
    for start in sorted(ids):
        if start in seen:
            continue
        comp, queue = [], deque([start])
        seen.add(start)
        while queue:
            u = queue.popleft()
            comp.append(u)
            for v in sorted(adj[u]):
                if v not in seen:
                    seen.add(v)
                    queue.append(v)
        comps.append(sorted(comp))
    return comps


# ------------------------------------------------------------------------------------------------
# Loading
# ------------------------------------------------------------------------------------------------


def load_scenario(path) -> Scenario:
    """Read and validate a scenario YAML file. Raises ConfigError naming ``path``."""
    text = read_user_text(path, 'scenario', MAX_FILE_BYTES)
    return parse_scenario_text(text, str(path))


def parse_scenario_text(text: str, source: str | None = None) -> Scenario:
    """Validate a scenario given as YAML text (what :func:`load_scenario` reads from a file)."""
    if len(text) > MAX_FILE_BYTES:
        raise ConfigError(
            f'{len(text)} characters; a scenario is at most {MAX_FILE_BYTES}', file=source
        )
    return parse_scenario(parse_user_yaml(text, source, 'scenario'), source=source)


def parse_scenario(mapping, source: str | None = None) -> Scenario:
    """Validate a scenario mapping (as loaded from YAML) and build the Scenario."""
    try:
        return _parse(mapping, source)
    except ConfigError as err:
        raise (err.with_file(source) if source else err) from None


# ------------------------------------------------------------------------------------------------
# Field checks
# ------------------------------------------------------------------------------------------------

_TOP_REQUIRED = {'name', 'duration_s', 'robots'}
_TOP_OPTIONAL = {
    'robot',
    'disturbance',
    'graph',
    'obstacles',
    'avoidance',
    'control',
    'camera',
    'expect',
    'floor',
}
_EXPECT_KEYS = {
    'settled_rms_max_m',
    'final_error_max_m',
    'avoidance_entries',
    'min_clearance_m',
    'min_inter_robot_distance_m',
}
_ROBOT_KEYS_REQUIRED = {'id', 'initial_pose'}
_ROBOT_KEYS_OPTIONAL = {'leader', 'path', 'slot_m', 'marker_id'}
_PARAM_KEYS = set(RobotParams.field_names())
_OBSTACLE_REQUIRED = {'name', 'center_m', 'semi_axes_m'}
_OBSTACLE_OPTIONAL = {'orientation_rad', 'velocity_mps', 'angular_velocity_radps', 'oscillation'}


def _keys(mapping, where: str, required: set, optional: set) -> None:
    if not isinstance(mapping, dict):
        raise ConfigError(f'must be a mapping (got {_kind(mapping)})', where or None)
    for key in mapping:
        if not isinstance(key, str):
            raise ConfigError(f'keys must be strings (got {excerpt(key)})', where or None)
    allowed = required | optional
    for key in sorted(set(mapping) - allowed):
        close = difflib.get_close_matches(key, allowed, n=1, cutoff=0.75)
        hint = f'did you mean {close[0]}?' if close else f'allowed: {", ".join(sorted(allowed))}'
        raise ConfigError(f'unknown key ({hint})', _join(where, key))
    for key in sorted(required - set(mapping)):
        raise ConfigError('missing required key', _join(where, key))


def _join(where: str, key: str) -> str:
    return f'{where}.{key}' if where else key


def _kind(value) -> str:
    return 'null' if value is None else type(value).__name__


def _number(value, where: str, *, positive=False, nonneg=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f'must be a number (got {_kind(value)} {excerpt(value)})', where)
    if not math.isfinite(value):
        raise ConfigError(f'must be finite (got {excerpt(value)})', where)
    if abs(value) > MAX_MAGNITUDE:
        raise ConfigError(f'must be within +-{MAX_MAGNITUDE:g} (got {excerpt(value)})', where)
    if positive and not value > 0:
        raise ConfigError(f'must be > 0 (got {excerpt(value)})', where)
    if nonneg and value < 0:
        raise ConfigError(f'must be >= 0 (got {excerpt(value)})', where)
    return float(value)


def _integer(value, where: str, *, nonneg=True) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f'must be an integer (got {_kind(value)} {excerpt(value)})', where)
    if nonneg and value < 0:
        raise ConfigError(f'must be >= 0 (got {excerpt(value)})', where)
    if abs(value) > MAX_INTEGER:
        raise ConfigError(f'must be within +-{MAX_INTEGER} (got {excerpt(value)})', where)
    return int(value)


def _vector(value, where: str, n: int, **kw) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise ConfigError(f'must be a list of {n} numbers (got {excerpt(value)})', where)
    return tuple(_number(v, f'{where}[{i}]', **kw) for i, v in enumerate(value))


def _params_from(mapping: dict, where: str, cls, base: dict | None = None):
    """A parameter dataclass from ``base`` overridden by ``mapping`` (numbers only)."""
    values = dict(base or {})
    for key, value in mapping.items():
        if value is None and key in {'wheel_spin_inertia_kgm2', 'wheel_diameter_inertia_kgm2'}:
            values[key] = None
            continue
        values[key] = _number(value, _join(where, key))
    try:
        return cls(**values)
    except ConfigError as err:
        raise err.under(where) if where else err from None


# ------------------------------------------------------------------------------------------------
# The parser
# ------------------------------------------------------------------------------------------------


def _parse(data, source) -> Scenario:
    if data is None:
        raise ConfigError('the file is empty (expected a mapping with name, duration_s, robots)')
    _keys(data, '', _TOP_REQUIRED, _TOP_OPTIONAL)
    name = data['name']
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f'must be a non-empty string (got {excerpt(name)})', 'name')
    _check_name_length(name, 'name')
    duration = _number(data['duration_s'], 'duration_s', positive=True)
    if duration > MAX_DURATION_S:
        raise ConfigError(
            f'must be <= {MAX_DURATION_S:g} s (got {excerpt(duration)})', 'duration_s'
        )

    # robot defaults
    robot_defaults = data.get('robot', {}) or {}
    _keys(robot_defaults, 'robot', set(), _PARAM_KEYS)
    default_params = _params_from(robot_defaults, 'robot', RobotParams)
    base = {f.name: getattr(default_params, f.name) for f in fields(RobotParams)}

    disturbance = _parse_disturbance(data.get('disturbance', {}))
    avoidance = _parse_params_block(data, 'avoidance', AvoidanceParams)
    control = _parse_params_block(data, 'control', ControlGains)
    camera = _parse_camera(data.get('camera', {}))
    floor = _parse_floor(data['floor']) if data.get('floor') is not None else None

    robots = _parse_robots(data['robots'], base)
    ids = [r.id for r in robots]
    edges = _parse_graph(data.get('graph', {'edges': []}), set(ids))
    obstacles = _parse_obstacles(data.get('obstacles', []) or [])

    _check_teams(robots, edges)
    _check_start_geometry(robots, obstacles, avoidance)
    if floor is not None:
        _check_start_on_floor(robots, floor)
    _check_limit_cycles(obstacles, avoidance, duration)
    starts = [r.initial_pose[:2] for r in robots]
    avoided, members = avoided_as_one(
        obstacles, avoidance.heading_scale, avoidance.limit_cycle_scale, starts
    )
    if len(avoided) < len(obstacles):  # S13 #3 again for an enclosing ellipse (§18)
        order = sorted(range(len(avoided)), key=lambda j: len(members[j]) == 1)  # merged first
        _check_limit_cycles(
            [avoided[j] for j in order], avoidance, duration, [members[j][-1] for j in order]
        )
    expect = _parse_expect(data.get('expect', {}), ids)

    return Scenario(
        name=name.strip(),
        duration_s=duration,
        robots=tuple(robots),
        edges=tuple(edges),
        obstacles=tuple(obstacles),
        disturbance=disturbance,
        avoidance=avoidance,
        control=control,
        camera=camera,
        expect=expect,
        source=source,
        floor=floor,
    )


def _parse_params_block(data, key, cls):
    block = data.get(key, {})
    if block is None:
        block = {}
    _keys(block, key, set(), {f.name for f in fields(cls)})
    return _params_from(block, key, cls)


def _parse_disturbance(block) -> DisturbanceSpec:
    block = {} if block is None else block
    _keys(block, 'disturbance', set(), {'accel_bound', 'seed'})
    bound = _vector(
        block.get('accel_bound', [0.0, 0.0]), 'disturbance.accel_bound', 2, nonneg=True
    )
    seed = _integer(block.get('seed', 0), 'disturbance.seed')
    return DisturbanceSpec(accel_bound=bound, seed=seed)


def _parse_camera(block) -> CameraSpec:
    block = {} if block is None else block
    _keys(block, 'camera', set(), {'fps', 'width_px', 'height_px'})
    fps = _number(block.get('fps', 30.0), 'camera.fps', positive=True)
    width = _integer(block.get('width_px', 640), 'camera.width_px')
    height = _integer(block.get('height_px', 480), 'camera.height_px')
    for key, value in (('width_px', width), ('height_px', height)):
        if not 0 < value <= MAX_IMAGE_PX:
            raise ConfigError(f'must be > 0 and <= {MAX_IMAGE_PX} (got {value})', f'camera.{key}')
    return CameraSpec(fps=fps, width_px=width, height_px=height)


def _parse_floor(block) -> FloorSpec:
    _keys(block, 'floor', {'x_m', 'y_m'}, set())
    limits = []
    for key in ('x_m', 'y_m'):
        lo, hi = _vector(block[key], f'floor.{key}', 2)
        if not hi > lo:
            raise ConfigError(
                f'must be [min, max] with min < max (got {[lo, hi]})', f'floor.{key}'
            )
        limits.append((lo, hi))
    return FloorSpec(x_m=limits[0], y_m=limits[1])


def _per_robot(value, where: str, ids: list[int], parse_one) -> tuple:
    """A per-robot expectation: one value for every robot, or a mapping robot id -> value (ids as
    integers or strings, e.g. ``{"0": 0.01, "1": 0.02}``). Returns ((id, value), ...) in robot
    order.
    """
    if not isinstance(value, dict):
        one = parse_one(value, where)
        return tuple((rid, one) for rid in ids)
    if not value:
        raise ConfigError('must not be empty (a value, or a mapping robot id -> value)', where)
    out = {}
    for key, item in value.items():
        rid = key
        if isinstance(key, str) and re.fullmatch(r'[0-9]+', key.strip()):
            rid = int(key.strip())
        if isinstance(rid, bool) or not isinstance(rid, int) or rid not in ids:
            raise ConfigError(
                f'{excerpt(key)} is not a robot id of the scenario (ids: {sorted(ids)})', where
            )
        if rid in out:
            raise ConfigError(f'robot {rid} is listed twice', where)
        out[rid] = parse_one(item, f'{where}.{key}')
    return tuple((rid, out[rid]) for rid in ids if rid in out)


def _entries_range(value, where: str) -> tuple[int, int]:
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ConfigError(
                f'must be a count or a [min, max] pair of counts (got {excerpt(value)})', where
            )
        lo, hi = _integer(value[0], f'{where}[0]'), _integer(value[1], f'{where}[1]')
        if lo > hi:
            raise ConfigError(f'min must be <= max (got {list(value)})', where)
        return lo, hi
    n = _integer(value, where)
    return n, n


def _parse_expect(block, ids: list[int]) -> ExpectSpec:
    block = {} if block is None else block
    _keys(block, 'expect', set(), _EXPECT_KEYS)

    def limit(value, where):
        return _number(value, where, positive=True)

    kw = {}
    for key in ('settled_rms_max_m', 'final_error_max_m'):
        if key in block:
            kw[key] = _per_robot(block[key], f'expect.{key}', ids, limit)
    if 'avoidance_entries' in block:
        kw['avoidance_entries'] = _per_robot(
            block['avoidance_entries'], 'expect.avoidance_entries', ids, _entries_range
        )
    for key in ('min_clearance_m', 'min_inter_robot_distance_m'):
        if key in block:
            kw[key] = _number(block[key], f'expect.{key}')
    return ExpectSpec(**kw)


def _parse_robots(items, base: dict) -> list[RobotSpec]:
    if not isinstance(items, list) or not items:
        raise ConfigError(f'must be a non-empty list of robots (got {_kind(items)})', 'robots')
    if len(items) > MAX_ROBOTS:
        raise ConfigError(f'{len(items)} robots; at most {MAX_ROBOTS}', 'robots')
    robots: list[RobotSpec] = []
    seen_ids: dict[int, int] = {}
    seen_markers: dict[int, int] = {}
    for i, item in enumerate(items):
        where = f'robots[{i}]'
        _keys(item, where, _ROBOT_KEYS_REQUIRED, _ROBOT_KEYS_OPTIONAL | _PARAM_KEYS)
        rid = _integer(item['id'], f'{where}.id')
        if rid in seen_ids:
            raise ConfigError(
                f'duplicate robot id {rid} (also robots[{seen_ids[rid]}])', f'{where}.id'
            )
        seen_ids[rid] = i
        leader = item.get('leader', False)
        if not isinstance(leader, bool):
            raise ConfigError(f'must be true or false (got {excerpt(leader)})', f'{where}.leader')
        pose = _vector(item['initial_pose'], f'{where}.initial_pose', 3)
        if 'slot_m' in item:
            slot = _vector(item['slot_m'], f'{where}.slot_m', 2)
        elif leader:
            slot = (0.0, 0.0)
        else:
            raise ConfigError(
                'missing required key (a follower needs its formation slot)', f'{where}.slot_m'
            )
        if leader and slot != (0.0, 0.0):
            raise ConfigError(
                f"a team leader's slot must be [0, 0] (S1: c_leader = 0; got {list(slot)})",
                f'{where}.slot_m',
            )
        path_cfg = item.get('path')
        if leader and path_cfg is None:
            raise ConfigError(
                'a leader needs a path (sinusoid, line or waypoints)', f'{where}.path'
            )
        if not leader and path_cfg is not None:
            raise ConfigError(
                'only a leader (leader: true) has a path; a follower tracks its parent',
                f'{where}.path',
            )
        path = None
        if path_cfg is not None:
            try:
                path = path_from_config(path_cfg)
            except ConfigError as err:
                raise err.under(f'{where}.path') from None
        marker = _integer(item.get('marker_id', rid), f'{where}.marker_id')
        if marker in seen_markers:
            raise ConfigError(
                f'duplicate marker id {marker} (also robots[{seen_markers[marker]}])',
                f'{where}.marker_id',
            )
        seen_markers[marker] = i
        overrides = {k: v for k, v in item.items() if k in _PARAM_KEYS}
        params = _params_from(overrides, where, RobotParams, base)
        if path is not None:
            _check_path_feasible(path, params, f'{where}.path')
        robots.append(
            RobotSpec(
                id=rid,
                params=params,
                initial_pose=pose,
                slot_m=slot,
                leader=leader,
                path=path,
                marker_id=marker,
            )
        )
    return robots


def _parse_graph(block, ids: set[int]) -> list[tuple[int, int]]:
    _keys(block, 'graph', {'edges'}, set())
    items = block['edges']
    if items is None:
        items = []
    if not isinstance(items, list):
        raise ConfigError(
            f'must be a list of [parent, child] pairs (got {_kind(items)})', 'graph.edges'
        )
    edges: list[tuple[int, int]] = []
    for k, edge in enumerate(items):
        where = f'graph.edges[{k}]'
        if not isinstance(edge, (list, tuple)) or len(edge) != 2:
            raise ConfigError(f'must be a [parent, child] pair (got {excerpt(edge)})', where)
        parent = _integer(edge[0], f'{where}[0]')
        child = _integer(edge[1], f'{where}[1]')
        for end, rid in (('parent', parent), ('child', child)):
            if rid not in ids:
                raise ConfigError(f'{end} {rid} is not a robot id (ids: {sorted(ids)})', where)
        if parent == child:
            raise ConfigError(f'self-loop {parent} -> {child} is not allowed (S1)', where)
        if (parent, child) in edges:
            raise ConfigError(f'edge {parent} -> {child} is listed twice', where)
        edges.append((parent, child))
    return edges


def _parse_obstacles(items) -> list[ObstacleSpec]:
    if not isinstance(items, list):
        raise ConfigError(f'must be a list of obstacles (got {_kind(items)})', 'obstacles')
    if len(items) > MAX_OBSTACLES:
        raise ConfigError(f'{len(items)} obstacles; at most {MAX_OBSTACLES}', 'obstacles')
    out: list[ObstacleSpec] = []
    seen: dict[str, int] = {}
    for j, item in enumerate(items):
        where = f'obstacles[{j}]'
        _keys(item, where, _OBSTACLE_REQUIRED, _OBSTACLE_OPTIONAL)
        name = item['name']
        if not isinstance(name, str) or not name.strip():
            raise ConfigError(f'must be a non-empty string (got {excerpt(name)})', f'{where}.name')
        _check_name_length(name, f'{where}.name')
        if not _NAME_RE.fullmatch(name):
            raise ConfigError(
                f"must use only letters, digits, '_', '-' and '.' (got {excerpt(name)})",
                f'{where}.name',
            )
        if name in seen:
            raise ConfigError(
                f'duplicate obstacle name {excerpt(name)} (also obstacles[{seen[name]}])',
                f'{where}.name',
            )
        seen[name] = j
        center = _vector(item['center_m'], f'{where}.center_m', 2)
        axes = _vector(item['semi_axes_m'], f'{where}.semi_axes_m', 2)
        for k, a in enumerate(axes):
            if not a > 0:
                raise ConfigError(
                    f'semi-axes must be > 0 m (got {list(axes)})', f'{where}.semi_axes_m[{k}]'
                )
        phi = _number(item.get('orientation_rad', 0.0), f'{where}.orientation_rad')
        if axes[1] > axes[0]:  # normalise to r1 >= r2 (the same ellipse, turned by pi/2)
            axes = (axes[1], axes[0])
            phi += 0.5 * math.pi
        vel = _vector(item.get('velocity_mps', [0.0, 0.0]), f'{where}.velocity_mps', 2)
        omega = _number(item.get('angular_velocity_radps', 0.0), f'{where}.angular_velocity_radps')
        amp, period = (0.0, 0.0), 0.0
        if 'oscillation' in item:
            osc = item['oscillation']
            _keys(osc, f'{where}.oscillation', {'amplitude_m', 'period_s'}, set())
            amp = _vector(osc['amplitude_m'], f'{where}.oscillation.amplitude_m', 2)
            period = _number(osc['period_s'], f'{where}.oscillation.period_s', positive=True)
        try:
            out.append(
                ObstacleSpec(
                    name=name,
                    center_m=center,
                    semi_axes_m=axes,
                    orientation_rad=phi,
                    velocity_mps=vel,
                    angular_velocity_radps=omega,
                    oscillation_amplitude_m=amp,
                    oscillation_period_s=period,
                )
            )
        except ConfigError as err:
            raise err.under(where) from None
    return out


# ------------------------------------------------------------------------------------------------
# Cross checks
# ------------------------------------------------------------------------------------------------


def _check_teams(robots: list[RobotSpec], edges: list[tuple[int, int]]) -> None:
    ids = [r.id for r in robots]
    index = {r.id: i for i, r in enumerate(robots)}
    leaders = {r.id for r in robots if r.leader}
    for comp in _weak_components(ids, edges):
        lead = [v for v in comp if v in leaders]
        if len(lead) == 0:
            raise ConfigError(
                f'the team of robots {comp} has no leader '
                "(mark one robot 'leader: true' or connect "
                'them to a leader through graph.edges)',
                f'robots[{index[comp[0]]}]',
            )
        if len(lead) > 1:
            raise ConfigError(
                f'robots {lead} are leaders of one connected team {comp}: a team has exactly one '
                'leader (split the graph or make one a follower)',
                f'robots[{index[lead[1]]}].leader',
            )
        out = {v: [] for v in comp}
        for u, v in edges:
            if u in out:
                out[u].append(v)
        reached = {lead[0]}
        queue = deque([lead[0]])
        while queue:
            u = queue.popleft()
            for v in out[u]:
                if v not in reached:
                    reached.add(v)
                    queue.append(v)
        missing = [v for v in comp if v not in reached]
        if missing:
            raise ConfigError(
                f'robot {missing[0]} cannot be reached from its team leader {lead[0]} along '
                'graph.edges [parent, child]',
                'graph.edges',
            )


def _check_start_on_floor(robots, floor: FloorSpec) -> None:
    for i, r in enumerate(robots):
        x, y = r.initial_pose[:2]
        rad = r.params.body_radius_m
        inside = (
            floor.x_m[0] + rad <= x <= floor.x_m[1] - rad
            and floor.y_m[0] + rad <= y <= floor.y_m[1] - rad
        )
        if not inside:
            raise ConfigError(
                f'robot {r.id} starts at ({x:.3f}, {y:.3f}) m with its body '
                f'(radius {rad:g} m) not on the floor x {list(floor.x_m)}, y {list(floor.y_m)}',
                f'robots[{i}].initial_pose',
            )


def _check_start_geometry(robots, obstacles, avoidance: AvoidanceParams) -> None:
    if obstacles:
        field_ = ObstacleField(obstacles).at(0.0)
        for i, r in enumerate(robots):
            p = np.asarray(r.initial_pose[:2])
            for j, obs in enumerate(obstacles):
                z = p - field_.center_m[j]
                c, s = math.cos(field_.phi_rad[j]), math.sin(field_.phi_rad[j])
                u, w = c * z[0] + s * z[1], -s * z[0] + c * z[1]
                r1, r2 = field_.semi_axes_m[j]
                if (u / r1) ** 2 + (w / r2) ** 2 < 1.0:
                    raise ConfigError(
                        f'robot {r.id} starts inside the prohibited region P '
                        f'of obstacle {excerpt(obs.name)} '
                        '(S13 #2: never start a mission in collision)',
                        f'robots[{i}].initial_pose',
                    )
    for a in range(len(robots)):
        for b in range(a + 1, len(robots)):
            ra, rb = robots[a], robots[b]
            keepout = (
                ra.params.body_radius_m
                + rb.params.body_radius_m
                + avoidance.agent_keepout_margin_m
            )
            dist = math.dist(ra.initial_pose[:2], rb.initial_pose[:2])
            if dist < keepout:
                raise ConfigError(
                    f'robots {ra.id} and {rb.id} start {dist:.3f} m apart, '
                    'inside the robot prohibited '
                    f'circle {keepout:.3f} m (S7)',
                    f'robots[{b}].initial_pose',
                )


def _check_name_length(name: str, where: str) -> None:
    if len(name) > MAX_NAME_CHARS:
        raise ConfigError(
            f'at most {MAX_NAME_CHARS} characters (got {excerpt(name)})', where
        )


def _check_limit_cycles(
    obstacles, avoidance: AvoidanceParams, duration_s: float, index_of=None
) -> None:
    """S13 #3: the limit cycles L_j = rho_L P_j of different obstacles must never overlap
    (checked every :data:`_OVERLAP_STEP_S` of the scenario when one of a pair moves or turns).
    ``index_of``: the scenario's obstacle index of each given one (default: its position).

    Pairs whose L's cannot meet (the boxes their swept bounding circles stay in, then the
    circles at each instant) are not tested further; the first overlapping pair in index order
    is named, at its first instant. More than :data:`MAX_OBSTACLE_PAIR_SAMPLES` instants of
    pairs that may meet is refused (docs/scenarios.md "Limits").
    """
    m = len(obstacles)
    if m < 2:
        return
    c0, vel, amp, omega, phi0, phid, axes, static = obstacle_arrays(obstacles)
    axes = axes * avoidance.limit_cycle_scale
    reach = axes.max(axis=1)  # L's bounding circle
    end = c0 + vel * duration_s  # centre = c0 + v t + A sin(w t) stays in a box
    lo = np.minimum(c0, end) - np.abs(amp) - reach[:, None]
    hi = np.maximum(c0, end) + np.abs(amp) + reach[:, None]
    a, b = np.triu_indices(m, 1)
    near = np.all((lo[a] <= hi[b]) & (lo[b] <= hi[a]), axis=1)
    a, b = a[near], b[near]
    moving = ~(static[a] & static[b])
    times = np.arange(0.0, duration_s + _OVERLAP_STEP_S, _OVERLAP_STEP_S)
    times[-1] = min(times[-1], duration_s)
    if moving.sum() * len(times) > MAX_OBSTACLE_PAIR_SAMPLES:
        raise ConfigError(
            f'{moving.sum()} pairs of obstacles that move near each other for {duration_s:g} s '
            f'need {moving.sum() * len(times):.3g} pair-samples of the limit-cycle check, over '
            f'the budget of {MAX_OBSTACLE_PAIR_SAMPLES:.3g} (docs/scenarios.md "Limits"): '
            'shorten duration_s or use fewer moving obstacles',
            'obstacles',
        )
    first = {}  # (a, b) -> the first time [s] its L's overlap
    for pick, when in ((~moving, times[:1]), (moving, times)):  # at rest: one instant
        pairs = np.stack([a, b], 1)[pick]
        hit = first_overlaps(when, c0, vel, amp, omega, phi0, phid, axes, pairs)
        first.update(
            ((int(x), int(y)), float(when[k])) for x, y, k in zip(a[pick], b[pick], hit) if k >= 0
        )
    if first:
        (x, y), when = min(first.items())
        kind = '' if static[x] and static[y] else f' at t = {when:.2f} s'
        raise ConfigError(
            f'the limit cycles (L = {avoidance.limit_cycle_scale} P) of obstacles '
            f'{excerpt(obstacles[x].name)} and {excerpt(obstacles[y].name)} '
            f'overlap{kind}; '
            'move them apart or '
            'merge them into one enclosing ellipse (S13 #3)',
            f'obstacles[{y if index_of is None else index_of[y]}]',
        )


def check_sim_budget(
    scenario: Scenario, dt_s: float, record_every_s: float, budget=None, sensed: bool = False
) -> None:
    """Raise ConfigError (one line) when simulating ``scenario`` at ``dt_s`` with a record every
    ``record_every_s`` (``sensed``: with camera sensing) would exceed :data:`SIM_BUDGET` (or
    ``budget``): the work and memory a run of `formation sim` may take on this class of machine.
    """
    budget = {**SIM_BUDGET, **(budget or {})}
    if scenario.duration_s < max(dt_s, record_every_s):
        raise ConfigError(
            f'{scenario.duration_s:g} s is shorter than one step or record '
            f'({max(dt_s, record_every_s):g} s): nothing would be simulated',
            'duration_s',
        )
    n, m = len(scenario.robots), len(scenario.obstacles)
    steps = scenario.duration_s / dt_s
    samples = scenario.duration_s / max(record_every_s, dt_s)
    need = {
        'robot_steps': steps * n,
        'robot_samples': samples * n,
        'pair_samples': samples * n * (n - 1) / 2,
        'obstacle_steps': steps * m,
        'obstacle_samples': samples * m,
        'sensed_robot_seconds': scenario.duration_s * n if sensed else 0.0,
    }
    for key, value in need.items():
        if value > budget[key]:
            what = key.replace('_', '-')
            who = f'{m} obstacles' if key.startswith('obstacle') else f'{n} robots'
            fewer = 'robots or obstacles' if 'obstacle' in key else 'robots'
            other = 'ideal sensing' if key == 'sensed_robot_seconds' else 'a longer record period'
            raise ConfigError(
                f'{who} for {scenario.duration_s:g} s need {value:.3g} {what}'
                f', over the budget of {budget[key]:.3g} (docs/scenarios.md "Limits"): shorten '
                f'duration_s, use fewer {fewer} or {other}',
                'duration_s',
            )


# ------------------------------------------------------------------------------------------------
# Writing a scenario back (run directories keep the exact scenario they ran)
# ------------------------------------------------------------------------------------------------


def _check_path_feasible(path, params: RobotParams, where: str) -> None:
    """A sinusoid travelled at constant speed v0 asks its robot's point for v0^2 A k^2 at its
    crests (the curvature A k^2 times v0^2); refuse one that asks for more than the torque limit
    gives the point, 2 tau_max / (m~ r) (S2.2): no robot can follow it, and its arc-length
    integral needs A k panels per time (a 200 m amplitude took 16 s of a run's set-up).
    """
    curve = getattr(path, 'path', path)  # a HeldPath wraps the path it stops
    if not isinstance(curve, SinusoidPath):
        return
    need = curve.speed_mps**2 * curve.amplitude_m * curve.wavenumber_radpm**2
    can = params.accel_limit_mps2
    if need > can:
        raise ConfigError(
            f'the sinusoid asks for {need:.3g} m/s^2 at its crests (speed^2 amplitude '
            f'wavenumber^2), more than the robot can give ({can:.3g} m/s^2 at its torque limit): '
            'lower amplitude_m, wavenumber_radpm or speed_mps',
            where,
        )


def _path_to_mapping(path) -> dict:
    from ament_formation.core.model.paths import HeldPath, LinePath, SinusoidPath, WaypointPath

    if isinstance(path, HeldPath):
        return {**_path_to_mapping(path.path), 'stop_s': path.t_end_s}
    if isinstance(path, SinusoidPath):
        return {
            'type': 'sinusoid',
            'start_m': list(path.start_m),
            'amplitude_m': path.amplitude_m,
            'wavenumber_radpm': path.wavenumber_radpm,
            'speed_mps': path.speed_mps,
            'heading_rad': path.heading_rad,
        }
    if isinstance(path, LinePath):
        return {
            'type': 'line',
            'start_m': list(path.start_m),
            'heading_rad': path.heading_rad,
            'speed_mps': path.speed_mps,
        }
    if isinstance(path, WaypointPath):
        return {
            'type': 'waypoints',
            'points_m': [list(p) for p in path.points_m],
            'speed_mps': path.speed_mps,
            'accel_mps2': path.accel_mps2,
        }
    raise TypeError(f'unknown path {excerpt(path)}')


def scenario_to_mapping(scenario: Scenario) -> dict:
    """The scenario as a mapping that :func:`parse_scenario` reads back to an equal Scenario.

    Every robot lists all its parameters explicitly (no ``robot:`` defaults block).
    """

    def floats(values):
        return [float(v) for v in values]

    robots = []
    for r in scenario.robots:
        item = {
            'id': r.id,
            'leader': r.leader,
            'slot_m': floats(r.slot_m),
            'initial_pose': floats(r.initial_pose),
            'marker_id': r.marker_id,
        }
        if r.path is not None:
            item['path'] = _path_to_mapping(r.path)
        for f in fields(RobotParams):
            value = getattr(r.params, f.name)
            item[f.name] = None if value is None else float(value)
        robots.append(item)
    obstacles = []
    for o in scenario.obstacles:
        item = {
            'name': o.name,
            'center_m': floats(o.center_m),
            'semi_axes_m': floats(o.semi_axes_m),
            'orientation_rad': float(o.orientation_rad),
            'velocity_mps': floats(o.velocity_mps),
            'angular_velocity_radps': float(o.angular_velocity_radps),
        }
        if o.oscillation_period_s > 0:
            item['oscillation'] = {
                'amplitude_m': floats(o.oscillation_amplitude_m),
                'period_s': float(o.oscillation_period_s),
            }
        obstacles.append(item)
    out = {
        'name': scenario.name,
        'duration_s': float(scenario.duration_s),
        'disturbance': {
            'accel_bound': floats(scenario.disturbance.accel_bound),
            'seed': int(scenario.disturbance.seed),
        },
        'robots': robots,
        'graph': {'edges': [[int(u), int(v)] for u, v in scenario.edges]},
        'obstacles': obstacles,
        'avoidance': {
            f.name: float(getattr(scenario.avoidance, f.name)) for f in fields(AvoidanceParams)
        },
        'control': {
            f.name: float(getattr(scenario.control, f.name)) for f in fields(ControlGains)
        },
        'camera': {
            'fps': float(scenario.camera.fps),
            'width_px': int(scenario.camera.width_px),
            'height_px': int(scenario.camera.height_px),
        },
    }
    if scenario.floor is not None:
        out['floor'] = {'x_m': floats(scenario.floor.x_m), 'y_m': floats(scenario.floor.y_m)}
    e = scenario.expect
    if not e.empty:
        expect = {}
        for key in ('settled_rms_max_m', 'final_error_max_m'):
            if getattr(e, key):
                expect[key] = {int(rid): float(v) for rid, v in getattr(e, key)}
        if e.avoidance_entries:
            expect['avoidance_entries'] = {
                int(rid): [int(lo), int(hi)] for rid, (lo, hi) in e.avoidance_entries
            }
        for key in ('min_clearance_m', 'min_inter_robot_distance_m'):
            if getattr(e, key) is not None:
                expect[key] = float(getattr(e, key))
        out['expect'] = expect
    return out


def dump_scenario(scenario: Scenario) -> str:
    """YAML text of :func:`scenario_to_mapping`."""
    return yaml.safe_dump(scenario_to_mapping(scenario), sort_keys=False, default_flow_style=None)
