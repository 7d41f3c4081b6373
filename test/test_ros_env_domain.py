"""scripts/ros_env.sh: concurrent shells get different ROS_DOMAIN_IDs (a lock per id).

An id is free again when the shell that took it (and everything it started) is gone.
"""

import fcntl
import os
from pathlib import Path
import subprocess
import sys

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / 'scripts' / 'ros_env.sh'
# source the script, print the domain, then hold it until stdin closes
HOLD = f'source "{SCRIPT}" "$LOGDIR" >/dev/null; echo "$ROS_DOMAIN_ID"; read -r _ || true'


def _env(tmp_path, lock_dir):
    env = {k: v for k, v in os.environ.items() if k != 'ROS_DOMAIN_ID'}
    env.update(AF_DOMAIN_LOCK_DIR=str(lock_dir), LOGDIR=str(tmp_path / 'log'))
    return env


def _shell(env):
    p = subprocess.Popen(
        ['bash', '-c', HOLD], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env
    )
    return p, int(p.stdout.readline())


def _stop(p):
    p.stdin.close()
    assert p.wait(timeout=30) == 0


def test_concurrent_shells_get_free_domains_and_release_them(tmp_path):
    lock_dir = tmp_path / 'locks'
    lock_dir.mkdir()
    free = {17, 101}
    held = []
    for d in range(1, 102):  # everything but two ids is taken by "other runs"
        if d in free:
            continue
        f = open(lock_dir / f'{d}.lock', 'a')
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        held.append(f)
    env = _env(tmp_path, lock_dir)
    try:
        first, d1 = _shell(env)
        second, d2 = _shell(env)
        assert {d1, d2} == free  # both free ids, never one twice
        _stop(first)  # the first run ends: its id is free again
        third, d3 = _shell(env)
        assert d3 == d1
        _stop(second)
        _stop(third)
    finally:
        for f in held:
            f.close()


def test_domains_stay_in_ros_safe_range_on_linux(tmp_path):
    """Every id ros_env.sh draws is in 1..101 (ROS's safe range on Linux is 0..101), also when
    every id is held (its fallback) and from the test harness's own helpers.
    """
    from processes import take_free_domain

    lock_dir = tmp_path / 'locks'
    lock_dir.mkdir()
    env = _env(tmp_path, lock_dir)
    drawn = []
    shells = []
    try:
        for _ in range(101):  # takes every id in turn: each shell holds its own until stopped
            p, d = _shell(env)
            shells.append(p)
            drawn.append(d)
        assert sorted(drawn) == list(range(1, 102))
        for _ in range(5):  # all held: the random fallback
            p, d = _shell(env)
            _stop(p)
            assert 1 <= d <= 101
    finally:
        for p in shells:
            _stop(p)
    taken = take_free_domain()
    assert taken is not None and 1 <= taken[0] <= 101
    os.close(taken[1])
    assert 1 <= int(os.environ['ROS_DOMAIN_ID']) <= 101  # test/conftest.py's choice


def test_a_chosen_domain_is_kept(tmp_path):
    env = _env(tmp_path, tmp_path / 'locks')
    env['ROS_DOMAIN_ID'] = '42'
    out = subprocess.run(
        ['bash', '-c', f'source "{SCRIPT}" "$LOGDIR"; echo "$ROS_DOMAIN_ID"'],
        env=env,
        capture_output=True,
        text=True,
        timeout=30,
        check=True,
    )
    assert out.stdout.split() == ['42']


def test_formation_run_takes_a_free_domain_too(tmp_path):
    """`formation run` without ros_env.sh (tools/run_cmd.loopback_env) uses the same locks."""
    lock_dir = tmp_path / 'locks'
    lock_dir.mkdir()
    held = []
    for d in range(1, 102):
        if d != 77:
            f = open(lock_dir / f'{d}.lock', 'a')
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            held.append(f)
    env = _env(tmp_path, lock_dir)
    code = (
        'from pathlib import Path; import os; from ament_formation.tools import run_cmd; '
        "run_cmd.loopback_env(Path('log')); print(os.environ['ROS_DOMAIN_ID'])"
    )
    try:
        out = subprocess.run(
            [sys.executable, '-c', code],
            env=env,
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=120,
            check=True,
        )
        assert out.stdout.split() == ['77']
    finally:
        for f in held:
            f.close()
