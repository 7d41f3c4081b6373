"""Small geometric cases for the switching tables (test/test_switching.py,
test/test_arbitration.py): obstacles, robots and modes built from a few numbers, and one
decision of a robot's table or of the coordinator's with its events as tuples.
"""

from __future__ import annotations

import numpy as np

from ament_formation.core.control.arbitration import arbitrate, new_teams
from ament_formation.core.control.law_params import LawParams
from ament_formation.core.control.switching import (
    MODE_NAMES,
    new_modes,
    robot_transitions,
    Robots,
)
from ament_formation.core.model.obstacles import ObstacleSnapshot

PRM = LawParams().compiled()
R_BODY = 0.1


def obstacles(*specs) -> ObstacleSnapshot:
    """An ObstacleSnapshot of dicts {center, axes, phi, phi_dot, vel} (defaults: at the origin,
    (0.4, 0.15), not turning, at rest).
    """
    m = len(specs)
    c = np.array([s.get('center', (0.0, 0.0)) for s in specs], float).reshape(m, 2)
    v = np.array([s.get('vel', (0.0, 0.0)) for s in specs], float).reshape(m, 2)
    axes = np.array([s.get('axes', (0.4, 0.15)) for s in specs], float).reshape(m, 2)
    phi = np.array([s.get('phi', 0.0) for s in specs], float)
    phid = np.array([s.get('phi_dot', 0.0) for s in specs], float)
    static = np.array([s.get('phi_dot', 0.0) == 0.0 and not np.any(s.get('vel', (0.0, 0.0)))
                       for s in specs], dtype=np.bool_)
    return ObstacleSnapshot(c, v, np.zeros((m, 2)), phi, phid, np.zeros(m), axes, static)


NO_OBSTACLES = obstacles()


def robots(p, pd=None, goal=None, goal_dot=None, vc=None, team=None, parent=None, slot=None,
           known=None, rbody=R_BODY, origin=None) -> Robots:
    """:data:`Robots` of points p (N, 2); by default: at rest, goals 3 s ahead of their
    velocity (moving with it), V_c = p_dot, each robot its own team, no parents, slots unknown,
    every robot known, original parents as the current ones.
    """
    p = np.array(p, float).reshape(-1, 2)
    n = len(p)
    pd = np.zeros((n, 2)) if pd is None else np.array(pd, float).reshape(n, 2)
    goal = p + 3.0 * pd if goal is None else np.array(goal, float).reshape(n, 2)
    goal_dot = pd.copy() if goal_dot is None else np.array(goal_dot, float).reshape(n, 2)
    vc = pd.copy() if vc is None else np.array(vc, float).reshape(n, 2)
    team = np.arange(n) if team is None else np.array(team)
    parent = np.full(n, -1) if parent is None else np.array(parent)
    slot = np.full((n, 2), np.nan) if slot is None else np.array(slot, float).reshape(n, 2)
    known = np.ones(n, bool) if known is None else np.array(known, bool)
    origin = parent if origin is None else np.array(origin)
    return Robots(p, pd, goal, goal_dot, vc, team.astype(np.int64), np.full(n, float(rbody)),
                  parent.astype(np.int64), slot, known, origin.astype(np.int64))


def modes(n: int):
    return new_modes(n)


def set_mode(m, i, mode, target, sense=1.0, t_entry=0.0):
    """Put robot row i of :data:`Modes` ``m`` into ``mode`` as if it had entered at t_entry."""
    m.mode[i], m.tgt[i], m.sdir[i], m.t_entry[i] = mode, target, sense, t_entry
    m.since[i] = -1.0
    m.park_at[i] = -np.inf


def held_since(m, i, p, t_s):
    """Robot row i's progress monitor anchored at p since ``t_s`` (it has not moved)."""
    m.anchor[i] = p
    m.t_anchor[i] = t_s


def events(ev, nev):
    """Event rows as tuples (t_s, row, 'enter'|'exit', mode name, target row, sense)."""
    return [(float(r[0]), int(r[1]), 'enter' if r[2] > 0.5 else 'exit', MODE_NAMES[int(r[3])],
             int(r[4]), float(r[5])) for r in ev[:nev]]


def robot_decision(t, m, rb, ob=NO_OBSTACLES, i=0, prm=PRM):
    """One decision of robot i's own table -> its events."""
    ev = np.zeros((32, 6))
    return events(ev, robot_transitions(i, t, rb, ob, m, prm, ev, 0))


def coordinator_decision(t, m, rb, teams=None, prm=PRM):
    """One decision of the coordinator's table -> its events (``teams`` updated)."""
    teams = new_teams(len(rb.p)) if teams is None else teams
    ev = np.zeros((16 * len(rb.p) + 16, 6))
    return events(ev, arbitrate(t, rb, m, teams, prm, ev, 0))
