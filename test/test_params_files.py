"""Parameters of every node: the installed params files (config/params/<node>.yaml), their
descriptors, and what a wrong value does at start and at run time.

The process tests start the real console scripts (``formation_*``, found on PATH or in the install
prefix by processes.program) with the installed params file and talk to them with a small rclpy
client (rcl_interfaces GetParameters, DescribeParameters, SetParameters), as ``ros2 param`` would.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
from pathlib import Path
import signal
import subprocess

from processes import program
import pytest
import yaml

from ament_formation.core.config_files import config_file
from ament_formation.core.errors import ConfigError
from ament_formation.core.params import param

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'

# node name -> (module, parameter dataclass)
NODES = {
    'formation_world': ('ament_formation.nodes.world', 'WorldParams'),
    'formation_tracker': ('ament_formation.nodes.tracker', 'TrackerNodeParams'),
    'formation_bridge': ('ament_formation.core.serial.serial_link', 'LinkParams'),
    'formation_controller': ('ament_formation.nodes.controller', 'ControllerParams'),
    'formation_coordinator': ('ament_formation.nodes.coordinator', 'CoordinatorParams'),
    'formation_team': ('ament_formation.nodes.team', 'TeamParams'),
}
# parameters a params file leaves to the command line (required, or not writable in ROS YAML)
COMMAND_LINE_ONLY = {'scenario', 'robot_id'}
EMPTY_LIST_ONLY = {'formation_team': {'robot_ids'}}  # [] cannot be written in a ROS params file
REQUIRED = {'scenario': 'x.yaml', 'robot_id': 0}


def _params_class(node: str):
    module, name = NODES[node]
    return getattr(importlib.import_module(module), name)


def _file_params(node: str) -> dict:
    data = yaml.safe_load(config_file(f'params/{node}.yaml').read_text())
    assert list(data) == [f'/**/{node}'], f'{node}.yaml: one key /**/{node} expected'
    return data[f'/**/{node}']['ros__parameters']


def _required_for(cls) -> dict:
    names = {f.name for f in dataclasses.fields(cls)}
    return {k: v for k, v in REQUIRED.items() if k in names}


# ---------------------------------------------------------------------------------- static checks
@pytest.mark.parametrize('node', sorted(NODES))
def test_params_file_lists_every_parameter_with_its_default(node):
    cls = _params_class(node)
    values = _file_params(node)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    assert set(values) == set(fields) - COMMAND_LINE_ONLY - EMPTY_LIST_ONLY.get(node, set())
    for name, value in values.items():
        default = fields[name].default
        if isinstance(default, tuple):
            default = list(default)
        assert value == default and type(value) is type(default), (name, value, default)


@pytest.mark.parametrize('node', sorted(NODES))
def test_every_parameter_has_a_description_and_ranges_match_the_validation(node):
    """Each field is declared with ``param`` (a description); a value just outside a declared
    range is also refused by the dataclass, so the descriptor never rejects a valid value.
    """
    cls = _params_class(node)
    base = _required_for(cls)
    for f in dataclasses.fields(cls):
        assert f.metadata.get('description'), f'{cls.__name__}.{f.name} has no description'
        bounds = f.metadata.get('range')
        if not bounds:
            continue
        lo, hi = bounds
        assert lo < hi
        is_int = isinstance(f.default, int)
        step = 1 if is_int else 1e-3 * max(1.0, abs(lo), abs(hi))
        for outside in (lo - step, hi + step):
            with pytest.raises(ValueError):
                cls(**{**base, f.name: outside})


def test_params_files_are_installed_by_setup_py():
    import ast

    tree = ast.parse((ROOT / 'setup.py').read_text())
    walked = any(
        isinstance(n, ast.Call) and getattr(n.func, 'id', '') == 'config_files'
        for n in ast.walk(tree)
    )
    assert walked, 'setup.py data_files must walk config/ (config/params/ lands in share/)'
    assert sorted(p.stem for p in (ROOT / 'config' / 'params').glob('*.yaml')) == sorted(NODES)


# ------------------------------------------------------------------------------ in-process checks
@dataclasses.dataclass(frozen=True)
class _Demo:
    rate_hz: float = param(10.0, 'a rate [Hz]', range=(1.0, 100.0), live=True)
    label: str = param('a', 'a label')
    count: int = param(3, 'a count', range=(0, 10))
    gains: tuple[float, ...] = param((1.0, 2.0), 'gains [1]')

    def __post_init__(self) -> None:
        if self.rate_hz == 13.0:
            raise ConfigError('13 Hz is unlucky', 'rate_hz')


def _node(ctx, name='demo', **overrides):
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    return Node(
        name,
        context=ctx,
        parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()],
    )


def test_descriptors_carry_type_description_range_and_read_only(ros_context):
    from rcl_interfaces.msg import ParameterType

    from ament_formation.ros.params import declare_dataclass

    node = _node(ros_context)
    try:
        declare_dataclass(node, _Demo)
        rate, label, count, gains = node.describe_parameters(
            ['rate_hz', 'label', 'count', 'gains']
        )
        assert rate.type == ParameterType.PARAMETER_DOUBLE and rate.description == 'a rate [Hz]'
        assert (
            rate.floating_point_range[0].from_value,
            rate.floating_point_range[0].to_value,
        ) == (1.0, 100.0)
        assert rate.read_only  # live, but nobody applies it (no on_change)
        assert label.read_only and label.type == ParameterType.PARAMETER_STRING
        assert count.integer_range[0].from_value == 0 and count.integer_range[0].to_value == 10
        assert gains.type == ParameterType.PARAMETER_DOUBLE_ARRAY
    finally:
        node.destroy_node()


def test_integer_for_float_is_taken_and_wrong_types_name_the_parameter(ros_context):
    from ament_formation.ros.params import declare_dataclass

    node = _node(ros_context, 'ok', rate_hz=20, gains=[1, 3])
    try:
        obj = declare_dataclass(node, _Demo)
        assert obj.rate_hz == 20.0 and isinstance(obj.rate_hz, float)
        assert obj.gains == (1.0, 3.0) and all(isinstance(g, float) for g in obj.gains)
    finally:
        node.destroy_node()
    for name, value, expected in (
        ('rate_hz', 'fast', 'expected a float'),
        ('label', 7, 'expected a string'),
        ('count', 2.5, 'expected an integer'),
        ('gains', ['a'], 'expected a list of floats'),
    ):
        node = _node(ros_context, 'bad', **{name: value})
        try:
            with pytest.raises(ConfigError) as err:
                declare_dataclass(node, _Demo)
            line = str(err.value)
            assert line.startswith(f'/bad: {name}: {expected}') and '\n' not in line, line
        finally:
            node.destroy_node()
    node = _node(ros_context, 'range', count=11)
    try:
        with pytest.raises(ConfigError, match=r'^/range: count: must be in \[0, 10\] \(got 11\)'):
            declare_dataclass(node, _Demo)
    finally:
        node.destroy_node()


def test_live_parameter_is_validated_by_the_dataclass_and_applied(ros_context):
    from rclpy.parameter import Parameter

    from ament_formation.ros.params import declare_dataclass

    node = _node(ros_context)
    applied = []
    try:
        obj = declare_dataclass(node, _Demo, on_change=applied.append)
        assert obj.rate_hz == 10.0 and not node.describe_parameter('rate_hz').read_only

        def set_(name, value):
            return node.set_parameters([Parameter(name, value=value)])[0]

        res = set_('rate_hz', 500.0)
        assert not res.successful and 'out of range' in res.reason
        res = set_('rate_hz', 13.0)
        assert not res.successful and '13 Hz is unlucky' in res.reason
        res = set_('rate_hz', 'x')
        assert not res.successful
        res = set_('label', 'b')
        assert not res.successful and 'read-only' in res.reason
        assert applied == [] and node.get_parameter('rate_hz').value == 10.0
        res = set_('rate_hz', 20.0)
        assert res.successful and [a.rate_hz for a in applied] == [20.0]
        assert applied[0].label == 'a' and node.get_parameter('rate_hz').value == 20.0
    finally:
        node.destroy_node()


# --------------------------------------------------------------------------------- process checks
# per node: extra command line, (namespace, node name) that holds the parameters, one parameter
# changed in a copy of the installed file to show the file reaches the node
def _launches(tmp: Path) -> dict:
    scen = f'scenario:={SCENARIO}'
    return {
        'formation_world': (
            [
                '-p',
                scen,
                '-p',
                f'pty_dir:={tmp / "ptys"}',
                '-p',
                'exit_at_end:=false',
                '-p',
                'camera_enabled:=false',
            ],
            '/formation_world',
            ('tick_s', 0.02),
        ),
        'formation_tracker': ([], '/formation_tracker', ('max_speed_mps', 2.0)),
        'formation_bridge': (
            [
                '-r',
                '__ns:=/robot_0',
                '-p',
                f'port:={tmp / "no_board"}',
                '-p',
                'wait_for_port:=true',
            ],
            '/robot_0/formation_bridge',
            ('command_rate_hz', 50.0),
        ),
        'formation_controller': (
            ['-r', '__ns:=/robot_0', '-p', scen, '-p', 'robot_id:=0'],
            '/robot_0/formation_controller',
            ('pose_timeout_s', 0.7),
        ),
        'formation_coordinator': (
            ['-p', scen],
            '/formation_coordinator',
            ('markers_rate_hz', 2.0),
        ),
        'formation_team': (
            [
                '-p',
                scen,
                '-p',
                'robot_ids:=[1]',
                '-p',
                'wait_for_port:=true',
                '--params-file',
                str(config_file('params/formation_controller.yaml')),
            ],
            '/formation_team',
            ('port_template', f'{tmp}/no_board_{{id}}'),
        ),
    }


@pytest.fixture(scope='module')
def node_processes(tmp_path_factory):
    """Every node process, started with its installed params file (and a copy of it with one
    value changed, given second).
    """
    tmp = tmp_path_factory.mktemp('params_nodes')
    procs = {}
    try:
        for node, (extra, fqn, (name, value)) in _launches(tmp).items():
            changed = {f'/**/{node}': {'ros__parameters': {name: value}}}
            copy = tmp / f'{node}.yaml'
            copy.write_text(yaml.safe_dump(changed))
            cmd = [
                program(node),
                '--ros-args',
                '--params-file',
                str(config_file(f'params/{node}.yaml')),
                '--params-file',
                str(copy),
                *extra,
            ]
            log = open(tmp / f'{node}.log', 'w')
            procs[node] = (
                subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT),
                fqn,
                (name, value),
                tmp / f'{node}.log',
            )
            log.close()
        yield procs
    finally:
        for proc, *_ in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc, *_ in procs.values():
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _call(node, executor, srv_type, name, request, timeout_s=120.0):
    """Call service ``name``; a request is sent again every 10 s without an answer (a response
    can be lost while discovery of the reply reader is still under way, slow on a busy machine;
    the calls made here are idempotent).
    """
    import time

    from ament_formation.ros.executors import spin_until

    deadline = time.monotonic() + timeout_s
    client = node.create_client(srv_type, name)
    try:
        assert spin_until(executor, client.service_is_ready, timeout_s), f'{name} never came up'
        while True:
            future = client.call_async(request)
            if spin_until(executor, future.done, min(10.0, max(0.1, deadline - time.monotonic()))):
                return future.result()
            client.remove_pending_request(future)
            assert time.monotonic() < deadline, f'{name}: no answer in {timeout_s:g} s'
    finally:
        node.destroy_client(client)


def _get(node, executor, fqn, names):
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    res = _call(
        node,
        executor,
        GetParameters,
        f'{fqn}/get_parameters',
        GetParameters.Request(names=list(names)),
    )
    return {n: parameter_value_to_python(v) for n, v in zip(names, res.values)}


def _alive_or_log(procs, node):
    proc, _fqn, _changed, log = procs[node]
    assert proc.poll() is None, f'{node} exited {proc.returncode}:\n{log.read_text()[-3000:]}'


@pytest.mark.timeout(400)
@pytest.mark.parametrize('node', sorted(NODES))
def test_node_starts_with_its_installed_params_file(node, node_processes, ros_context, executor):
    from rcl_interfaces.srv import DescribeParameters

    procs = node_processes
    _proc, fqn, (changed, value), _log = procs[node]
    client = _node(ros_context, 'params_client')
    executor.add_node(client)
    try:
        extra = _launches(Path('/'))[node][0]
        on_command_line = {a.split(':=')[0] for a in extra if ':=' in a}
        want = {k: v for k, v in _file_params(node).items() if k not in on_command_line}
        want[changed] = value
        got = _get(client, executor, fqn, list(want))
        _alive_or_log(procs, node)
        for name, v in want.items():
            assert got[name] == pytest.approx(v) if isinstance(v, float) else got[name] == v, (
                name,
                got[name],
                v,
            )
        desc = _call(
            client,
            executor,
            DescribeParameters,
            f'{fqn}/describe_parameters',
            DescribeParameters.Request(names=list(want)),
        ).descriptors
        assert all(d.read_only and d.description for d in desc), [
            d.name for d in desc if not (d.read_only and d.description)
        ]
        if node == 'formation_team':  # hosted controllers read formation_controller.yaml
            hosted = _get(client, executor, '/robot_1/formation_controller', ['control_rate_hz'])
            assert hosted == {'control_rate_hz': 100.0}
    finally:
        executor.remove_node(client)
        client.destroy_node()


@pytest.mark.timeout(300)
def test_run_time_change_of_a_read_only_or_out_of_range_value_is_rejected(
    node_processes, ros_context, executor
):
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    fqn = '/robot_0/formation_bridge'
    client = _node(ros_context, 'set_client')
    executor.add_node(client)
    try:
        for name, value in (
            ('torque_limit_nm', -5.0),
            ('torque_limit_nm', 0.1),
            ('torque_limit_nm', 'abc'),
            ('port', '/dev/null'),
        ):
            msg: ParameterMsg = Parameter(name, value=value).to_parameter_msg()
            res = _call(
                client,
                executor,
                SetParameters,
                f'{fqn}/set_parameters',
                SetParameters.Request(parameters=[msg]),
            ).results[0]
            assert not res.successful and res.reason, (name, value, res)
        assert _get(client, executor, fqn, ['torque_limit_nm']) == {'torque_limit_nm': 0.15}
        _alive_or_log(node_processes, 'formation_bridge')
    finally:
        executor.remove_node(client)
        client.destroy_node()


@pytest.mark.parametrize(
    'exe, args, parameter, expected',
    [
        (
            'formation_bridge',
            ['-p', 'torque_limit_nm:=abc'],
            'torque_limit_nm',
            'expected a float',
        ),
        ('formation_tracker', ['-p', 'camera_config:=0'], 'camera_config', 'expected a string'),
        (
            'formation_controller',
            ['-p', f'scenario:={SCENARIO}', '-p', 'robot_id:=zero'],
            'robot_id',
            'expected an integer',
        ),
        (
            'formation_coordinator',
            ['-p', f'scenario:={SCENARIO}', '-p', 'markers_rate_hz:=500.0'],
            'markers_rate_hz',
            'must be in [0, 100]',
        ),
    ],
)
def test_wrong_type_at_start_is_one_line_and_exit_2(exe, args, parameter, expected):
    node = exe
    proc = subprocess.run(
        [
            program(exe),
            '--ros-args',
            '--params-file',
            str(config_file(f'params/{node}.yaml')),
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, 'RCUTILS_LOGGING_USE_STDOUT': '0'},
    )
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr
    lines = [ln for ln in proc.stderr.strip().splitlines() if not ln.startswith('[')]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f'{node}: /{node}: {parameter}: {expected}'), lines[0]
