"""`formation multihost` (issue 11): the camera PC and each robot on a host of its own, made of
network namespaces (tools/netns.py), DDS over UDP only between them.

Two robots of test/data/paper_short.yaml (14 s):

* a normal run: it completes, no prohibited entry, no contact, the world finished first, discovery
  and the traffic of each robot link are reported, the robot processes ran with the profile and
  the SUBNET range, and nothing of the network is left afterwards;
* robot 1's link taken down for 3 s at t = 4 s, with a lab's own Fast DDS profile that keeps
  Fast DDS's default blocking sends (test/data/fastdds_lab_udp.xml, kept by the launchers):
  its controller stops (a stopped state), the robot comes to rest before the link is back, its
  control loop does not stall on the network (the 2-3 s blocked publish of ros/nonblocking.py's
  docstring), robot 0 goes on, robot 1 runs again once its link is back, and the run completes;
* in the first run, robot 1's wall clock 0.9 s ahead of the camera PC's (``--clock-shift 1:0.9``,
  libfaketime, issue 33): its host really reads +0.9 s, its controller estimates the camera PC's
  clock (camera poses and coordinator messages) 0.9 s behind its own within CLOCK_ERROR_MAX_S, no
  robot stops for its clock and the run completes.

The runs are skipped, with the reason, when network namespaces cannot be made here (not root, no
`ip netns`); the first run keeps the true clock without libfaketime
(scripts/install_clock_deps.sh); the parsing of --link-down, --fault and --clock-shift is tested
anyway.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import subprocess
import sys
import time

import pytest

from ament_formation.core.errors import ConfigError
from ament_formation.tools import clock_shift, netns
from ament_formation.tools.clock_shift import parse_clock_shift, parse_clock_shifts
from ament_formation.tools.multihost_cmd import (
    CLOCK_ERROR_MAX_S,
    parse_fault,
    parse_faults,
    parse_link_down,
)

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'
LAB_PROFILE = ROOT / 'test' / 'data' / 'fastdds_lab_udp.xml'
REASON = netns.unavailable_reason()
# a control-loop gap the network would cause is 2-3 s (blocked sendto); a loaded 2-core machine
# gives gaps of a few hundred ms
GAP_LIMIT_S = 1.0

pytestmark = [pytest.mark.timeout(600)]
needs_netns = pytest.mark.skipif(REASON is not None, reason=f'multi-host test: {REASON}')
CLOCK_REASON = clock_shift.missing_reason()


def _multihost(out: Path, *extra: str) -> tuple[subprocess.CompletedProcess, dict]:
    proc = subprocess.run(
        [
            sys.executable, '-m', 'ament_formation.tools.cli', 'multihost',
            '--scenario', str(SCENARIO), '--out', str(out), '--no-figure',
            '--control-gap-max', str(GAP_LIMIT_S), *extra,
        ],
        capture_output=True,
        text=True,
        timeout=540,
        cwd=str(ROOT),
    )  # fmt: skip
    report_file = out / 'multihost.json'
    assert report_file.exists(), f'no multihost.json\n{proc.stdout}\n{proc.stderr}'
    return proc, json.loads(report_file.read_text())


def _checks(report: dict) -> dict:
    return {c['name']: c for c in report.get('checks') or []}


def _assert_ok(checks: dict, *names: str) -> None:
    for name in names:
        assert name in checks, f'check {name} missing: {sorted(checks)}'
        assert checks[name]['ok'], f'{name}: {checks[name]}'


def _no_namespaces_left(report: dict) -> None:
    assert report['namespaces_left'] == []
    mine = set(report['namespaces'].values())
    assert not mine & set(netns.list_namespaces()), 'namespaces of the run still exist'


@needs_netns
def test_two_robot_hosts_complete_the_mission(tmp_path):
    """Robot 1's wall clock runs 0.9 s ahead when libfaketime is installed (one run for both:
    the suite's time), else every host keeps the true clock.
    """
    out = tmp_path / 'run'
    shifted = CLOCK_REASON is None
    proc, report = _multihost(out, *(['--clock-shift', '1:0.9'] if shifted else []))
    detail = f'\n{proc.stdout}\n{proc.stderr}'
    assert proc.returncode in (0, 1), detail
    checks = _checks(report)
    _assert_ok(checks, 'processes', 'completed', 'prohibited_entries', 'contact', 'truth_gap_s')
    assert report['prohibited_entries'] == 0
    disc = report['discovery']
    assert disc['all_heard_s'] is not None and disc['all_heard_s'] > 0, disc
    assert disc['all_running_s'] is not None, disc
    # the coordinator decided the start after every robot's process was up (it cannot hear a
    # robot before); all_heard_s is when the base host's *recorder* first heard each robot, another
    # participant whose discovery may finish later than the coordinator's (seen: 65 ms after the
    # start on an idle machine), so it is reported, not ordered against the start
    up = max(r['node_up_s'] for r in disc['robots'].values())
    assert disc['mission_start_decided_s'] >= up - 1e-3, disc
    assert disc['mission_start_s'] > disc['mission_start_decided_s'], disc
    for rid in ('0', '1'):
        robot = disc['robots'][rid]
        assert robot['discovery_s'] is not None, disc
        link = report['traffic']['links'][rid]
        assert link['from_host_Bps'] > 0 and link['to_host_Bps'] > 0, report['traffic']
        env = report['robot_process_environment'][rid]
        assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET', env
        assert env['FASTRTPS_DEFAULT_PROFILES_FILE'] == report['profile'], env
        assert env['ROS_DOMAIN_ID'] == str(report['ros_domain_id']), env
        _assert_ok(checks, f'control_gap_s[R{rid}]')
    assert 'discovery:' in proc.stdout and 'traffic per robot link' in proc.stdout
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['prohibited_entries'] == 0
    if shifted:
        _clock_ahead_estimated(proc, report, checks)
    _no_namespaces_left(report)


def _clock_ahead_estimated(proc, report, checks) -> None:
    """Robot 1's host really reads +0.9 s, its controller estimates the camera PC's clock
    (camera poses and coordinator messages) 0.9 s behind its own within CLOCK_ERROR_MAX_S, and no
    robot stops for its clock.
    """
    _assert_ok(checks, 'clock_stop[R0]', 'clock_stop[R1]', 'clock_offset[R1.camera]',
               'clock_offset[R1.coordinator]')  # fmt: skip
    env = report['robot_process_environment']
    assert env['1']['FAKETIME'] == '+0.900000' and 'libfaketime' in env['1']['LD_PRELOAD'], env
    assert env['0']['FAKETIME'] is None, env  # robot 0's host keeps the true clock
    robot = report['clock']['robots']['1']
    assert robot['shift_s'] == 0.9
    assert abs(robot['measured_shift_s'] - 0.9) < 0.005, robot  # its host's clock, probed
    for source in ('camera', 'coordinator'):  # both on the camera PC: 0.9 s behind robot 1
        est = robot['estimates'][source]
        assert est['true_offset_s'] == -0.9, robot
        assert abs(est['estimated_offset_s'] + 0.9) <= CLOCK_ERROR_MAX_S, robot
    assert robot['clock_stop'] is None and report['clock']['robots']['0']['clock_stop'] is None
    assert 'clock R1: shifted +0.9000 s' in proc.stdout


@needs_netns
def test_link_loss_stops_the_robot_which_rejoins(tmp_path):
    out = tmp_path / 'run'
    proc, report = _multihost(out, '--link-down', '1:4:3', '--profile', str(LAB_PROFILE))
    detail = f'\n{proc.stdout}\n{proc.stderr}'
    assert proc.returncode in (0, 1), detail
    checks = _checks(report)
    _assert_ok(checks, 'processes', 'completed', 'prohibited_entries', 'contact', 'truth_gap_s')
    env = report['robot_process_environment']['1']
    assert env['FASTRTPS_DEFAULT_PROFILES_FILE'] == str(LAB_PROFILE), env  # the lab's own
    (trace,) = report['link_loss']
    assert trace['robot'] == 1
    assert 2.9 <= trace['up_t_s'] - trace['down_t_s'] <= 3.5, trace
    # its controller stopped, and the robot came to rest (not coasting) before the link was back
    assert trace['controller_stop'] and trace['controller_stop'].startswith('stopped'), trace
    assert trace['time_to_rest_s'] is not None, trace
    assert trace['time_to_rest_s'] < trace['up_t_s'] - trace['down_t_s'], trace
    assert trace['distance_to_rest_m'] < 0.1, trace
    # the safety logic did not block on the network
    _assert_ok(checks, 'control_gap_s[R1]', 'control_gap_s[R0]')
    # robot 0 went on meanwhile: its controller ran the law (heard in a law mode; on this 2-core
    # machine its own camera-loss stop may also cut in for a late pose) and it moved. How far is
    # not fixed: robot 1 is its follower, so the team's error slows the leader's reference while
    # robot 1 is held (S17.1); seen 0.02-0.15 m in these 3 s
    others = trace['others']['0']
    assert set(others['modes']) - {'hold', 'stopped'}, trace
    assert others['distance_m'] > 0.005, trace
    # robot 1 rejoined: its controller runs again and the camera PC hears it running
    _assert_ok(checks, 'link_loss[R1@4s].controller_stop', 'link_loss[R1@4s].at_rest_s',
               'link_loss[R1@4s].rejoined_s')  # fmt: skip
    assert trace['heard_running_after_up_s'] is not None, trace
    robot_log = (out / 'robot_1' / 'robot_1.log').read_text()
    assert 'publish thread:' in robot_log  # the robot process published off its control path
    _no_namespaces_left(report)


@needs_netns
def test_bad_input_and_no_leftovers(tmp_path):
    base = [sys.executable, '-m', 'ament_formation.tools.cli', 'multihost']
    for args, word in (
        (['--scenario', str(SCENARIO), '--link-down', '7:1:1'], '--link-down'),
        (['--scenario', str(SCENARIO), '--link-down', '1:x'], '--link-down'),
        (['--scenario', str(SCENARIO), '--fault', '1:4:bridge-stop'], '--fault'),
        (['--scenario', str(SCENARIO), '--rate', 'fast'], '--rate'),
        (['--scenario', str(SCENARIO), '--clock-shift', '7:0.9'], '--clock-shift'),
        (['--scenario', str(SCENARIO), '--profile', str(tmp_path / 'no.xml')], '--profile'),
        (['--scenario', str(SCENARIO), '--robot-params', str(tmp_path / 'no.yaml')],
         '--robot-params'),
        (['--robots', '12'], '--robots'),
    ):
        before = set(netns.list_namespaces())
        with subprocess.Popen(
            [*base, *args, '--out', str(tmp_path / 'bad')],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=dict(os.environ),
        ) as run:
            stdout, stderr = run.communicate(timeout=120)
        assert run.returncode == 2, (args, stdout, stderr)
        assert word in stderr, (args, stderr)
        assert len(stderr.strip().splitlines()) == 1, stderr
        # none of its namespaces (suffix: its pid % 10000 and 4 hex digits, tools/netns.py) is
        # left; other runs on the machine may be making theirs meanwhile
        ours = [
            n
            for n in set(netns.list_namespaces()) - before
            if n.rsplit('_', 1)[-1][:-4] == str(run.pid % 10000)
        ]
        assert ours == [], ours


def test_fault_and_link_down_parsing():
    """--fault ROBOT:AT_S:KIND and --link-down ROBOT:AT_S:DURATION_S: the values, and bad input
    as one ConfigError naming the option (no run).
    """
    ids = [0, 1]
    assert parse_fault('1:4:controller-kill', ids) == (1, 4.0, 'controller-kill')
    assert parse_fault('0:0.5:controller-stop', ids) == (0, 0.5, 'controller-stop')
    assert parse_fault('1:4:bridge-kill', ids) == (1, 4.0, 'bridge-kill')
    assert parse_faults(['0:2:bridge-kill', '1:4:controller-kill'], ids) == [
        (0, 2.0, 'bridge-kill'),
        (1, 4.0, 'controller-kill'),
    ]
    assert parse_link_down('1:4:3', ids) == (1, 4.0, 3.0)
    for bad in (
        '1:4',
        '1:4:controller-kill:2',
        'x:4:controller-kill',
        '1:soon:bridge-kill',
        '7:4:controller-kill',
        '1:-1:bridge-kill',
        '1:nan:bridge-kill',
        '1:4:kill',
        '',
    ):
        with pytest.raises(ConfigError) as err:
            parse_fault(bad, ids)
        assert '--fault' in str(err.value) and '\n' not in str(err.value), bad
    with pytest.raises(ConfigError, match='more than one fault'):
        parse_faults(['1:4:controller-kill', '1:6:bridge-kill'], ids)
    for bad in ('1:4', '7:1:1', '1:4:0'):
        with pytest.raises(ConfigError) as err:
            parse_link_down(bad, ids)
        assert '--link-down' in str(err.value), bad


def test_clock_shift_parsing():
    """--clock-shift ROBOT:SECONDS: the values (to the microsecond), bad input as one ConfigError
    naming the option.
    """
    ids = [0, 1]
    assert parse_clock_shift('1:0.9', ids) == (1, 0.9)
    assert parse_clock_shift('0:-5', ids) == (0, -5.0)
    assert parse_clock_shift('1:+0.2000004', ids) == (1, 0.2)
    assert parse_clock_shifts(['0:-0.9', '1:5'], ids) == {0: -0.9, 1: 5.0}
    assert clock_shift.faketime_spec(-0.9) == '-0.900000'
    for bad in ('1', '1:0.9:2', 'x:0.9', '1:soon', '7:0.9', '1:nan', '1:inf', '1:1e9', ''):
        with pytest.raises(ConfigError) as err:
            parse_clock_shift(bad, ids)
        assert '--clock-shift' in str(err.value) and '\n' not in str(err.value), bad
    with pytest.raises(ConfigError, match='more than one clock shift'):
        parse_clock_shifts(['1:0.2', '1:0.9'], ids)


def test_clock_report_of_a_robot(tmp_path):
    """tools/clock_shift.robot_clock: true offsets of each source from the shifts, the estimate's
    error, the clock stop found in the diagnostics and its reason in the log (the host's log times
    put back on the true clock; an earlier clock error while waiting is not the reason).
    """
    shifts = {1: -5.0}
    assert clock_shift.true_offset_s('camera', 1, shifts) == 5.0
    assert clock_shift.true_offset_s('robot_0', 1, shifts) == 5.0
    assert clock_shift.true_offset_s('robot_1', 0, shifts) == -5.0
    assert clock_shift.true_offset_s('robot_2', 0, shifts) == 0.0
    start = 1000.0
    statuses = [
        (start - 2.0, {'safety': 'waiting', 'clock_offset_coordinator_s': '5.9'}),
        (start + 1.0, {'safety': 'running', 'clock_offset_camera_s': '4.99',
                       'clock_offset_coordinator_s': '4.998'}),
        (start + 1.5, {'safety': 'stopped_clock', 'clock_offset_camera_s': '4.985',
                       'clock_offset_coordinator_s': '4.998'}),
    ]  # fmt: skip
    log = tmp_path / 'robot_1.log'
    shifted = start - 5.0  # the robot's log times read 5 s behind
    lines = [
        f'[ERROR] [{shifted - 2.0:.6f}] [robot_1.formation_controller]: the clock of coordinator '
        'is +5.900 s off ours, beyond the bound of 2 s: controlled stop',
        f'[ERROR] [{shifted + 1.49:.6f}] [robot_1.formation_controller]: the clock of camera is '
        '+4.985 s off ours, beyond the bound of 2 s: controlled stop',
        f'[WARN] [{shifted + 1.5:.6f}] [robot_1.formation_controller]: safety: running -> '
        'stopped_clock (a clock is off by more than the bound)',
    ]
    log.write_text('\n'.join(lines) + '\n')
    rec = clock_shift.robot_clock(1, shifts, statuses, start, log)
    cam = rec['estimates']['camera']
    assert cam['true_offset_s'] == 5.0 and cam['estimated_offset_s'] == 4.985
    assert cam['error_s'] == pytest.approx(-0.015) and cam['reports'] == 2
    assert rec['estimates']['coordinator']['min_s'] == 4.998  # the mission's reports only
    assert rec['clock_stop']['t_s'] == pytest.approx(1.5)
    assert rec['clock_stop']['reason'].startswith('the clock of camera is +4.985 s')
    assert rec['safety_first_t_s'] == {'waiting': -2.0, 'running': 1.0, 'stopped_clock': 1.5}
    assert [e['t_s'] for e in rec['clock_errors_logged']] == pytest.approx([-2.0, 1.49])


@pytest.mark.skipif(CLOCK_REASON is not None, reason=f'--clock-shift: {CLOCK_REASON}')
def test_a_shifted_host_reads_the_shift_sleeps_and_hands_the_gil_over(tmp_path):
    """What --clock-shift preloads (tools/clock_shift.py) shifts time.time() and nothing else a
    robot process relies on: time.sleep works (libfaketime 0.9.10 fails it with EINVAL, its issue
    #426), the monotonic clock is the true one and a thread waking beside a busy one gets the GIL
    back in time (pthread_cond_timedwait on a monotonic condition variable, the forced fix off).
    """
    code = (
        'import sys, threading, time\n'
        'sys.setswitchinterval(0.0005)\n'
        'busy = threading.Thread(target=lambda: [0 for _ in iter(int, 1)], daemon=True)\n'
        'm0 = time.monotonic()\n'
        'busy.start()\n'
        'n, t_end = 0, time.monotonic() + 1.0\n'
        'while time.monotonic() < t_end:\n'
        '    time.sleep(0.01)\n'
        '    n += 1\n'
        'print(time.time(), m0, n)\n'
    )  # fmt: skip
    fix = clock_shift.build_fix(tmp_path)
    env = dict(os.environ, **clock_shift.host_env(-5.0, fix))
    t0, m0 = time.time(), time.monotonic()
    with subprocess.Popen([sys.executable, '-c', code], env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True) as proc:  # fmt: skip
        stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    wall, mono, periods = stdout.split()
    assert t0 - 5.0 < float(wall) < time.time() - 5.0  # its wall clock: 5 s behind ours
    assert m0 <= float(mono) <= time.monotonic()  # the true monotonic clock
    assert int(periods) >= 40, periods  # ~90 idle; 3-15 with the forced monotonic fix on
    # libfaketime's semaphore and shared memory of that process: removed, nothing else
    clock_shift.remove_shm([proc.pid], t0)
    assert not list(Path('/dev/shm').glob(f'*faketime_s*_{proc.pid}'))
