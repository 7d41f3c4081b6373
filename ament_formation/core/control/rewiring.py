"""Communication graph and leader/follower rewiring (spec S1, S9).

Edges (u, v) mean "v receives u's state": u is a possible parent of v. The original parent pi0 is
the BFS spanning tree of G from the team leaders (neighbours in ascending id order). While some
robots avoid, :meth:`FormationGraph.rewire` rebuilds a forest rooted at the leaders and the
avoiders
(S9 steps 1-6); rewiring with fewer avoiders restores the original tree (step 6).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np

from ament_formation.core.errors import ConfigError


@dataclass(frozen=True)
class FormationGraph:
    """G = (V, E) with team leaders and formation slots.

    Parameters
    ----------
    robot_ids : the vertices V
    edges : (parent, child) pairs E (no self-loops)
    leaders : team leaders (roots of pi0)
    slots : {id: (2,) slot c_i [m]} relative to the team leader, world frame (S1)
    """

    robot_ids: tuple[int, ...]
    edges: tuple[tuple[int, int], ...]
    leaders: tuple[int, ...]
    slots: Mapping[int, tuple[float, float]] = field(default_factory=dict)
    original_parent: dict = field(init=False, compare=False, repr=False)
    team_leader: dict = field(init=False, compare=False, repr=False)
    _in: dict = field(init=False, compare=False, repr=False)
    _out: dict = field(init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        ids = tuple(int(i) for i in self.robot_ids)
        object.__setattr__(self, 'robot_ids', ids)
        object.__setattr__(self, 'edges', tuple((int(u), int(v)) for u, v in self.edges))
        object.__setattr__(self, 'leaders', tuple(sorted(int(i) for i in self.leaders)))
        known = set(ids)
        if len(known) != len(ids):
            raise ConfigError('robot ids must be unique', 'robot_ids')
        for u, v in self.edges:
            if u not in known or v not in known:
                raise ConfigError(f'edge ({u}, {v}) names an unknown robot', 'edges')
            if u == v:
                raise ConfigError(f'self-loop ({u}, {v}) is not allowed (S1)', 'edges')
        for lead in self.leaders:
            if lead not in known:
                raise ConfigError(f'leader {lead} is not a robot', 'leaders')
        in_nb = {i: [] for i in ids}
        out_nb = {i: [] for i in ids}
        for u, v in sorted(set(self.edges)):
            in_nb[v].append(u)
            out_nb[u].append(v)
        object.__setattr__(self, '_in', in_nb)
        object.__setattr__(self, '_out', out_nb)
        parent, team = self._bfs_tree()
        missing = [v for v in ids if v not in parent]
        if missing:
            raise ConfigError(f'robots {missing} cannot be reached from any leader', 'edges')
        object.__setattr__(self, 'original_parent', parent)
        object.__setattr__(self, 'team_leader', team)

    @classmethod
    def from_scenario(cls, scenario) -> 'FormationGraph':
        """The graph of a :class:`ament_formation.core.scenario.loader.Scenario`."""
        return cls(
            robot_ids=scenario.robot_ids,
            edges=scenario.edges,
            leaders=scenario.leaders,
            slots={r.id: tuple(r.slot_m) for r in scenario.robots},
        )

    def _bfs_tree(self):
        """pi0: BFS from each leader in ascending id; neighbours in ascending id (S9 inputs)."""
        parent: dict[int, int | None] = dict.fromkeys(self.leaders)  # leaders stay roots
        team: dict[int, int] = {lead: lead for lead in self.leaders}
        for lead in self.leaders:
            queue = deque([lead])
            while queue:
                u = queue.popleft()
                for v in self._out[u]:
                    if v not in parent:
                        parent[v] = u
                        team[v] = lead
                        queue.append(v)
        return parent, team

    # --------------------------------------------------------------------------------------------
    # implements: S9
    def rewire(self, avoiding: Iterable[int] = ()) -> dict[int, int | None]:
        """S9 steps 1-6: the current parent of every robot while ``avoiding`` robots avoid.

        Roots R = leaders + avoiders (parent None). Incoming edges of roots are removed; each root
        in turn (leaders first, then avoiders by id) grows a tree over still unattached robots in
        synchronous rounds: v attaches to pi0(v) when pi0(v) is in this root's tree and (pi0(v), v)
        survives, else to its attached in-neighbour of minimal (depth, id). Returns {child:
        parent}.
        With no avoiders the result is pi0 (restoration, step 6).
        """
        avoid = {int(a) for a in avoiding}
        unknown = avoid - set(self.robot_ids)
        if unknown:
            raise ValueError(f'avoiding robots {sorted(unknown)} are not in the graph')
        roots = list(self.leaders) + sorted(avoid - set(self.leaders))
        root_set = set(roots)
        parent: dict[int, int | None] = dict.fromkeys(roots)
        attached: set[int] = set(roots)
        for root in roots:
            depth = {root: 0}
            while True:
                new: dict[int, int] = {}
                for v in self.robot_ids:
                    if v in attached or v in root_set:
                        continue
                    cands = [
                        u for u in self._in[v] if u in depth
                    ]  # edges into v survive: v not a root
                    if not cands:
                        continue
                    pi0 = self.original_parent.get(v)
                    new[v] = pi0 if pi0 in depth else min(cands, key=lambda u: (depth[u], u))
                if not new:
                    break
                for v, u in new.items():
                    parent[v] = u
                    depth[v] = depth[u] + 1
                    attached.add(v)
        return {v: parent.get(v) for v in self.robot_ids}

    # --------------------------------------------------------------------------------------------
    def offset(self, child: int, parent: int) -> np.ndarray:
        """delta_{child,parent} = c_child - c_parent (2,) [m] (S1, S9 step 4)."""
        return np.asarray(self.slots[child], dtype=float) - np.asarray(
            self.slots[parent], dtype=float
        )

    def offsets(self, parents: Mapping[int, int | None]) -> dict[int, np.ndarray]:
        """{child: delta (2,)} for every robot that has a parent."""
        return {c: self.offset(c, p) for c, p in parents.items() if p is not None}

    @staticmethod
    def children(parents: Mapping[int, int | None]) -> dict[int, list[int]]:
        """{parent: sorted children} of a parent map."""
        out: dict[int, list[int]] = {}
        for c, p in parents.items():
            if p is not None:
                out.setdefault(p, []).append(c)
        return {p: sorted(cs) for p, cs in out.items()}

    @staticmethod
    def root_of(parents: Mapping[int, int | None], robot: int) -> int:
        """The root reached by following parents from ``robot`` (raises on a cycle)."""
        seen = set()
        v = robot
        while parents[v] is not None:
            if v in seen:
                raise ValueError(f'parent map has a cycle through {v}')
            seen.add(v)
            v = parents[v]
        return v

    @classmethod
    def partition(cls, parents: Mapping[int, int | None]) -> dict[int, set[int]]:
        """{root: vertices of its tree} (S9 step 3: V_L and the V_i)."""
        out: dict[int, set[int]] = {}
        for v in parents:
            out.setdefault(cls.root_of(parents, v), set()).add(v)
        return out

    def tree_edges(self, parents: Mapping[int, int | None]) -> set[tuple[int, int]]:
        """Edges (parent, child) of the grown forest (G~*)."""
        return {(p, c) for c, p in parents.items() if p is not None}
