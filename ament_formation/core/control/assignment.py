"""One robot's control period under the coordinator's encounter assignment (S7, S8.3), shared by
the controller node (nodes/controller.py) and the camera-sensing simulator (core/sim/sensed.py).

The coordinator publishes, per robot, at most one :class:`EncounterAssignment` (yield or mutual,
its partner and entry time). A robot applies it while the partner is heard; an assignment it has
left (by its own exit test, or on the coordinator's release) is never applied again, unless the
robot's own decision has put it back into that very encounter: then it gives the pair its sense
and w_c (docs/law-changes.md §25); when the coordinator withdraws or replaces the assignment in
force, the law gets ``release`` = the former partner (the coordinator's joint exit decision,
S8.3).
"""

from __future__ import annotations

import numpy as np

from ament_formation.core.control.controller import NeighbourState


def original_parent_link(fgraph, robot_id: int) -> tuple[int | None, np.ndarray]:
    """The robot's original parent pi0 in the scenario's graph (S9: where it returns after an
    avoidance) and its slot offset from pi0 (2,); (None, zeros) for a team leader.
    """
    parent = fgraph.original_parent.get(robot_id)
    if parent is None:
        return None, np.zeros(2)
    return parent, np.asarray(fgraph.offset(robot_id, parent), dtype=float)


def original_parent_state(
    heard: dict, orig_parent_id, orig_offset, state
) -> NeighbourState | None:
    """The original parent pi0's state for the formation goal (S8.3): as heard, or, while pi0 is
    silent, a state that puts the goal on the robot itself (no exit pull). None for a leader.
    """
    if orig_parent_id is None:
        return None
    known = heard.get(orig_parent_id)
    if known is not None:
        return known
    return NeighbourState(np.asarray(state, dtype=float) - np.r_[orig_offset, 0.0, 0.0, 0.0])


class AssignedLaw:
    """A :class:`~ament_formation.core.control.controller.RobotController` with the assignment
    bookkeeping around it. ``assignment`` is the coordinator's latest for this robot (or None).
    """

    def __init__(self, law):
        self.law = law
        self.assignment = None  # the coordinator's EncounterAssignment for this robot
        self._applied = None  # key (mode, partner, t_entry_s) of the assignment in force
        self._done: set = set()  # assignments this robot has already left

    def _in_force(self, mode: str, target) -> bool:
        return (mode, target) == (self._applied[0], f'robot_{self._applied[1]}')

    def _is_in(self, assignment) -> bool:
        """The robot is in ``assignment``'s encounter now by its own decision (re-entered after
        leaving it): the assignment, not re-entered, still gives the pair's one sense and w_c
        (docs/law-changes.md §25).
        """
        return (self.law.mode, self.law.target) == (
            assignment.mode,
            f'robot_{assignment.partner}',
        )

    def step(
        self, t_s: float, state, parent_id, original_parent, heard: dict, coordinated=False
    ):
        """One control period (RobotController.step) on the own ``state`` (5,), the parent's id
        (or None), pi0's state (:func:`original_parent_state`) and the heard neighbours
        {id: NeighbourState}; ``coordinated``: the coordinator is heard (its assignments are the
        robot's encounters but emergencies, docs/law-changes.md §23). Returns the ControlOutput.
        """
        assignment, key = self.assignment, None
        if assignment is not None:
            key = (assignment.mode, assignment.partner, assignment.t_entry_s)
            if assignment.partner not in heard or (
                key in self._done and not self._is_in(assignment)
            ):
                assignment = None
        withdrawn = self._applied is not None and key != self._applied
        # a new assignment with the same partner replaces the old one: no release (the robot's
        # own decision may already have turned the yield into the pair the coordinator now
        # assigns; a release would end it and the assignment would be lost, §23)
        release = None
        if withdrawn and (assignment is None or assignment.partner != self._applied[1]):
            release = self._applied[1]
        out = self.law.step(
            t_s,
            state,
            parent=None if parent_id is None else heard[parent_id],
            original_parent=original_parent,
            neighbours=heard,
            assignment=assignment,
            release=release,
            coordinated=coordinated,
        )
        if withdrawn and not self._in_force(out.mode, out.target):
            self._done.add(self._applied)  # left on the coordinator's release
            self._applied = None
        if assignment is not None:
            self._applied = key
        if self._applied is not None and not self._in_force(out.mode, out.target):
            self._done.add(self._applied)  # left (or replaced) with its own exit test
            self._applied = None
        return out
