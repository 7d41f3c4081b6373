"""The README's real-robot commands run as written across hosts (issue 33: "several machines as
the documented way to run robots: one command per machine that works as written").

The two commands are parsed from README.md ("### On real robots"): ``scripts/launch_robot.sh``
(each robot's computer) and ``scripts/launch_base.sh`` (the camera PC). They are run on hosts made
of Linux network namespaces (tools/netns.py: the camera PC and one host per robot on a bridge,
10.77.0.0/24; nothing outside the namespaces this test makes), each with a fresh machine's
environment (no ROS variable exported, no Fast DDS profile, not the tests' loopback guard), from
the checkout as the README's relative paths say. Only the hardware is replaced: the twin
(``formation_world``, on the camera host) stands for the motor boards and the camera, so a robot's
``--port`` is the twin's pty for it, ``--id`` is each robot's id in turn, and ``--camera`` is left
out (the twin publishes ``/camera/image_raw`` as a camera driver would). Everything else (the
lab-network default, the domain, the scenario) is the README's.

Checked from the camera host (tools/multihost_record.py, the `formation multihost` recorder):
every robot's controller is heard (robot -> camera PC), the coordinator starts the mission (it
heard every controller), every controller runs (it heard the graph and the tracker's poses:
camera PC -> robot) and the mission goes on for 3 s, each robot's link carried traffic both ways
(the switch's port counters), and each launcher says it ran on the lab network in the README's
domain. Skipped, with the reason, without root
or ``ip netns``; the parsing of the README is checked anyway.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import select
import shlex
import signal
import subprocess
import sys
import time

import pytest

from ament_formation.core.config_files import program_file
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.tools import netns

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / 'README.md'
REASON = netns.unavailable_reason()
START_TIMEOUT_S = 240.0  # programs' start and discovery on a loaded 2-core machine
# what a fresh lab machine has not exported (and the tests' own loopback settings)
_FRESH_UNSET = (
    'ROS_DOMAIN_ID',
    'ROS_AUTOMATIC_DISCOVERY_RANGE',
    'ROS_STATIC_PEERS',
    'ROS_LOCALHOST_ONLY',
    'ROS_LOG_DIR',
    'FASTRTPS_DEFAULT_PROFILES_FILE',
    'FASTDDS_DEFAULT_PROFILES_FILE',
    'RMW_IMPLEMENTATION',
    'AMENT_FORMATION_DDS',
    'AMENT_FORMATION_LOOPBACK_ONLY',
)

_NOT_DRIVING = ('hold', 'stopped', 'waiting')  # a controller's modes before it drives

pytestmark = [pytest.mark.timeout(900)]


def readme_lab_commands() -> dict[str, list[str]]:
    """{'launch_robot.sh': argv, 'launch_base.sh': argv} of the README's real-robot block."""
    section = README.read_text().split('### On real robots', 1)[1]
    block = section.split('```bash', 1)[1].split('```', 1)[0]
    commands = {}
    for line in block.splitlines():
        argv = shlex.split(line, comments=True)
        if argv:
            commands[Path(argv[0]).name] = argv
    return commands


def _option(argv: list[str], name: str) -> str:
    return argv[argv.index(name) + 1]


def _replaced(argv: list[str], name: str, value: str | None) -> list[str]:
    """``argv`` with option ``name``'s value replaced by ``value`` (None: the option dropped)."""
    i = argv.index(name)
    return argv[:i] + ([] if value is None else [name, value]) + argv[i + 2:]


def test_the_readme_gives_one_lab_command_per_machine():
    commands = readme_lab_commands()
    assert sorted(commands) == ['launch_base.sh', 'launch_robot.sh'], commands
    robot, base = commands['launch_robot.sh'], commands['launch_base.sh']
    assert robot[0] == 'scripts/launch_robot.sh' and base[0] == 'scripts/launch_base.sh'
    for argv in (robot, base):
        assert '--loopback' not in argv and '--multi-machine' not in argv  # the default network
        assert 0 <= int(_option(argv, '--domain')) <= 101  # ROS's safe range on Linux
        assert (ROOT / _option(argv, '--scenario')).is_file()
    assert _option(robot, '--domain') == _option(base, '--domain')
    assert _option(robot, '--scenario') == _option(base, '--scenario')
    assert {'--id', '--port'} <= set(robot)


def _fresh_env(tmp_dir: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in _FRESH_UNSET}
    env['TMPDIR'] = str(tmp_dir)  # the launchers' run folders (mktemp -d) land in the test's
    env['PYTHONUNBUFFERED'] = '1'
    return env


class _Host:
    """The processes this test starts inside the namespaces (stopped by PID at the end)."""

    def __init__(self, net: netns.LabNetwork, tmp_path: Path):
        self.net, self.tmp = net, tmp_path
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, host, argv: list[str], env: dict, pipe: bool = False):
        log = open(self.tmp / f'{name}.log', 'w')
        self.procs[name] = subprocess.Popen(
            [*self.net.exec_prefix(host), *argv],
            stdout=subprocess.PIPE if pipe else log,
            stderr=log,
            env=env,
            cwd=ROOT,
            start_new_session=True,
        )
        log.close()
        return self.procs[name]

    def dead(self) -> list[str]:
        return [n for n, p in self.procs.items() if p.poll() is not None]

    def log(self, name: str) -> str:
        return (self.tmp / f'{name}.log').read_text(errors='replace')[-3000:]

    def stop_all(self) -> None:
        for name in reversed(list(self.procs)):  # robots and base first, the world last
            proc = self.procs[name]
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(timeout=20.0)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()


