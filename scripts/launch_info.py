"""Print shell assignments describing a scenario for scripts/launch_*.sh (ids, marker ids, limits).

    eval "$(python scripts/launch_info.py SCENARIO.yaml [PARAMS.yaml] [--camera-fit DIR [CAMERA]])"
sets ids="0 1", robot_ids_list="[0, 1]", marker_ids_list="[0, 1]", torque_<id>=<N m>.
PARAMS.yaml (a launcher's --params) is checked as the nodes will read it: the safe reader's
checks, well-formed YAML, then rcl's own parse (ros/params.py init_rclpy_checked).
--camera-fit DIR [CAMERA] (the simulated twin, launch_sim.sh): also sets camera_file, the camera
file the world and the tracker must share: CAMERA (a config/ name or a path; default
camera.yaml) when it sees every start and goal of the scenario, otherwise one fitted to the
scenario written to DIR/camera.yaml (core/scenario/coverage.py), said in one line on stderr.
--camera-check (the camera PC, launch_base.sh): one line on stderr when the tracker's camera (the
``camera_config`` of PARAMS.yaml's formation_tracker, else camera.yaml) does not see every start
and goal of the scenario: the robots there will get no pose.
Bad scenario, params or camera file: one line on stderr, exit code 2.
"""

from pathlib import Path
import shlex
import sys

from ament_formation.core.errors import ConfigError
from ament_formation.core.scenario.loader import load_scenario


def _tracker_camera(params_file: str | None) -> str:
    """The camera_config a tracker started with ``params_file`` reads."""
    import yaml

    camera = 'camera.yaml'
    if params_file:
        data = yaml.safe_load(Path(params_file).read_text()) or {}
        for node in ('/**', 'formation_tracker', '/formation_tracker'):
            block = (data.get(node) or {}).get('ros__parameters') or {}
            camera = str(block.get('camera_config', camera))
    return camera


def _camera_check(scenario, camera: str) -> None:
    from ament_formation.core.config_files import config_file
    from ament_formation.core.scenario import coverage
    from ament_formation.core.vision.camera_model import load_camera_yaml

    path = Path(camera) if Path(camera).is_file() else config_file(camera)
    missed = coverage.unseen(load_camera_yaml(path).camera,
                             coverage.scenario_extent_m(scenario, obstacles=False))
    if len(missed):
        x, y = missed[0]
        print(f'launch_info: warning: {scenario.name} leaves the view of {path} (e.g. at '
              f'({x:.2f}, {y:.2f}) m): robots there get no camera pose (docs/camera.md, '
              '"Coverage")', file=sys.stderr)


def _camera_file(scenario, folder: str, camera: str) -> str:
    from ament_formation.core.config_files import config_file
    from ament_formation.core.scenario import coverage
    from ament_formation.core.vision.camera_model import load_camera_yaml, save_camera_yaml

    path = Path(camera) if Path(camera).is_file() else config_file(camera)  # as the nodes do
    setup = load_camera_yaml(path)
    if not coverage.needs_fitting(setup, scenario):
        return str(path.resolve())
    fitted = coverage.fit_camera(setup, coverage.scenario_extent_m(scenario))
    out = save_camera_yaml(fitted, Path(folder) / 'camera.yaml')
    w, h = fitted.camera.size_px
    print(f'launch_info: {scenario.name} leaves the view of {path.name}: the simulated camera is '
          f'fitted to it ({w}x{h} px, same lens and height): {out}', file=sys.stderr)
    return str(out)


def _check_params(path: str) -> None:
    import rclpy
    from rclpy.context import Context

    from ament_formation.ros.params import init_rclpy_checked

    ctx = Context()
    init_rclpy_checked(['launch_info', '--ros-args', '--params-file', path], context=ctx)
    rclpy.shutdown(context=ctx)


args = sys.argv[1:]
fit = None
check = '--camera-check' in args
if check:
    args.remove('--camera-check')
if '--camera-fit' in args:
    k = args.index('--camera-fit')
    fit, args = args[k + 1:], args[:k]
try:
    sc = load_scenario(args[0])
    if len(args) > 1:
        _check_params(args[1])
    if fit is not None:
        camera_file = _camera_file(sc, fit[0], fit[1] if len(fit) > 1 else 'camera.yaml')
        print(f'camera_file={shlex.quote(camera_file)}')
    if check:
        _camera_check(sc, _tracker_camera(args[1] if len(args) > 1 else None))
except (ConfigError, FileNotFoundError) as err:
    print(err, file=sys.stderr)
    sys.exit(2)
ids = [r.id for r in sc.robots]
print(f'ids={shlex.quote(" ".join(map(str, ids)))}')
print(f'robot_ids_list={shlex.quote(str(ids))}')
print(f'marker_ids_list={shlex.quote(str([r.marker_id for r in sc.robots]))}')
for r in sc.robots:
    print(f'torque_{r.id}={r.params.torque_limit_nm!r}')
