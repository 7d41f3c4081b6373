"""formation_coordinator: the graph (spec S9), the one authority for robot-robot encounters
(docs/control-law.md S7.1), the teams' right of way (S7.5) and the progress of their references
(S17); it starts the mission.

It watches every robot's ``state`` and ``mode``. When the set of robots in any avoidance mode
changes, it rewires the graph (core/control/rewiring.py; restoration = rewiring with fewer
avoiders) and publishes ``/formation/graph`` with a new revision (transient local, so late
controllers get the current graph). Once every robot's controller publishes its state (or at once
with ``wait_for_robots`` false) it fixes the mission start ``start_s = now + start_delay_s`` in
the same message: scenario time is ``now - start_s`` for every node. At ``encounter_rate_hz`` it
decides (core/control/coordinator.py: the compiled decision the ideal simulator runs, on every
robot's broadcast state, the robots' own obstacle modes taken as given) and publishes its
decisions on ``/formation/encounters`` (encounters/v2: the assignments and every team's progress
rate) on change and every ``republish_s``; a robot that hears nothing from it for its
``coordinator_timeout_s`` stops. It also publishes markers for RViz/Foxglove.

Topics (QoS from ros/qos.py)
  sub  robot_<id>/state     nav_msgs/Odometry (taken serialized at 100 Hz; only the newest of each
                            robot is decoded, when the arbitration or the markers read it)
                            QOS_CONTROL
  sub  robot_<id>/mode      std_msgs/String JSON ament_formation/mode/v1 {schema, mode, target,
                            direction, avoiding}; invalid payloads are counted  QOS_CONTROL
  pub  /formation/graph     std_msgs/String JSON ament_formation/graph/v1 {schema, revision,
  parents,
                            offsets_m, avoiding, stamp_s, start_s}           QOS_GRAPH
  pub  /formation/encounters  std_msgs/String JSON ament_formation/encounters/v2 {schema, revision,
                            stamp_s, assignments: {"<id>": {mode: yield|mutual|make_way, partner,
                            direction, t_entry_s, drift_mps, park_at_s}}, rates: {"<leader>":
                            rate}}  (docs/schemas/)                          QOS_GRAPH
  pub  /formation/markers   visualization_msgs/MarkerArray at markers_rate_hz: P/L/Q ellipses (ns
                            ellipse_P|L|Q, id = obstacle index), robots (ns robots, headings; id =
                            robot id) and graph edges (ns graph_edges, ARROW parent -> child, id =
                            child id); robots heard in the last ROBOT_SILENT_S only; a DELETEALL
                            first whenever the set of objects changes; robots and edges carry a
                            lifetime (3 periods, >= 1 s) so they vanish if the coordinator stops
                            QOS_MARKERS
  pub  /diagnostics         "formation_coordinator: graph" (mission, revision), "...: robots"
                            (silent robots WARN), "...: inputs" (rejected payloads WARN), "...:
                            arbitration loop", "...: markers loop" (stalls)   QOS_DIAGNOSTICS

Parameters
  scenario          str    scenario YAML (required)
  start_delay_s     float  mission start after every controller is up [s]     default 1.0
  wait_for_robots   bool   wait for every robot's state before starting       default true
  markers_rate_hz   float  marker publication rate [Hz] (0: none)             default 5.0
  republish_s       float  graph re-publication period [s]                    default 1.0
  encounter_rate_hz float  decision rate (S7.1, S17) [Hz], >= 1              default 50.0
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import sys
import time

import numpy as np
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from ament_formation.core.control.coordinator import Coordinator, Publisher
from ament_formation.core.errors import ConfigError
from ament_formation.core.model.obstacles import ObstacleField
from ament_formation.core.params import param
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.ros import diagnostics as diag
from ament_formation.ros import messages as msgs
from ament_formation.ros.executors import run_node
from ament_formation.ros.params import declare_dataclass
from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH, QOS_MARKERS


@dataclass(frozen=True)
class CoordinatorParams:
    scenario: str = param('', 'scenario YAML path (required)')
    start_delay_s: float = param(
        1.0, 'mission start after every controller is up [s]', range=(0.0, 60.0)
    )
    wait_for_robots: bool = param(True, "wait for every robot's state before starting")
    markers_rate_hz: float = param(
        5.0, '/formation/markers rate [Hz] (0: none)', range=(0.0, 100.0)
    )
    republish_s: float = param(1.0, '/formation/graph re-publication period [s], > 0')
    encounter_rate_hz: float = param(
        50.0, 'decision rate: encounters, right of way, progress (S7.1, S17) [Hz]',
        range=(1.0, 1000.0)
    )

    def __post_init__(self) -> None:
        if not self.scenario:
            raise ConfigError('is required (path of a scenario YAML)', 'scenario')
        if not (math.isfinite(self.start_delay_s) and 0.0 <= self.start_delay_s <= 60.0):
            raise ConfigError(
                f'must be in [0, 60] s (got {self.start_delay_s!r})', 'start_delay_s'
            )
        if not (math.isfinite(self.markers_rate_hz) and 0.0 <= self.markers_rate_hz <= 100.0):
            raise ConfigError(
                f'must be in [0, 100] Hz (got {self.markers_rate_hz!r})', 'markers_rate_hz'
            )
        if not (math.isfinite(self.republish_s) and self.republish_s > 0):
            raise ConfigError(f'must be > 0 s (got {self.republish_s!r})', 'republish_s')
        if not (math.isfinite(self.encounter_rate_hz) and 1.0 <= self.encounter_rate_hz <= 1000.0):
            raise ConfigError(
                f'must be in [1, 1000] Hz (got {self.encounter_rate_hz!r})', 'encounter_rate_hz'
            )


def is_avoiding(mode: dict) -> bool:
    """True when a robot's mode message says it is in any avoidance mode (S8)."""
    if 'avoiding' in mode:
        return bool(mode['avoiding'])
    return mode.get('mode') not in ('coordination', 'hold', 'stopped', 'idle', None)


