"""The whole system in one process: every node of a simulated run in one executor (world with real
ptys and rendered frames, a bridge and a controller per robot, tracker, coordinator). Used by the
system tests and the benchmarks; `formation run` starts the same nodes as separate processes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import shutil
import tempfile

from rclpy.parameter import Parameter


@dataclass
class InProcessSystem:
    """Handles to every node of an in-process run (see :func:`build_system`)."""

    world: object
    bridges: dict = field(default_factory=dict)
    controllers: dict = field(default_factory=dict)
    tracker: object = None
    coordinator: object = None
    team: object = None  # the formation_team node hosting bridges and controllers, if any
    pty_dir: Path | None = None
    owns_pty_dir: bool = False  # build_system made pty_dir: destroy() removes it

    @property
    def nodes(self) -> list:
        hosts = [self.team] if self.team is not None else []
        return [
            self.world,
            *hosts,
            *self.bridges.values(),
            *self.controllers.values(),
            self.tracker,
            self.coordinator,
        ]

    def destroy(self, executor=None) -> None:
        """Remove the nodes from ``executor`` and destroy them (controllers first, world last)."""
        hosted = [*self.controllers.values(), *self.bridges.values()]
        if self.team is not None and executor is not None:
            for node in hosted:
                executor.remove_node(node)
        first = [self.team] if self.team is not None else list(self.controllers.values())
        last = [] if self.team is not None else list(self.bridges.values())
        for node in [*first, self.coordinator, self.tracker, *last, self.world]:
            if node is None:
                continue
            if executor is not None:
                executor.remove_node(node)
            node.destroy_node()  # the team node destroys the nodes it hosts
        if self.owns_pty_dir and self.pty_dir is not None:
            shutil.rmtree(self.pty_dir, ignore_errors=True)


def build_system(
    context,
    scenario_path: str | Path,
    executor=None,
    *,
    speed_factor: float = 1.0,
    start_delay_s: float = 1.0,
    pty_dir: str | Path | None = None,
    camera_noise: float = 2.0,
    controller_overrides: dict | None = None,
    bridge_poll_rate_hz: float = 500.0,
    team: bool = False,
) -> InProcessSystem:
    """Create every node of a simulated run in ``context`` (and add them to ``executor``).

    ``speed_factor`` != 1 runs on the world's /clock (use_sim_time on every other node).
    ``team``: the robots' bridges and controllers hosted by one formation_team node
    (nodes/team.py: one control tick, peer states in process) instead of a node pair per robot.
    """
    from ament_formation.core.scenario.loader import load_scenario
    from ament_formation.nodes.bridge import BridgeNode
    from ament_formation.nodes.controller import ControllerNode, ControllerParams
    from ament_formation.nodes.coordinator import CoordinatorNode, CoordinatorParams
    from ament_formation.nodes.tracker import TrackerNode, TrackerNodeParams
    from ament_formation.nodes.world import WorldNode, WorldParams

    scenario = load_scenario(scenario_path)
    owns_pty_dir = not pty_dir
    pty_dir = Path(pty_dir) if pty_dir else Path(tempfile.mkdtemp(prefix='ament_formation_sys_'))
    sim_time = [Parameter('use_sim_time', value=speed_factor != 1.0)]
    world = WorldNode(
        context=context,
        params=WorldParams(
            scenario=str(scenario_path),
            pty_dir=str(pty_dir),
            speed_factor=speed_factor,
            camera_noise=camera_noise,
        ),
    )
    system = InProcessSystem(world=world, pty_dir=pty_dir, owns_pty_dir=owns_pty_dir)
    if team:
        from ament_formation.nodes.team import TeamNode, TeamParams

        hosted = [
            Parameter('poll_rate_hz', value=float(bridge_poll_rate_hz)),
            *(Parameter(k, value=v) for k, v in (controller_overrides or {}).items()),
        ]
        system.team = TeamNode(
            context=context,
            parameter_overrides=sim_time,
            hosted_parameters=hosted,
            params=TeamParams(
                scenario=str(scenario_path), port_template=str(pty_dir / 'robot_{id}')
            ),
        )
        system.bridges, system.controllers = (
            dict(system.team.bridges),
            dict(system.team.controllers),
        )
    for r in scenario.robots if not team else ():
        ns = f'/robot_{r.id}'
        system.bridges[r.id] = BridgeNode(
            context=context,
            namespace=ns,
            parameter_overrides=sim_time
            + [
                Parameter('port', value=str(pty_dir / f'robot_{r.id}')),
                Parameter('torque_limit_nm', value=float(r.params.torque_limit_nm)),
                Parameter('poll_rate_hz', value=float(bridge_poll_rate_hz)),
            ],
        )
        system.controllers[r.id] = ControllerNode(
            context=context,
            namespace=ns,
            parameter_overrides=sim_time,
            params=ControllerParams(
                scenario=str(scenario_path), robot_id=r.id, **(controller_overrides or {})
            ),
        )
    system.tracker = TrackerNode(
        context=context,
        parameter_overrides=sim_time,
        params=TrackerNodeParams(
            marker_ids=tuple(r.marker_id for r in scenario.robots),
            robot_ids=tuple(r.id for r in scenario.robots),
        ),
    )
    system.coordinator = CoordinatorNode(
        context=context,
        parameter_overrides=sim_time,
        params=CoordinatorParams(scenario=str(scenario_path), start_delay_s=start_delay_s),
    )
    if executor is not None:
        for node in system.nodes:
            executor.add_node(node)
    return system
