"""Clean-up of /dev/shm after a run (ament_formation/ros/shm.py and scripts/ros_env.sh's
af_shm_cleanup): an entry goes only when no live process maps or holds open any entry of its group.
Fast DDS keeps a participant's lock file (<segment>_el) open but not mapped, and its port mutex
(sem.fastrtps_port<N>_mutex) neither: the clean-up once removed those of another run's live
participants, and that run's processes stopped hearing each other. Both implementations run on a
temporary folder (AF_SHM_DIR / shm_dir), with the processes of this test as the live ones.
"""

from __future__ import annotations

from pathlib import Path
import subprocess

from ament_formation.ros import shm

ROOT = Path(__file__).resolve().parents[1]
LIVE = ['fastrtps_aaaa', 'fastrtps_aaaa_el', 'sem.fastrtps_port7001_mutex', 'fastrtps_port7001']
DEAD = ['fastrtps_bbbb', 'fastrtps_bbbb_el', 'sem.fastrtps_port7003_mutex', 'lttng-ust-wait-8']
OTHER = ['fastrtps_port9_el', 'unrelated_file']  # fastrtps_port9_el: existed before the snapshot


def _touch(folder: Path, names) -> None:
    for name in names:
        (folder / name).write_bytes(b'\0' * 64)


def test_python_cleanup_keeps_every_entry_of_a_live_group(tmp_path):
    _touch(tmp_path, OTHER)
    before = shm.snapshot(tmp_path)
    _touch(tmp_path, LIVE + DEAD)
    import mmap

    with (
        open(tmp_path / 'fastrtps_aaaa_el', 'rb') as lock,  # held open, not mapped
        open(tmp_path / 'fastrtps_port7001', 'r+b') as seg,
        mmap.mmap(seg.fileno(), 64) as mapped,  # mapped (the file closed after: still mapped)
    ):
        assert lock and mapped
        removed = shm.cleanup(before, shm_dir=tmp_path)
    assert sorted(removed) == sorted(DEAD)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(LIVE + OTHER)
    assert shm.group('sem.fastrtps_port7001_mutex') == shm.group('fastrtps_port7001_el')


def _bash(script: str, tmp_path: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [
            'bash',
            '-c',
            f'set -euo pipefail; source "{ROOT}/scripts/ros_env.sh" "{tmp_path}/log"; ' + script,
        ],
        env={'PATH': '/usr/bin:/bin', 'AF_SHM_DIR': str(tmp_path / 'shm'), 'HOME': str(tmp_path)},
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_shell_cleanup_keeps_every_entry_of_a_live_group_and_takes_what_ours_used(tmp_path):
    d = tmp_path / 'shm'
    d.mkdir()
    _touch(d, OTHER + ['fastrtps_pre', 'fastrtps_pre_el'])  # before the snapshot
    names = ' '.join(LIVE + DEAD)
    res = _bash(
        f"""
        af_shm_snapshot
        for n in {names}; do head -c 64 /dev/zero >"$AF_SHM_DIR/$n"; done
        exec 9<"$AF_SHM_DIR/fastrtps_aaaa_el"          # this shell holds the lock file open
        sleep 300 <"$AF_SHM_DIR/fastrtps_port7001" &    # a live process holds the port open
        live=$!
        sleep 300 <"$AF_SHM_DIR/fastrtps_pre_el" &      # "our" process uses an older entry
        ours=$!
        for _ in $(seq 100); do
          [ -e /proc/$ours/fd/0 ] && [ -e /proc/$live/fd/0 ] && break; sleep 0.05
        done
        af_shm_note_used "$ours"
        kill "$ours"; wait "$ours" 2>/dev/null || true
        af_shm_cleanup
        kill "$live"; wait "$live" 2>/dev/null || true
        ls "$AF_SHM_DIR"
        """,
        tmp_path,
    )
    assert res.returncode == 0, res.stderr
    left = sorted(res.stdout.split())
    # the live groups stay (lock file held by the shell, port held by a live process: its mutex
    # too); the dead ones go; the older entry our process used goes; the other older ones stay
    assert left == sorted(LIVE + OTHER), res.stdout
