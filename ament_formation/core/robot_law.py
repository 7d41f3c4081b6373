"""ONE robot's switching automaton and sliding-mode law for the ROS controller node, built from
exactly the functions the simulator uses: :func:`ament_formation.core.encounters.decide` (S8
automaton: entry, re-targeting, exit with dwell and cool-down) and
:func:`ament_formation.core.simulator.robot_law` (S3/S4/S6 law of the current mode).

The robot sees itself, its current parent (state and commanded acceleration, S4 feed-forward)
and its original parent (exit goal, S8.3 item 1). Obstacles come from the scenario at scenario
time. Robot-robot encounters (S7) need every robot's state and are not decided here: this law
runs with N = 1 in ``decide`` (see the report of issue 5).

Rows of the small arrays passed to the compiled functions: 0 = this robot, 1 = current parent,
2 = original parent.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ament_formation.core.automaton import MODE_C, MODE_NAMES, MODE_OBSTACLE, SwitchingParams
from ament_formation.core.dynamics import PlantCoeffs
from ament_formation.core.encounters import decide
from ament_formation.core.graph import FormationGraph
from ament_formation.core.kernels import point_velocity_k
from ament_formation.core.simulator import goals_and_fields, robot_law


@dataclass(frozen=True)
class LawOutput:
    """One control step: torques [left, right] N m, commanded point acceleration (2,) [m/s^2,
    world], mode name, target (obstacle name or None), direction ("cw"/"ccw"/None), avoiding,
    saturated (S3.6), sliding variable sigma (2,) [m/s], formation goal (2,) [m]."""

    torque_nm: np.ndarray
    accel_cmd_mps2: np.ndarray
    mode: str
    target: str | None
    direction: str | None
    avoiding: bool
    saturated: bool
    sigma_mps: np.ndarray
    goal_m: np.ndarray


class SingleRobotLaw:
    """See the module docstring. ``step`` is called at the control rate with scenario time."""

    def __init__(self, scenario, robot_id: int, switching: SwitchingParams | None = None):
        self.scenario = scenario
        self.rid = int(robot_id)
        spec = scenario.robot(self.rid)
        self.spec = spec
        switching = switching or SwitchingParams(avoidance=scenario.avoidance)
        self.prm = switching.as_array()
        self.graph = FormationGraph.from_scenario(scenario)
        self.original_parent = self.graph.original_parent.get(self.rid)
        g = scenario.control
        self.gains = np.array([g.switching_gain_mps2, g.boundary_layer_mps, g.formation_gain_per_s,
                               g.formation_speed_cap_mps, g.reaching_rate_mps2], dtype=float)
        ids = [self.rid]
        par = self.original_parent
        others = [par if par is not None else self.rid]
        k = PlantCoeffs.from_params([scenario.robot(i).params for i in ids + others + others])
        self.coeffs = np.ascontiguousarray(np.stack([k.m_tilde, k.I_tilde, k.r, k.a, k.d, k.m_c, k.tau_max]))
        self.rbody = np.full(3, spec.params.body_radius_m)
        self.d = float(spec.params.com_offset_m)
        obs = scenario.obstacles
        self.obstacle_names = tuple(o.name for o in obs)
        m = len(obs)
        from ament_formation.core.obstacles import ObstacleField

        self.field = ObstacleField(obs)
        self.oaxes = np.array([o.semi_axes_m for o in obs], dtype=float).reshape(m, 2)
        self.ostatic = np.array([not (o.moves or o.rotates) for o in obs], dtype=np.bool_)
        self.orig_offset = (self.graph.offset(self.rid, par) if par is not None else np.zeros(2))
        # automaton state (N = 1)
        self.mode = np.zeros(1, dtype=np.int64)
        self.tgt = np.full(1, -1, dtype=np.int64)
        self.sdir = np.ones(1)
        self.t_entry = np.zeros(1)
        self.since = np.full(1, -1.0)
        self.last_kind = np.zeros(1, dtype=np.int64)
        self.last_tgt = np.full(1, -1, dtype=np.int64)
        self.last_exit = np.full(1, -1e9)
        self.wc = np.zeros((1, 2))
        self.wtgt = np.zeros((1, 2))
        self.ev = np.zeros((16, 6))
        self.team = np.zeros(1, dtype=np.int64)
        self.events: list[dict] = []
        self._last_decide_t = -np.inf
        self.decision_period_s = switching.decision_period_s

    def _pd(self, x: np.ndarray, d: float) -> np.ndarray:
        return np.array(point_velocity_k(x[2], x[3], x[4], d))

    def step(self, t_s: float, state, parent: int | None = None, parent_state=None, parent_accel=None,
             offset=None, original_parent_state=None) -> LawOutput:
        """Torque at scenario time ``t_s`` for ``state`` (5,); parent data as (5,), (2,), (2,)."""
        x = np.zeros((3, 5))
        x[0] = state
        acmd = np.zeros((3, 2))
        parent_row = np.array([-1, -1, -1], dtype=np.int64)
        off = np.zeros((3, 2))
        if parent is not None and parent_state is not None:
            x[1] = parent_state
            acmd[1] = parent_accel if parent_accel is not None else 0.0
            parent_row[0] = 1
            off[0] = offset if offset is not None else self.graph.offset(self.rid, parent)
        if self.original_parent is not None:
            x[2] = original_parent_state if original_parent_state is not None else (
                x[1] if parent == self.original_parent else x[0] - np.r_[self.orig_offset, 0, 0, 0])
        pd = np.zeros((3, 2))
        for row in range(3):
            pd[row] = self._pd(x[row], float(self.coeffs[4, row]))
        ref = np.zeros((3, 6))
        if self.spec.leader and self.spec.path is not None:
            r, rd, rdd = self.spec.path.reference(t_s)
            ref[0] = np.r_[r, rd, rdd]
        orig_row = np.array([2 if self.original_parent is not None else -1, -1, -1], dtype=np.int64)
        orig_off = np.zeros((3, 2))
        orig_off[0] = self.orig_offset
        goal = np.zeros((3, 2))
        goal_dot = np.zeros((3, 2))
        vc = np.zeros((3, 2))
        goals_and_fields(x, pd, ref, orig_row, orig_off, self.gains, goal, goal_dot, vc)
        o = self.field.at(t_s)
        if t_s - self._last_decide_t >= self.decision_period_s - 1e-9:
            self._last_decide_t = t_s
            nev = decide(t_s, x[:1, :2].copy(), pd[:1].copy(), goal[:1].copy(), goal_dot[:1].copy(),
                         vc[:1].copy(), self.team, self.rbody[:1], o.center_m, o.velocity_mps, o.phi_rad,
                         o.phi_dot_radps, self.oaxes, self.ostatic, self.mode, self.tgt, self.sdir,
                         self.t_entry, self.since, self.last_kind, self.last_tgt, self.last_exit, self.wc,
                         self.wtgt, self.prm, self.ev, 0)
            for e in self.ev[:nev]:
                self.events.append({"t_s": float(e[0]), "event": "enter" if e[2] else "exit",
                                    "mode": MODE_NAMES[int(e[3])], "target": self._target(int(e[3]), int(e[4])),
                                    "direction": "ccw" if e[5] > 0 else "cw"})
        mode3 = np.r_[self.mode, 0, 0].astype(np.int64)
        tgt3 = np.r_[self.tgt, -1, -1].astype(np.int64)
        sdir3 = np.r_[self.sdir, 1.0, 1.0]
        tent3 = np.r_[self.t_entry, 0.0, 0.0]
        wc3 = np.vstack([self.wc, np.zeros((2, 2))])
        wt3 = np.vstack([self.wtgt, np.zeros((2, 2))])
        t1, t2, sx, sy, sat, acx, acy, _, _ = robot_law(
            0, t_s, x, pd, acmd, parent_row, off, ref, goal, goal_dot, mode3, tgt3, sdir3, tent3, wc3, wt3,
            o.center_m, o.velocity_mps, o.accel_mps2, o.phi_rad, o.phi_dot_radps, o.phi_ddot_radps2,
            self.oaxes, self.rbody, self.coeffs, self.gains, self.prm)
        md = int(self.mode[0])
        avoiding = md != MODE_C
        return LawOutput(np.array([t1, t2]), np.array([acx, acy]), MODE_NAMES[md],
                         self._target(md, int(self.tgt[0])) if avoiding else None,
                         ("ccw" if self.sdir[0] > 0 else "cw") if avoiding else None,
                         avoiding, bool(sat), np.array([sx, sy]), goal[0].copy())

    def _target(self, mode: int, target: int) -> str | None:
        if target < 0:
            return None
        if mode == MODE_OBSTACLE:
            return self.obstacle_names[target]
        return f"robot_{target}"
