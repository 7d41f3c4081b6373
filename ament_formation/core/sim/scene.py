"""What the live view shows (ROS-free): the arena at one scenario time, and the per-robot series.

:class:`LiveScene` is built once from a scenario. Given the robots' newest states, modes and the
current parents of /formation/graph it returns

* :meth:`LiveScene.scene`: a :class:`Scene` of plain numbers: every robot (pose, body radius,
  mode, target, direction, its formation goal g_i, the heading of its avoidance circulation),
  every obstacle at scenario time t (centre, orientation phi_j, semi-axes of P_j and the scales of
  P, L = rho_L P and Q = kappa P, spec S6.1; each outline as a closed polyline in the obstacle's
  own frame, so it moves and turns with the obstacle's pose) and the active graph edges;
* :meth:`LiveScene.series`: per robot the formation error |p_i - g_i| [m], the clearance (exact
  signed distance of p_i to the nearest P_j, < 0 inside) [m], the distance to the nearest other
  robot [m] and the wheel torques [N m].

The formation goal is the metrics' one (core/sim/metrics.py, ros/run_record.py): a leader's r(t), a
follower's original parent's point p plus delta = c_i - c_parent (S1). Scenario time t is ROS time
minus the mission start ``start_s`` of /formation/graph; before the start t is None and goals and
obstacles are taken at t = 0.

States are rows [x_m, y_m, theta_rad, v_mps, omega_radps] with (x, y) the controlled point p
(spec S2.1); everything is in the world frame, SI units.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from ament_formation.core.control.rewiring import FormationGraph
from ament_formation.core.model.ellipse import ellipse_outline, signed_distance_to_ellipse
from ament_formation.core.model.obstacles import ObstacleField

AVOIDANCE_MODES = ('obstacle', 'yield', 'mutual')  # S8 modes in which a robot goes round a target

# a stable colour per robot id (the live view's and the RViz markers' of ros/messages.py)
PALETTE = (
    (0.12, 0.47, 0.71),
    (1.0, 0.5, 0.05),
    (0.17, 0.63, 0.17),
    (0.84, 0.15, 0.16),
    (0.58, 0.4, 0.74),
    (0.55, 0.34, 0.29),
    (0.89, 0.47, 0.76),
    (0.5, 0.5, 0.5),
)


def robot_rgb(robot_id: int) -> tuple[float, float, float]:
    """(r, g, b) in [0, 1] of a robot id."""
    return PALETTE[int(robot_id) % len(PALETTE)]


def circulation_heading_rad(p_m, center_m, direction: str | None) -> float | None:
    """Heading [rad] of the sense in which a robot at ``p_m`` goes round a target at ``center_m``:
    (p - c) turned by +90 deg for ``ccw``, -90 deg for ``cw``; None for another direction or p = c.
    """
    if direction not in ('ccw', 'cw'):
        return None
    dx, dy = float(p_m[0] - center_m[0]), float(p_m[1] - center_m[1])
    if dx == 0.0 and dy == 0.0:
        return None
    radial = math.atan2(dy, dx)
    return radial + (0.5 * math.pi if direction == 'ccw' else -0.5 * math.pi)


def mode_label(robot_id: int, mode: dict | None) -> str:
    """The text shown next to a robot: ``robot 1`` and, while avoiding, ``obstacle O1 ccw``."""
    if not mode:
        return f'robot {robot_id}'
    name = mode.get('mode') or '?'
    parts = [str(name)]
    if mode.get('target') is not None and name in AVOIDANCE_MODES:
        parts.append(str(mode['target']))
    if mode.get('direction') and name in AVOIDANCE_MODES:
        parts.append(str(mode['direction']))
    return f'robot {robot_id}\n{" ".join(parts)}'


def is_avoiding(mode: dict | None) -> bool:
    """True in an avoidance mode (the mode JSON's ``avoiding`` flag, or its mode name)."""
    if not mode:
        return False
    if 'avoiding' in mode:
        return bool(mode['avoiding'])
    return mode.get('mode') in AVOIDANCE_MODES


@dataclass(frozen=True)
class RobotView:
    """One robot as shown: pose (3,) [x_m, y_m, theta_rad] of p; ``goal_m`` (2,) or None when its
    original parent is unknown; ``target_m`` (2,) centre of what it avoids (None otherwise);
    ``circulation_rad`` heading of its sense of circulation round the target (None otherwise).
    """

    id: int  # noqa: A003
    pose: np.ndarray
    body_radius_m: float
    mode: str
    target: str | None
    direction: str | None
    avoiding: bool
    label: str
    goal_m: np.ndarray | None
    target_m: np.ndarray | None
    circulation_rad: float | None


@dataclass(frozen=True)
class ObstacleView:
    """One obstacle at time t: centre (2,) [m], orientation phi [rad], semi-axes (2,) of P_j [m],
    and per outline name ("P", "L", "Q") its scale and its (n + 1, 2) polyline in the obstacle
    frame (apply the pose (centre, phi) to place it in the world).
    """

    name: str
    center_m: np.ndarray
    phi_rad: float
    semi_axes_m: np.ndarray
    outlines: dict[str, tuple[float, np.ndarray]]


@dataclass(frozen=True)
class EdgeView:
    """An active graph edge parent -> child with both robots' points p (2,) [m]."""

    parent: int
    child: int
    parent_m: np.ndarray
    child_m: np.ndarray


@dataclass(frozen=True)
class Scene:
    """The arena at scenario time ``t_s`` (None before the mission start)."""

    t_s: float | None
    robots: tuple[RobotView, ...]
    obstacles: tuple[ObstacleView, ...]
    edges: tuple[EdgeView, ...]


class LiveScene:
    """Scene and series of one scenario (see the module docstring).

    Parameters
    ----------
    scenario : a validated :class:`~ament_formation.core.scenario.loader.Scenario`
    outline_points : number of segments of each ellipse outline
    """

    def __init__(self, scenario, outline_points: int = 64):
        self.scenario = scenario
        self.ids = tuple(scenario.robot_ids)
        self.field = ObstacleField(scenario.obstacles)
        self.names = self.field.names
        graph = FormationGraph.from_scenario(scenario)
        self.original_parent = dict(graph.original_parent)
        self.offset = {
            c: graph.offset(c, p) for c, p in self.original_parent.items() if p is not None
        }
        self.radius = {r.id: float(r.params.body_radius_m) for r in scenario.robots}
        self.path = {r.id: r.path for r in scenario.robots if r.leader and r.path is not None}
        av = scenario.avoidance
        self.scales = {'P': 1.0, 'L': float(av.limit_cycle_scale), 'Q': float(av.protected_scale)}
        self._outlines = [
            {
                k: (s, ellipse_outline(np.asarray(o.semi_axes_m) * s, outline_points))
                for k, s in self.scales.items()
            }
            for o in scenario.obstacles
        ]

    # ------------------------------------------------------------------ pieces
    def goals(self, t_s: float | None, states: dict) -> dict[int, np.ndarray | None]:
        """{id: g_i (2,) [m] or None}: leader r(t) (t = 0 before the start); follower p of its
        original parent + delta, None while that parent's state is unknown.
        """
        t = 0.0 if t_s is None else max(0.0, float(t_s))
        out: dict[int, np.ndarray | None] = {}
        for rid in self.ids:
            if rid in self.path:
                out[rid] = np.asarray(self.path[rid].reference(t)[0], dtype=float)
                continue
            parent = self.original_parent.get(rid)
            xp = states.get(parent) if parent is not None else None
            out[rid] = None if xp is None else np.asarray(xp[:2], dtype=float) + self.offset[rid]
        return out

    def obstacles_at(self, t_s: float | None) -> tuple[ObstacleView, ...]:
        """Every obstacle at scenario time ``t_s`` (0 before the start)."""
        if not len(self.field):
            return ()
        obs = self.field.at(0.0 if t_s is None else float(t_s))
        return tuple(
            ObstacleView(
                name,
                obs.center_m[j].copy(),
                float(obs.phi_rad[j]),
                obs.semi_axes_m[j].copy(),
                self._outlines[j],
            )
            for j, name in enumerate(self.names)
        )

    def target_center(
        self, target, t_s: float | None, states: dict, obstacles
    ) -> np.ndarray | None:
        """Centre (2,) [m] of a mode target: an obstacle name or ``robot_<k>`` (None if
        unknown).
        """
        if not isinstance(target, str):
            return None
        if target.startswith('robot_'):
            try:
                xk = states.get(int(target[len('robot_'):]))
            except ValueError:
                return None
            return None if xk is None else np.asarray(xk[:2], dtype=float)
        for o in obstacles:
            if o.name == target:
                return o.center_m
        return None

    # ------------------------------------------------------------------ outputs
    def scene(self, t_s: float | None, states: dict, modes: dict, parents: dict) -> Scene:
        """The arena. ``states`` {id: (5,)} (robots not heard yet are left out), ``modes``
        {id: mode dict of robot_<id>/mode}, ``parents`` {child: parent or None} of the graph.
        """
        obstacles = self.obstacles_at(t_s)
        goals = self.goals(t_s, states)
        robots = []
        for rid in self.ids:
            x = states.get(rid)
            if x is None:
                continue
            mode = modes.get(rid) or {}
            avoiding = is_avoiding(mode)
            target_m = (
                self.target_center(mode.get('target'), t_s, states, obstacles)
                if avoiding
                else None
            )
            circ = (
                None
                if target_m is None
                else circulation_heading_rad(x[:2], target_m, mode.get('direction'))
            )
            robots.append(
                RobotView(
                    rid,
                    np.asarray(x[:3], dtype=float),
                    self.radius[rid],
                    str(mode.get('mode', 'unknown')),
                    mode.get('target'),
                    mode.get('direction'),
                    avoiding,
                    mode_label(rid, mode),
                    goals[rid],
                    target_m,
                    circ,
                )
            )
        edges = tuple(
            EdgeView(
                int(p),
                int(c),
                np.asarray(states[p][:2], dtype=float),
                np.asarray(states[c][:2], dtype=float),
            )
            for c, p in sorted(parents.items())
            if p is not None and p in states and c in states
        )
        return Scene(t_s, tuple(robots), obstacles, edges)

    def series(self, t_s: float | None, states: dict, torques: dict) -> dict[int, dict]:
        """{id: {formation_error_m, clearance_m, nearest_obstacle, robot_distance_m,
        torque_left_nm, torque_right_nm}} for every robot with a state (None where unknown).
        ``torques`` {id: (2,) [left, right] N m}.
        """
        ids = [rid for rid in self.ids if states.get(rid) is not None]
        if not ids:
            return {}
        p = np.array([states[rid][:2] for rid in ids], dtype=float)  # (N, 2)
        goals = self.goals(t_s, states)
        # clearance: exact signed distance of every p to every P_j at time t, min over j
        m = len(self.field)
        if m:
            obs = self.field.at(0.0 if t_s is None else float(t_s))
            pts = np.repeat(p, m, axis=0)  # (N M, 2)
            centers = np.tile(obs.center_m, (len(ids), 1))
            phis = np.tile(obs.phi_rad, len(ids))
            axes = np.tile(obs.semi_axes_m, (len(ids), 1))
            dist = signed_distance_to_ellipse(pts, centers, phis, axes[:, 0], axes[:, 1]).reshape(
                len(ids), m
            )
            nearest = np.argmin(dist, axis=1)
        # nearest other robot
        gaps = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
        np.fill_diagonal(gaps, np.inf)
        out = {}
        for k, rid in enumerate(ids):
            goal = goals[rid]
            tau = torques.get(rid)
            gap = float(gaps[k].min()) if len(ids) > 1 else None
            out[rid] = {
                'formation_error_m': None if goal is None else float(np.hypot(*(p[k] - goal))),
                'clearance_m': float(dist[k, nearest[k]]) if m else None,
                'nearest_obstacle': self.names[nearest[k]] if m else None,
                'robot_distance_m': gap,
                'torque_left_nm': None if tau is None else float(tau[0]),
                'torque_right_nm': None if tau is None else float(tau[1]),
            }
        return out


def finite_or_none(value):
    """``value`` as a float, or None when it is None, NaN or inf (JSON has no NaN)."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def scenario_time_s(now_s: float, start_s: float | None) -> float | None:
    """Scenario time t = now - start_s [s], None before the mission start is known."""
    return None if start_s is None else float(now_s) - float(start_s)
