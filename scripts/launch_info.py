"""Print shell assignments describing a scenario for scripts/launch_*.sh (ids, marker ids, limits).

    eval "$(python scripts/launch_info.py SCENARIO.yaml [PARAMS.yaml])"
sets ids="0 1", robot_ids_list="[0, 1]", marker_ids_list="[0, 1]", torque_<id>=<N m>.
PARAMS.yaml (a launcher's --params) is checked as the nodes will read it: the safe reader's
checks, well-formed YAML, then rcl's own parse (ros/params.py init_rclpy_checked).
Bad scenario or params file: one line on stderr, exit code 2.
"""

import shlex
import sys

from ament_formation.core.errors import ConfigError
from ament_formation.core.scenario.loader import load_scenario


def _check_params(path: str) -> None:
    import rclpy
    from rclpy.context import Context

    from ament_formation.ros.params import init_rclpy_checked

    ctx = Context()
    init_rclpy_checked(['launch_info', '--ros-args', '--params-file', path], context=ctx)
    rclpy.shutdown(context=ctx)


try:
    sc = load_scenario(sys.argv[1])
    if len(sys.argv) > 2:
        _check_params(sys.argv[2])
except ConfigError as err:
    print(err, file=sys.stderr)
    sys.exit(2)
ids = [r.id for r in sc.robots]
print(f'ids={shlex.quote(" ".join(map(str, ids)))}')
print(f'robot_ids_list={shlex.quote(str(ids))}')
print(f'marker_ids_list={shlex.quote(str([r.marker_id for r in sc.robots]))}')
for r in sc.robots:
    print(f'torque_{r.id}={r.params.torque_limit_nm!r}')
