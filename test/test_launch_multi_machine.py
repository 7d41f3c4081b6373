"""--multi-machine keeps a lab's own Fast DDS profile (scripts/launch_common.sh): a
FASTRTPS_DEFAULT_PROFILES_FILE set by the user (other than the project's loopback profile)
survives,
the loopback profile is dropped, a missing file is bad input (one line, exit code 2). Nothing here
starts a DDS participant: the environment is inspected in a shell, the bad input exits first.
"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / 'scripts'
SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'
LOOPBACK = ROOT / 'config' / 'fastdds_localhost.xml'


def _env(profile: str | None, dds: str | None = None) -> dict:
    dropped = (
        'FASTRTPS_DEFAULT_PROFILES_FILE',
        'ROS_AUTOMATIC_DISCOVERY_RANGE',
        'AMENT_FORMATION_DDS',
    )
    env = {k: v for k, v in os.environ.items() if k not in dropped}
    env['ROS_DOMAIN_ID'] = '7'
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
        ['bash', '-c', script], env=_env(profile, dds), capture_output=True, text=True, timeout=30
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    return lines[0], lines[1]


def test_multi_machine_keeps_a_labs_profile(tmp_path):
    lab = tmp_path / 'lab_profile.xml'
    lab.write_text('<profiles/>\n')
    assert _launch_env(tmp_path, str(lab), multi=True) == (str(lab), 'SUBNET')


@pytest.mark.parametrize('profile', [None, str(LOOPBACK)], ids=['unset', 'loopback_profile'])
def test_multi_machine_drops_the_loopback_profile(tmp_path, profile):
    assert _launch_env(tmp_path, profile, multi=True) == ('<unset>', 'SUBNET')


def test_single_machine_stays_on_loopback_udp(tmp_path):
    # the loopback profile governs discovery (range SUBNET): UDP on 127.0.0.1 only, no shared
    # memory (docs/executors.md "The stall found")
    assert _launch_env(tmp_path, None, multi=False) == (str(LOOPBACK), 'SUBNET')
    assert _launch_env(tmp_path, None, multi=False, dds='udp') == (str(LOOPBACK), 'SUBNET')


def test_single_machine_with_shared_memory_on_request(tmp_path):
    assert _launch_env(tmp_path, None, multi=False, dds='shm') == (str(LOOPBACK), 'LOCALHOST')


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