ROBOT_SILENT_S = 1.0  # a robot whose state is older is not drawn and is reported silent [s]


class CoordinatorNode(Node):
    """See the module docstring."""

    def __init__(self, *, context=None, params: CoordinatorParams | None = None, **node_kw):
        super().__init__('formation_coordinator', context=context, **node_kw)
        self.prm = params if params is not None else declare_dataclass(self, CoordinatorParams)
        self.scenario = load_scenario(self.prm.scenario)
        self.core = Coordinator(self.scenario)  # graph, encounters, right of way, progress
        self.graph = self.core.graph
        self.ids = self.scenario.robot_ids
        self.obstacles = ObstacleField(self.scenario.obstacles)
        self._raw_states: dict[int, bytes] = {}  # newest serialized state of each robot
        self._states: dict[int, np.ndarray] = {}  # decoded (finite) states
        self.avoiding: set[int] = set()
        self.modes: dict[int, dict] = {}
        self.revision = 0
        self.parents = self.graph.rewire(())
        self.start_s: float | None = None
        self.history: list[msgs.GraphMessage] = []
        self.publisher = Publisher(self.prm.republish_s)  # when its decisions are sent
        self.decision: tuple[dict, dict] = ({}, {})  # the newest (assignments, rates)
        self.encounter_revision = 0
        self._end_sent = False  # the mission's end was published
        self._heard_mono: dict[int, float] = {}  # when each state last arrived [s, monotonic]
        self._heard_at: dict[int, float] = {}  # ... [s, ROS time]
        self.rejections = diag.Rejections(('mode', 'state'), lambda: self.now_s())
        self.rejected = self.rejections.counts  # kind -> count, reported as 'inputs'
        self._marker_keys: frozenset | None = None  # (ns, id) drawn by the last marker array
        self.diag = diag.Diagnostics(self)
        self.diag.add('graph', self._graph_status)
        self.diag.add('robots', self._robots_status)
        self.diag.add('inputs', self.rejections.status)

        self.pub_graph = self.create_publisher(String, '/formation/graph', QOS_GRAPH)
        self.pub_markers = self.create_publisher(MarkerArray, '/formation/markers', QOS_MARKERS)
        self.pub_encounters = self.create_publisher(String, '/formation/encounters', QOS_GRAPH)
        for rid in self.ids:
            self.create_subscription(
                msgs.Odometry,
                f'/robot_{rid}/state',
                lambda m, rid=rid: self._on_state(rid, m),
                QOS_CONTROL,
                raw=True,
            )
            self.create_subscription(
                String, f'/robot_{rid}/mode', lambda m, rid=rid: self._on_mode(rid, m), QOS_CONTROL
            )
        if not self.prm.wait_for_robots:
            self.start_s = self.now_s() + self.prm.start_delay_s
        self._publish_graph()
        self.create_timer(self.prm.republish_s, self._republish)
        self._publish_encounters()
        self.arbitration_watch = self.diag.watch(
            'arbitration loop', 1.0 / self.prm.encounter_rate_hz)
        self.create_timer(1.0 / self.prm.encounter_rate_hz, self._arbitrate)
        self.markers_watch = None
        if self.prm.markers_rate_hz > 0:
            self.markers_watch = self.diag.watch('markers loop', 1.0 / self.prm.markers_rate_hz)
            self.create_timer(1.0 / self.prm.markers_rate_hz, self._publish_markers)

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    # ------------------------------------------------------------------ callbacks
    @property
    def states(self) -> dict[int, np.ndarray]:
        """Every heard robot's newest finite state (5,) (decoded here, on demand)."""
        for rid, raw in self._raw_states.items():
            state, _ = msgs.state_from_odometry(deserialize_message(raw, msgs.Odometry))
            if np.all(np.isfinite(state)):
                self._states[rid] = state
            else:
                self.rejected['state'] += 1
        self._raw_states.clear()
        return self._states

    def _on_state(self, rid: int, raw: bytes) -> None:
        self._raw_states[rid] = raw
        self._heard_mono[rid] = time.monotonic()  # receive time: no clock skew between hosts
        self._heard_at[rid] = self.now_s()
        if self.start_s is None and len(self.states) == len(self.ids):
            self.start_s = self.now_s() + self.prm.start_delay_s
            self.get_logger().info(
                f'every controller is up: mission starts at {self.start_s:.3f} s'
            )
            self._publish_graph()

    def _on_mode(self, rid: int, msg: String) -> None:
        try:
            mode = msgs.mode_from_msg(msg)
        except ValueError as err:
            self.rejected['mode'] += 1
            self.diag.changed()
            self.get_logger().warn(f'robot_{rid}/mode: {err}', throttle_duration_sec=5.0)
            return
        self.modes[rid] = mode
        self.core.report(rid, {**mode, 'avoiding': is_avoiding(mode)})
        parents = self.core.reported_avoiding()
        if parents is not None:  # S9 steps 1-6
            self.avoiding, self.parents = set(self.core.avoiding), parents
            self._publish_graph()

    # ------------------------------------------------------------------ output
    def current_graph(self) -> msgs.GraphMessage:
        offsets = {
            c: tuple(float(x) for x in d) for c, d in self.graph.offsets(self.parents).items()
        }
        return msgs.GraphMessage(
            self.revision,
            dict(self.parents),
            offsets,
            tuple(sorted(self.avoiding)),
            self.now_s(),
            self.start_s,
        )

    def _publish_graph(self) -> None:
        self.revision += 1
        graph = self.current_graph()
        self.history.append(graph)
        self.pub_graph.publish(msgs.graph_msg(graph))
        self.diag.changed()  # a new graph (start, rewiring) is published when it happens

    def _republish(self) -> None:
        """Same graph revision again (a controller that missed it catches up)."""
        self.pub_graph.publish(msgs.graph_msg(self.current_graph()))

    def _arbitrate(self) -> None:
        """The coordinator's decision (core/control/coordinator.py) at its rate; published on
        change and every republish_s (before the start: the empty decision, so the robots hear
        the coordinator).
        """
        now = self.now_s()
        self.arbitration_watch.tick(int(now * 1e9))
        if self.start_s is not None and now >= self.start_s:
            t = now - self.start_s
            for rid, state in self.states.items():  # stamped on arrival: no clock skew
                self.core.state(rid, state, self._heard_at.get(rid, -math.inf) - self.start_s)
            self.decision = self.core.decide(t)
        ended = self.core.mission_end_s is not None and not self._end_sent
        if self.publisher.due(now, *self.decision) or ended:
            self._end_sent = self.core.mission_end_s is not None
            self._publish_encounters()

    def _publish_encounters(self) -> None:
        self.encounter_revision += 1
        self.pub_encounters.publish(msgs.encounters_msg(msgs.EncountersMessage(
            self.encounter_revision, *self.decision, self.now_s(), self.core.mission_end_s)))

    def live_robots(self) -> list[int]:
        """Robots with a valid state received in the last ROBOT_SILENT_S [s, wall time]."""
        now = time.monotonic()
        return sorted(
            i for i in self.states if now - self._heard_mono.get(i, -math.inf) <= ROBOT_SILENT_S
        )

    def marker_array(self, now_s: float) -> MarkerArray:
        """The /formation/markers array at ``now_s`` [s, ROS time] (see the module docstring)."""
        stamp = msgs.stamp_from_s(now_s)
        t = 0.0 if self.start_s is None else max(0.0, now_s - self.start_s)
        lifetime_s = (
            max(3.0 / self.prm.markers_rate_hz, 1.0) if self.prm.markers_rate_hz > 0 else 0.0
        )
        groups = []
        if len(self.obstacles):
            obs = self.obstacles.at(t)
            av = self.scenario.avoidance
            groups.append(
                msgs.ellipse_markers(
                    self.obstacles.names,
                    obs.center_m,
                    obs.phi_rad,
                    obs.semi_axes_m,
                    {'P': 1.0, 'L': av.limit_cycle_scale, 'Q': av.protected_scale},
                    stamp,
                )
            )
        ids = self.live_robots()
        if ids:
            states = self.states
            radius = [self.scenario.robot(i).params.body_radius_m for i in ids]
            groups.append(
                msgs.robot_markers(
                    ids,
                    np.stack([states[i] for i in ids]),
                    radius,
                    stamp,
                    avoiding=[i in self.avoiding for i in ids],
                    lifetime_s=lifetime_s,
                )
            )
            groups.append(
                msgs.edge_markers(
                    self.parents, {i: states[i][:2] for i in ids}, stamp, lifetime_s=lifetime_s
                )
            )
        arr = msgs.marker_array(*groups)
        keys = frozenset((mk.ns, mk.id) for mk in arr.markers)
        if keys != self._marker_keys:  # a new layout: drop whatever the viewer still shows
            arr.markers.insert(0, msgs.delete_all_marker(stamp))
            self._marker_keys = keys
        return arr

    def _publish_markers(self) -> None:
        now = self.now_s()
        self.markers_watch.tick(int(now * 1e9))
        self.pub_markers.publish(self.marker_array(now))

    # ------------------------------------------------------------------ diagnostics
    def _graph_status(self) -> tuple[int, str, dict]:
        values = {
            'revision': self.revision,
            'avoiding': sorted(self.avoiding),
            'parents': dict(sorted(self.parents.items())),
            'encounter_revision': self.encounter_revision,
            'assignments': len(self.decision[0]),
            'mission_end_s': 'none' if self.core.mission_end_s is None else
            self.core.mission_end_s,
            'start_s': 'none' if self.start_s is None else self.start_s,
        }
        if self.start_s is None:
            return (
                diag.OK,
                f'waiting for robots ({len(self._states)}/{len(self.ids)} heard)',
                values,
            )
        return (
            diag.OK,
            f'mission started; revision {self.revision}, {len(self.avoiding)} avoiding',
            values,
        )

    def _robots_status(self) -> tuple[int, str, dict]:
        now = time.monotonic()
        states = self.states
        values = {
            f'robot_{i}_age_s': (now - self._heard_mono[i] if i in states else 'never')
            for i in self.ids
        }
        silent = [
            i for i in self.ids if i in states and now - self._heard_mono[i] > ROBOT_SILENT_S
        ]
        if self.start_s is not None and silent:
            return diag.WARN, 'silent: ' + ', '.join(f'robot_{i}' for i in silent), values
        return diag.OK, f'{len(states) - len(silent)}/{len(self.ids)} robots heard', values


def main(args: list[str] | None = None) -> int:
    return run_node('formation_coordinator', CoordinatorNode, args)


if __name__ == '__main__':
    sys.exit(main())
