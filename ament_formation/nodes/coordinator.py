"""formation_coordinator: owns the communication graph (spec S9), arbitrates robot-robot encounters
(spec S7) and starts the mission.

It watches every robot's ``state`` and ``mode``. When the set of robots in any avoidance mode
changes, it recomputes the parents with core/control/rewiring.py (S9 rewiring; restoration =
rewiring with
fewer avoiders) and publishes ``/formation/graph`` with a new revision (transient local, so late
controllers get the current graph). Once every robot's controller publishes its state (or at once
with ``wait_for_robots`` false) it fixes the mission start ``start_s = now + start_delay_s`` in
the same message: scenario time is ``now - start_s`` for every node. At ``encounter_rate_hz`` it
arbitrates robot-robot encounters over all robots together (core/control/arbiter.py: the
simulator's
``decide`` on every robot's broadcast state, the robots' reported obstacle modes taken as given)
and publishes the yield/mutual assignments on ``/formation/encounters`` (on change with a new
revision; when a mutual pair's drift w_c moved by more than 5 mm/s; and every ``republish_s``,
always the newest); each controller applies its own as an override of its local
decision. It also publishes markers for RViz/Foxglove.

Topics (QoS from ros/qos.py)
  sub  robot_<id>/state     nav_msgs/Odometry (taken serialized at 100 Hz; only the newest of each
                            robot is decoded, when the arbitration or the markers read it)
                            QOS_CONTROL
  sub  robot_<id>/mode      std_msgs/String JSON ament_formation/mode/v1 {schema, mode, target,
                            direction, avoiding}; invalid payloads are counted  QOS_CONTROL
  pub  /formation/graph     std_msgs/String JSON ament_formation/graph/v1 {schema, revision,
  parents,
                            offsets_m, avoiding, stamp_s, start_s}           QOS_GRAPH
  pub  /formation/encounters  std_msgs/String JSON ament_formation/encounters/v1 {schema, revision,
                            stamp_s, assignments: {"<id>": {mode: yield|mutual, partner, direction
                            (+1 CCW, -1 CW), t_entry_s (scenario time), drift_mps [wx, wy] or
                            null}}}  (docs/schemas/)                         QOS_GRAPH
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
  encounter_rate_hz float  S7 arbitration rate [Hz] (0: no arbitration)       default 50.0
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

from ament_formation.core.control.arbiter import AssignmentSender, EncounterArbiter
from ament_formation.core.control.rewiring import FormationGraph
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
        50.0, 'S7 arbitration rate [Hz] (0: no arbitration)', range=(0.0, 1000.0)
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
        if not (math.isfinite(self.encounter_rate_hz) and 0.0 <= self.encounter_rate_hz <= 1000.0):
            raise ConfigError(
                f'must be in [0, 1000] Hz (got {self.encounter_rate_hz!r})', 'encounter_rate_hz'
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
        self.graph = FormationGraph.from_scenario(self.scenario)
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
        self.arbiter = EncounterArbiter(self.scenario)
        self.sender = AssignmentSender()  # when the assignments are sent (new decision, w_c)
        self.encounter_revision = 0
        self._heard_mono: dict[
            int, float
        ] = {}  # when each robot's state last arrived [s, monotonic]
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
        self._publish_encounters(new_revision=True)
        self.arbitration_watch = self.markers_watch = None
        if self.prm.encounter_rate_hz > 0:
            self.arbitration_watch = self.diag.watch(
                'arbitration loop', 1.0 / self.prm.encounter_rate_hz
            )
            self.create_timer(1.0 / self.prm.encounter_rate_hz, self._arbitrate)
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
        avoiding = set(self.avoiding)
        (avoiding.add if is_avoiding(mode) else avoiding.discard)(rid)
        if avoiding != self.avoiding:
            self.avoiding = avoiding
            self.parents = self.graph.rewire(sorted(avoiding))  # S9 steps 1-6
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
        """Same revision again (a controller that missed it catches up)."""
        self.pub_graph.publish(msgs.graph_msg(self.current_graph()))
        self.sender.republish()
        self._publish_encounters(new_revision=False)

    def _arbitrate(self) -> None:
        """S7 over all robots (core/control/arbiter.py); publish the assignments on change."""
        now = self.now_s()
        self.arbitration_watch.tick(int(now * 1e9))
        if self.start_s is None or now < self.start_s:
            return
        what = self.sender.update(self.arbiter.decide(now - self.start_s, self.states, self.modes))
        if what is not None:  # a new decision (new revision), or a pair's w_c moved
            self._publish_encounters(new_revision=what == 'revision')

    def _publish_encounters(self, new_revision: bool) -> None:
        if new_revision:
            self.encounter_revision += 1
        self.pub_encounters.publish(
            msgs.encounters_msg(self.encounter_revision, self.sender.current, self.now_s())
        )

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
            'assignments': len(self.sender.current),
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
