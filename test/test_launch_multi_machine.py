"""The lab network (scripts/launch_common.sh): the default of launch_robot.sh and
launch_base.sh, --multi-machine of af_launch_init. A lab's own Fast DDS profile
(FASTRTPS_DEFAULT_PROFILES_FILE other than the project's loopback profile) survives; otherwise the
loopback profile is replaced by the project's UDP profile; a missing file is bad input (one line,
exit code 2). The launchers need a domain id in ROS's safe range (--domain N or ROS_DOMAIN_ID,
0..101) for it, and refuse it under AMENT_FORMATION_LOOPBACK_ONLY (the tests' guard). Nothing
here starts a DDS participant: the environment is inspected in a shell, the bad input exits first.
"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / 'scripts'
SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'
LOOPBACK = ROOT / 'config' / 'fastdds_localhost.xml'  # loopback UDP only
SHM = ROOT / 'config' / 'fastdds_localhost_shm.xml'  # the one-machine default
UDP = ROOT / 'config' / 'fastdds_udp.xml'
_UNSET = (
    'FASTRTPS_DEFAULT_PROFILES_FILE',
    'ROS_AUTOMATIC_DISCOVERY_RANGE',
    'AMENT_FORMATION_LOOPBACK_ONLY',  # these runs exit at bad input or start nothing
)


def _env(profile: str | None, domain: str | None = '7', dds: str | None = None) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in (*_UNSET, 'ROS_DOMAIN_ID', 'AMENT_FORMATION_DDS')}
    if domain is not None:
        env['ROS_DOMAIN_ID'] = domain
    if profile is not None:
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = profile
    if dds is not None:
        env['AMENT_FORMATION_DDS'] = dds
    return env


def _launch_env(
    tmp_path: Path, profile: str | None, multi: bool, dds: str | None = None
) -> tuple[str, str]:
    """(FASTRTPS_DEFAULT_PROFILES_FILE or '<unset>', ROS_AUTOMATIC_DISCOVERY_RANGE) after
    af_launch_init.
    """
    script = (
        f'source "{SCRIPTS}/launch_common.sh" && af_launch_init "{tmp_path}/run" '
        f'{"--multi-machine" if multi else ""} && '
        'printf "%s\\n%s\\n" "${FASTRTPS_DEFAULT_PROFILES_FILE-<unset>}" '
        '"$ROS_AUTOMATIC_DISCOVERY_RANGE"'
    )
    proc = subprocess.run(
        ['bash', '-c', script], env=_env(profile, dds=dds), capture_output=True, text=True,
        timeout=30,
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    return lines[0], lines[1]


def test_multi_machine_keeps_a_labs_profile(tmp_path):
    lab = tmp_path / 'lab_profile.xml'
    lab.write_text('<profiles/>\n')
    assert _launch_env(tmp_path, str(lab), multi=True) == (str(lab), 'SUBNET')


@pytest.mark.parametrize('profile', [None, str(LOOPBACK), str(SHM)],
                         ids=['unset', 'loopback_profile', 'shm_profile'])
def test_multi_machine_replaces_the_loopback_profile_by_the_udp_one(tmp_path, profile):
    assert _launch_env(tmp_path, profile, multi=True) == (str(UDP), 'SUBNET')


def test_single_machine_stays_on_loopback(tmp_path):
    # the default: discovery range LOCALHOST with the shared-memory profile
    assert _launch_env(tmp_path, None, multi=False) == (str(SHM), 'LOCALHOST')
    assert _launch_env(tmp_path, None, multi=False, dds='shm') == (str(SHM), 'LOCALHOST')


def test_single_machine_udp_only_on_request(tmp_path):
    # AMENT_FORMATION_DDS=udp: the loopback profile governs discovery (UDP on 127.0.0.1 only, no
    # shared memory; docs/executors.md "The stall found")
    assert _launch_env(tmp_path, None, multi=False, dds='udp') == (str(LOOPBACK), 'SUBNET')


@pytest.mark.parametrize('launcher', ['launch_robot.sh', 'launch_base.sh'])
def test_multi_machine_missing_profile_is_bad_input(tmp_path, launcher):
    args = {
        'launch_robot.sh': ['--id', '0', '--port', '/dev/null', '--scenario', str(SCENARIO)],
        'launch_base.sh': ['--scenario', str(SCENARIO)],
    }[launcher]
    proc = subprocess.run(
        [str(SCRIPTS / launcher), *args, '--multi-machine', '--run-dir', str(tmp_path / 'run')],
        env=_env(str(tmp_path / 'missing.xml')),
        capture_output=True,
        text=True,
        timeout=30,
        cwd=tmp_path,
    )
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert (
        len(lines) == 1 and 'FASTRTPS_DEFAULT_PROFILES_FILE' in lines[0] and launcher in lines[0]
    ), proc.stderr
    assert 'missing.xml' in lines[0]
    assert proc.stdout == ''  # nothing was started


_ROBOT = ['launch_robot.sh', '--id', '0', '--port', '/dev/null', '--scenario', str(SCENARIO)]
_BASE = ['launch_base.sh', '--scenario', str(SCENARIO)]


def _refusal(tmp_path: Path, args: list[str], env: dict) -> str:
    """The one line a launcher refuses ``args`` with (exit 2, nothing started)."""
    proc = subprocess.run(
        [str(SCRIPTS / args[0]), *args[1:], '--run-dir', str(tmp_path / 'run')],
        env=env, capture_output=True, text=True, timeout=60, cwd=tmp_path,
    )  # fmt: skip
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and args[0] in lines[0], proc.stderr
    assert proc.stdout == '' and not (tmp_path / 'run').exists()  # nothing was started
    return lines[0]


@pytest.mark.parametrize('args', [_ROBOT, _BASE], ids=['robot', 'base'])
def test_the_lab_network_is_the_default_and_needs_a_safe_domain_id(tmp_path, args):
    line = _refusal(tmp_path, args, _env(None, domain=None))
    assert '--domain N (0..101) or export ROS_DOMAIN_ID' in line and '--loopback' in line
    for bad in ('102', '232', '-1', '4x'):
        line = _refusal(tmp_path, [*args, '--domain', bad], _env(None, domain=None))
        assert f"--domain: expected a ROS domain id in [0, 101] (ROS's safe range on Linux), " \
               f"got '{bad}'" in line  # fmt: skip
    line = _refusal(tmp_path, args, _env(None, domain='150'))  # an exported id out of range
    assert 'ROS_DOMAIN_ID: expected a ROS domain id in [0, 101]' in line and "'150'" in line


@pytest.mark.parametrize('args', [_ROBOT, _BASE], ids=['robot', 'base'])
def test_the_tests_guard_refuses_the_lab_network(tmp_path, args):
    env = dict(_env(None), AMENT_FORMATION_LOOPBACK_ONLY='1')
    line = _refusal(tmp_path, [*args, '--domain', '42'], env)
    assert 'the lab network is refused here' in line and 'add --loopback' in line
