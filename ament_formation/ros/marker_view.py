"""What a viewer (RViz, Foxglove) holds after a sequence of visualization_msgs/MarkerArray, and the
marker census of a recording: counts per action and how many objects were ever shown at once.

    viewer = MarkerViewer()
    viewer.apply(array, now_s)        # ADD/MODIFY replaces (ns, id), DELETE removes it,
    viewer.shown(now_s)               # DELETEALL removes everything; lifetimes expire
    census('run/run.mcap')            # {'arrays', 'actions', 'max_shown', 'final_shown', ...}
"""

from __future__ import annotations

import math
from pathlib import Path

MARKERS_TOPIC = '/formation/markers'


class MarkerViewer:
    """The markers a viewer shows: ADD (and MODIFY) replaces (ns, id), DELETE removes it,
    DELETEALL removes everything; a marker with a lifetime expires that long after it was
    received (``now_s``: receive time [s]), one without stays until replaced or deleted.
    """

    def __init__(self):
        self.live: dict[tuple[str, int], float] = {}  # (ns, id) -> expiry [s] (inf: none)
        self.actions = {'add': 0, 'delete': 0, 'deleteall': 0}
        self.max_adds_per_array = 0

    def apply(self, arr, now_s: float) -> None:
        from visualization_msgs.msg import Marker

        adds = 0
        for mk in arr.markers:
            if mk.action == Marker.DELETEALL:
                self.live.clear()
                self.actions['deleteall'] += 1
            elif mk.action == Marker.DELETE:
                self.live.pop((mk.ns, mk.id), None)
                self.actions['delete'] += 1
            else:
                life = mk.lifetime.sec + mk.lifetime.nanosec * 1e-9
                self.live[(mk.ns, mk.id)] = now_s + life if life > 0 else math.inf
                self.actions['add'] += 1
                adds += 1
        self.max_adds_per_array = max(self.max_adds_per_array, adds)

    def shown(self, now_s: float) -> set:
        return {k for k, expiry in self.live.items() if expiry >= now_s}


def census(mcap_path: str | Path, topic: str = MARKERS_TOPIC) -> dict:
    """Replay ``topic`` of a recording into a :class:`MarkerViewer` at the recorded receive times:
    arrays, markers per action, the most objects shown at once (``max_shown``), the objects shown
    after the last array (``final_shown``) and the namespaces seen with their largest id count.
    """
    from ament_formation.ros.recorder import read_topic

    viewer = MarkerViewer()
    max_shown, arrays, last_s = 0, 0, -math.inf
    namespaces: dict[str, set] = {}
    for t_ns, arr in read_topic(mcap_path, topic):
        last_s = t_ns * 1e-9
        viewer.apply(arr, last_s)
        arrays += 1
        for mk in arr.markers:
            if mk.ns:
                namespaces.setdefault(mk.ns, set()).add(mk.id)
        max_shown = max(max_shown, len(viewer.shown(last_s)))
    return {
        'arrays': arrays,
        'actions': dict(viewer.actions),
        'max_adds_per_array': viewer.max_adds_per_array,
        'max_shown': max_shown,
        'final_shown': len(viewer.shown(last_s)) if arrays else 0,
        'namespaces': {ns: len(ids) for ns, ids in sorted(namespaces.items())},
    }
