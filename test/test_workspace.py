"""The package in a ROS 2 workspace (issue 33): scripts/workspace_check.sh --build-only makes a
workspace with this working tree in src/ (no .venv), builds it with colcon on the emulated system
ROS (a venv outside the source: the ros-jazzy-* wheels, the dependencies, colcon), and the
programs then start from its install tree in a clean environment (system ROS + install/setup.bash
+ scripts/ros_env.sh, nothing of this run's own environment): `formation sim`, a node with the
topic tool, the launchers of the install and of the source tree. The whole `colcon test` in such
a workspace is the script without --build-only (docs/package.md).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import signal
import subprocess
import time

from processes import alive
import pytest
import yaml

from ament_formation.tools.entry import PROGRAMS

ROOT = Path(__file__).resolve().parents[1]
SHORT = 'test/data/paper_short.yaml'
# the first run of the system ROS venv installs it (minutes); numba compiles the installed copy
pytestmark = pytest.mark.timeout(1800)


def _clean_env(work: Path) -> dict[str, str]:
    """The environment of a lab's shell in the workspace: the system ROS and the install sourced,
    DDS on loopback in a domain of its own; nothing inherited but HOME and TMPDIR.
    """
    script = (
        f'source "{work}/env.bash" && '
        f'source "{work}/install/ament_formation/share/ament_formation/scripts/ros_env.sh" '
        f'"{work}/ros_log" >/dev/null && env -0'
    )
    base = {
        'HOME': os.environ.get('HOME', '/root'),
        'TMPDIR': os.environ.get('TMPDIR', '/tmp'),
        'PATH': '/usr/local/bin:/usr/bin:/bin',
        'LANG': 'C.UTF-8',
    }
    out = subprocess.run(['bash', '-c', script], env=base, capture_output=True, timeout=60)
    assert out.returncode == 0, out.stderr.decode()
    pairs = (item.split('=', 1) for item in out.stdout.decode().split('\0') if '=' in item)
    env = dict(pairs)
    env['ROS_DOMAIN_ID'] = os.environ['ROS_DOMAIN_ID']  # this module's own (test/conftest.py)
    return env


@pytest.fixture(scope='module')
def ws(tmp_path_factory):
    work = tmp_path_factory.mktemp('ws')
    out = subprocess.run(
        [str(ROOT / 'scripts' / 'workspace_check.sh'), '--work', str(work), '--from-worktree',
         '--build-only'],
        capture_output=True,
        text=True,
        timeout=1500,
    )
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    env = _clean_env(work)
    prefix = work / 'install' / 'ament_formation'
    return work, env, prefix


def test_the_workspace_has_no_venv_and_installs_every_program(ws):
    work, env, prefix = ws
    src = work / 'src' / 'ament_formation'
    assert (src / 'package.xml').is_file() and not (src / '.venv').exists()
    for name in PROGRAMS:
        exe = prefix / 'lib' / 'ament_formation' / name
        assert exe.is_file() and os.access(exe, os.X_OK), name
        assert '.venv' not in exe.read_text().splitlines()[0], exe  # its interpreter: the system's
    assert '.venv' not in env['PATH'] + env.get('PYTHONPATH', '') + env.get('LD_LIBRARY_PATH', '')
    # the package the programs import is the installed copy
    out = subprocess.run(
        [str(prefix / 'lib' / 'ament_formation' / 'formation'), 'sim', '--help'],
        env=env, capture_output=True, text=True, timeout=120, cwd=work,
    )
    assert out.returncode == 0 and '--out' in out.stdout, out.stderr
    where = subprocess.run(
        ['python3', '-c', 'import ament_formation; print(ament_formation.__file__)'],
        env=env, capture_output=True, text=True, timeout=120, cwd=work,
    )
    assert where.stdout.strip().startswith(str(prefix / 'lib')), where


def test_formation_sim_runs_from_the_install_tree(ws, tmp_path):
    work, env, prefix = ws
    scenario = work / 'src' / 'ament_formation' / SHORT
    out = subprocess.run(
        [str(prefix / 'lib' / 'ament_formation' / 'formation'), 'sim', str(scenario),
         '--out', str(tmp_path / 'run'), '--no-figure', '--quiet'],
        env=env, capture_output=True, text=True, timeout=1200, cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    metrics = json.loads((tmp_path / 'run' / 'metrics.json').read_text())
    duration_s = yaml.safe_load(scenario.read_text())['duration_s']
    # the run lasts until the mission ends: every leader's reference at its end, no sooner than
    # the free traversal duration_s (a reference may wait for its team, docs/control-law.md S17)
    assert metrics['mission_end_s'] is not None
    assert duration_s - 0.02 <= metrics['mission_end_s'] <= metrics['sim_time_s'] + 0.02
    assert metrics['prohibited_entries'] == 0
    assert metrics['min_clearance_m'] > 0.0


def test_a_node_and_the_topic_tool_talk_from_the_install_tree(ws, tmp_path):
    """`ros2 run ament_formation formation_bridge --ros-args --params-file <installed params>`
    as a workspace runs it (the console script in <prefix>/lib/ament_formation) on an emulated
    motor board, heard by the installed `formation echo`.
    """
    work, env, prefix = ws
    lib = prefix / 'lib' / 'ament_formation'
    params = prefix / 'share' / 'ament_formation' / 'config' / 'params' / 'formation_bridge.yaml'
    link = tmp_path / 'board.tty'
    board = subprocess.Popen(
        [str(lib / 'formation'), 'board', '--pty', '--link', str(link)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )
    bridge = None
    try:
        deadline = time.monotonic() + 120
        while not link.exists() and time.monotonic() < deadline and board.poll() is None:
            time.sleep(0.05)
        assert link.exists(), board.stderr.read() if board.poll() is not None else 'no pty'
        bridge = subprocess.Popen(
            [str(lib / 'formation_bridge'), '--ros-args', '-r', '__ns:=/robot_0',
             '--params-file', str(params), '-p', f'port:={link}'],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )
        echo = subprocess.run(
            [str(lib / 'formation'), 'echo', '/robot_0/wheel_state', '--once', '--timeout', '120'],
            env=env, capture_output=True, text=True, timeout=300,
        )
        assert echo.returncode == 0, echo.stderr[-2000:]
        assert 'position' in echo.stdout and 'velocity' in echo.stdout, echo.stdout
        bridge.send_signal(signal.SIGINT)
        assert bridge.wait(timeout=60) == 0, bridge.stderr.read()[-2000:]
    finally:
        for proc in (bridge, board):
            if proc is not None and alive(proc.pid):
                proc.kill()
                proc.wait(timeout=30)


@pytest.mark.parametrize('tree', ['install', 'source'])
def test_the_launchers_find_the_installed_programs(ws, tree):
    """launch_robot.sh of the install (share/ament_formation/scripts) and of the source tree
    (no .venv there) find the programs and their interpreter: the scenario is read, and a robot
    id it does not have is the usual one line and exit code 2.
    """
    work, env, prefix = ws
    base = prefix / 'share' / 'ament_formation' if tree == 'install' else work / 'src' / (
        'ament_formation'
    )
    scenario = work / 'src' / 'ament_formation' / SHORT
    out = subprocess.run(
        [str(base / 'scripts' / 'launch_robot.sh'), '--id', '7', '--port', '/dev/null',
         '--scenario', str(scenario), '--loopback'],
        env=env, capture_output=True, text=True, timeout=300, cwd=work,
    )
    assert out.returncode == 2, out
    assert out.stderr.splitlines() == [
        f'launch_robot.sh: --id: robot 7 is not in {scenario} (ids: 0 1)'
    ]


def test_a_launcher_without_programs_says_what_to_do(ws):
    """The source tree's launcher with only the system ROS sourced (no install, no .venv)."""
    work, env, prefix = ws
    bare = {k: v for k, v in env.items() if k not in ('AMENT_PREFIX_PATH', 'PYTHONPATH')}
    out = subprocess.run(
        [str(work / 'src' / 'ament_formation' / 'scripts' / 'launch_robot.sh'), '--id', '0',
         '--port', '/dev/null', '--scenario', str(work / 'src' / 'ament_formation' / SHORT),
         '--loopback'],
        env=bare, capture_output=True, text=True, timeout=120, cwd=work,
    )
    assert out.returncode == 2, out
    assert out.stderr.splitlines() == [
        'launch_robot.sh: the ament_formation programs (formation_world, ...) are not installed: '
        'run scripts/setup.sh in a checkout, or colcon build and source install/setup.bash'
    ]