def _events(recorder: subprocess.Popen, buf: list[bytes], timeout_s: float) -> list[dict]:
    """The recorder's JSON events that arrived within ``timeout_s``."""
    ready, _, _ = select.select([recorder.stdout], [], [], timeout_s)
    if not ready:
        return []
    chunk = os.read(recorder.stdout.fileno(), 65536)
    *lines, rest = (buf[0] + chunk).split(b'\n')
    buf[0] = rest
    out = []
    for line in lines:
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out


@pytest.mark.skipif(REASON is not None, reason=f'multi-host test: {REASON}')
def test_the_readme_lab_commands_find_each_other_across_hosts(tmp_path):
    commands = readme_lab_commands()
    robot_cmd, base_cmd = commands['launch_robot.sh'], commands['launch_base.sh']
    domain = _option(base_cmd, '--domain')
    scenario = ROOT / _option(base_cmd, '--scenario')
    ids = list(load_scenario(scenario).robot_ids)
    net = netns.LabNetwork(ids)
    hosts = _Host(net, tmp_path)
    pty_dir = tmp_path / 'pty'
    # the twin stands for the lab's camera and boards: on the camera host, on the lab network
    # the launchers choose by default (the README's domain, subnet discovery, the UDP profile)
    twin_env = dict(
        _fresh_env(tmp_path),
        ROS_DOMAIN_ID=domain,
        ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET',
        FASTRTPS_DEFAULT_PROFILES_FILE=str(ROOT / 'config' / 'fastdds_udp.xml'),
        ROS_LOG_DIR=str(tmp_path / 'twin_log'),
    )
    seen = {'ready': False, 'start': None, 'state': set(), 'running': set(), 't': 0.0}
    buf = [b'']
    try:
        net.build()
        world = [program_file('formation_world'), '--ros-args',
                 '--params-file', str(ROOT / 'config' / 'params' / 'formation_world.yaml'),
                 '-p', f'scenario:={scenario}', '-p', f'pty_dir:={pty_dir}',
                 '-p', 'speed_factor:=1.0']  # fmt: skip
        hosts.start('world', 'camera', world, twin_env)
        recorder = hosts.start(
            'recorder', 'camera',
            [sys.executable, '-m', 'ament_formation.tools.multihost_record',
             '--scenario', str(scenario), '--out', str(tmp_path / 'run.mcap')],
            twin_env, pipe=True,
        )  # fmt: skip
        # the camera PC's command as written, but its camera: the twin's images on the topic
        (tmp_path / 'base').mkdir()
        hosts.start('base', 'camera', _replaced(base_cmd, '--camera', None),
                    _fresh_env(tmp_path / 'base'))  # fmt: skip
        deadline = time.monotonic() + START_TIMEOUT_S
        while not (seen['ready'] and all((pty_dir / f'robot_{i}').exists() for i in ids)):
            assert not hosts.dead(), {n: hosts.log(n) for n in hosts.dead()}
            assert time.monotonic() < deadline, 'the twin or the recorder did not come up'
            seen['ready'] |= any(e.get('ev') == 'ready' for e in _events(recorder, buf, 0.2))
        counters0 = net.counters()
        for rid in ids:  # each robot's command as written, with its id and its board's port
            argv = _replaced(_replaced(robot_cmd, '--id', str(rid)), '--port',
                             str(pty_dir / f'robot_{rid}'))  # fmt: skip
            (tmp_path / f'robot_{rid}').mkdir()
            hosts.start(f'robot_{rid}', rid, argv, _fresh_env(tmp_path / f'robot_{rid}'))
        deadline = time.monotonic() + START_TIMEOUT_S
        while not (seen['start'] is not None and seen['running'] >= set(ids) and seen['t'] > 3.0):
            assert not hosts.dead(), (seen, {n: hosts.log(n) for n in hosts.dead()})
            assert time.monotonic() < deadline, (
                f'not within {START_TIMEOUT_S:g} s: {seen}\n'
                + '\n'.join(f'--- {n}\n{hosts.log(n)}' for n in hosts.procs if n != 'recorder')
            )
            for ev in _events(recorder, buf, 0.2):
                kind = ev.get('ev')
                if kind == 'start':
                    seen['start'] = ev['start_s']
                elif kind == 'state':
                    seen['state'].add(ev['robot'])
                elif kind == 'mode' and not str(ev['mode']).startswith(_NOT_DRIVING):
                    seen['running'].add(ev['robot'])  # a mode of the law: it drives
                elif kind == 't':
                    seen['t'] = ev['t']
        counters = net.counters()
        moved = {h: (c[0] - counters0[h][0], c[1] - counters0[h][1]) for h, c in counters.items()}
        print(f'README lab commands across hosts: {seen}; link bytes (from, to) per host since '
              f'the robots were launched: {moved}')  # fmt: skip
        assert seen['state'] == set(ids)  # every controller heard on the camera PC
        for rid in ids:  # traffic crossed each robot's link both ways (bytes from, to the host)
            assert moved[rid][0] > 10_000 and moved[rid][1] > 10_000, (rid, moved[rid])
        for name in ('base', *(f'robot_{r}' for r in ids)):
            assert f'ROS_DOMAIN_ID={domain}' in hosts.log(name), hosts.log(name)
            assert 'network: lab (subnet discovery' in hosts.log(name), hosts.log(name)
    finally:
        hosts.stop_all()
        failed = net.destroy()
    assert failed == [] and net.leftovers() == []
    for name in ('base', *(f'robot_{r}' for r in ids)):  # a launcher ends 143 after TERM
        assert hosts.procs[name].returncode == 143, (name, hosts.log(name))
