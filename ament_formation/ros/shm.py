"""Shared memory the ROS processes of a run leave in /dev/shm, and its cleanup.

liblttng-ust (loaded by the ROS wheels) creates ``lttng-ust-wait-*``, and Fast DDS's shared-memory
transport (which it keeps next to the loopback UDP one) leaves ``fastrtps_*`` / ``sem.fastrtps_*``
segments when a process does not close them. The rules are those of scripts/ros_env.sh
(``af_shm_snapshot`` / ``af_shm_cleanup``), for runs that a Python process drives (``formation
run``): remember what existed, and at the end remove only what appeared since and no other live
process still uses. In use: any entry of its group (the name without ``sem.`` and
``_mutex``/``_el``/``_sl``) mapped or held open by a live process. Fast DDS keeps a segment mapped,
but its liveness lock file (``<segment>_el``) only open and its port mutex
(``sem.fastrtps_port<N>_mutex``) neither mapped nor open between uses: removing those of another
run's live participant broke that run's shared-memory delivery mid-run.
"""

from __future__ import annotations

import os
from pathlib import Path
import re

SHM_DIR = Path('/dev/shm')
PATTERN = re.compile(r'^(lttng-ust-wait|fastrtps_|sem\.fastrtps_)')


def snapshot(shm_dir: Path = SHM_DIR) -> frozenset[str]:
    """Names of the run-related entries in ``shm_dir`` now."""
    try:
        return frozenset(n for n in os.listdir(shm_dir) if PATTERN.match(n))
    except FileNotFoundError:
        return frozenset()


def mapped(shm_dir: Path = SHM_DIR, ignore_pid: int | None = None) -> set[str]:
    """Names in ``shm_dir`` that a live process (other than ``ignore_pid``) has mapped."""
    prefix = f'{shm_dir}/'
    names: set[str] = set()
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit() or int(entry.name) == ignore_pid:
            continue
        try:
            text = (entry / 'maps').read_text()
        except OSError:  # gone, or not ours to read
            continue
        for line in text.splitlines():
            at = line.find(prefix)
            if at >= 0:
                names.add(line[at + len(prefix):].split()[0])
    return names


def held_open(shm_dir: Path = SHM_DIR, ignore_pid: int | None = None) -> set[str]:
    """Names in ``shm_dir`` that a live process (other than ``ignore_pid``) holds open."""
    prefix = f'{shm_dir}/'
    names: set[str] = set()
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit() or int(entry.name) == ignore_pid:
            continue
        try:
            fds = list((entry / 'fd').iterdir())
        except OSError:  # gone, or not ours to read
            continue
        for fd in fds:
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith(prefix):
                names.add(target.removeprefix(prefix))
    return names


def group(name: str) -> str:
    """The Fast DDS object an entry belongs to: its name without ``sem.`` and
    ``_mutex``/``_el``/``_sl`` (a segment, its lock files and its mutex share one group).
    """
    name = name.removeprefix('sem.')
    for suffix in ('_mutex', '_el', '_sl'):
        name = name.removesuffix(suffix)
    return name


def in_use(shm_dir: Path = SHM_DIR, ignore_pid: int | None = None) -> set[str]:
    """Groups (:func:`group`) of which a live process (other than ``ignore_pid``) maps or holds
    open an entry.
    """
    return {group(n) for n in mapped(shm_dir, ignore_pid) | held_open(shm_dir, ignore_pid)}


def cleanup(
    before: frozenset[str], shm_dir: Path = SHM_DIR, ignore_pid: int | None = None
) -> list[str]:
    """Remove the entries that appeared since ``before`` (a :func:`snapshot`) and whose group no
    live process other than ``ignore_pid`` uses (:func:`in_use`); return their names.
    """
    new = snapshot(shm_dir) - before
    if not new:
        return []
    busy = in_use(shm_dir, ignore_pid)
    removed = []
    for name in sorted(n for n in new if group(n) not in busy):
        try:
            (shm_dir / name).unlink()
            removed.append(name)
        except FileNotFoundError:
            pass
    return removed
