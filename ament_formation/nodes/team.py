"""formation_team: several robots' bridge and controller nodes composed in one process.

What an rclcpp component container gives, for Python nodes: every hosted robot keeps its own
``formation_controller`` and ``formation_bridge`` node (namespace ``robot_<id>``, the same topics,
parameters, QoS and safety as when they run as separate processes), but they share one process
and one executor, and

* one timer runs every hosted controller's control period back to back (one wake-up of the
  process per period instead of one per robot), and one timer polls every hosted bridge;
* the hosted controllers read each other's latest state, accel and mode in process
  (nodes/controller.py PeerTable) instead of through N^2 DDS subscriptions, and each controller
  hands its torques to its robot's bridge and takes the wheel samples from it directly. State,
  accel and mode are still published on DDS for the coordinator, the recorder, the tools and the
  robots in other processes; wheel_torque and wheel_state are published while anyone subscribes
  (a hosted bridge takes its commands only from its hosted controller).

For simulated runs of many robots on one machine (``scripts/launch_sim.sh --team K``: K robots per
process). On real robots each board runs its own bridge and controller (scripts/launch_robot.sh).

Parameters (this node; ``--ros-args -p NAME:=VALUE`` given to the process also reaches every
hosted node, as in any ROS 2 process, e.g. ``control_rate_hz``, ``pose_timeout_s``,
``poll_rate_hz``, ``use_sim_time``)
  scenario        str    scenario YAML (required)
  robot_ids       int[]  robots hosted here                         default [] = every robot
  port_template   str    serial port of robot {id}, e.g. /dev/ttyACM{id} or PTY_DIR/robot_{id};
                         empty: no bridges (controllers only)        default ""
Torque limits of the bridges come from the scenario.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Sequence

from rclpy.node import Node
from rclpy.parameter import Parameter

from ament_formation.core.errors import ConfigError
from ament_formation.core.params import param
from ament_formation.core.scenario import load_scenario
from ament_formation.nodes.bridge import BridgeNode
from ament_formation.nodes.controller import ControllerNode, PeerTable
from ament_formation.nodes.controller import _send_zero_torque as _controller_zero_torque
from ament_formation.ros.executors import run_node
from ament_formation.ros.params import declare_dataclass


@dataclass(frozen=True)
class TeamParams:
    scenario: str = param("", "scenario YAML path (required)")
    robot_ids: tuple[int, ...] = param((), "robots hosted here (empty: every robot)")
    port_template: str = param("", "serial port of robot {id}, e.g. /dev/ttyACM{id} "
                               "('': no bridges, controllers only)")

    def __post_init__(self) -> None:
        if not self.scenario:
            raise ConfigError("is required (path of a scenario YAML)", "scenario")
        ids = self.robot_ids
        if len(set(ids)) != len(ids) or any(not isinstance(i, int) or i < 0 for i in ids):
            raise ConfigError(f"must be distinct integers >= 0 (got {list(ids)})", "robot_ids")
        if self.port_template and "{id}" not in self.port_template:
            raise ConfigError(f"must contain {{id}} (got {self.port_template!r})", "port_template")


class TeamNode(Node):
    """See the module docstring. ``composed_nodes``: the hosted nodes (spun with this one)."""

    def __init__(self, *, context=None, params: TeamParams | None = None,
                 hosted_parameters: Sequence[Parameter] = (), **node_kw):
        """``hosted_parameters``: parameter overrides for every hosted node (what ``-p NAME:=VALUE``
        on the process command line does), e.g. ``poll_rate_hz`` or ``pose_timeout_s``."""
        super().__init__("formation_team", context=context, **node_kw)
        self.prm = params if params is not None else declare_dataclass(self, TeamParams)
        scenario = load_scenario(self.prm.scenario)
        ids = list(self.prm.robot_ids) or list(scenario.robot_ids)
        unknown = [i for i in ids if i not in scenario.robot_ids]
        if unknown:
            raise ConfigError(f"{unknown} are not robots of {scenario.name} (ids {list(scenario.robot_ids)})",
                              "robot_ids")
        use_sim_time = bool(self.get_parameter("use_sim_time").value)
        common = [*hosted_parameters, Parameter("use_sim_time", value=use_sim_time)]
        self.peers = PeerTable(ids)
        self.controllers: dict[int, ControllerNode] = {}
        self.bridges: dict[int, BridgeNode] = {}
        try:
            for rid in ids:
                ns = f"/robot_{rid}"
                if self.prm.port_template:
                    self.bridges[rid] = BridgeNode(
                        context=context, namespace=ns, poll_timer=False, torque_topic=False,
                        parameter_overrides=common + [
                            Parameter("port", value=self.prm.port_template.replace("{id}", str(rid))),
                            Parameter("torque_limit_nm", value=float(scenario.robot(rid).params.torque_limit_nm))])
                self.controllers[rid] = ControllerNode(
                    context=context, namespace=ns, tick_timer=False, peers=self.peers,
                    bridge=self.bridges.get(rid),
                    parameter_overrides=common + [Parameter("scenario", value=str(self.prm.scenario)),
                                                  Parameter("robot_id", value=int(rid))])
        except BaseException:
            self.destroy_node()
            raise
        rates = {c.prm.control_rate_hz for c in self.controllers.values()}
        self.create_timer(1.0 / rates.pop(), self._control)
        if self.bridges:
            poll_hz = next(iter(self.bridges.values())).params.poll_rate_hz
            self.create_timer(1.0 / poll_hz, self._poll)
        self.get_logger().info(f"hosting robots {ids}" + (" with bridges" if self.bridges else ""))

    @property
    def composed_nodes(self) -> list[Node]:
        return [*self.bridges.values(), *self.controllers.values()]

    def _poll(self) -> None:
        for bridge in self.bridges.values():
            bridge.poll()

    def _control(self) -> None:
        now_s = self.get_clock().now().nanoseconds * 1e-9     # one time for the whole period
        for controller in self.controllers.values():
            controller.control_tick(now_s)

    def destroy_node(self):
        for node in [*self.controllers.values(), *self.bridges.values()]:
            node.destroy_node()
        self.controllers, self.bridges = {}, {}
        return super().destroy_node()


def _send_zero_torque(team: TeamNode) -> None:
    """Last word of the process: zero torque from every hosted controller."""
    for node in team.controllers.values():
        _controller_zero_torque(node)


def main(args: list[str] | None = None) -> int:
    return run_node("formation_team", TeamNode, args, on_exit=_send_zero_torque)


if __name__ == "__main__":
    sys.exit(main())
