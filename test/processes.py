"""Process helpers shared by the launcher tests."""

from __future__ import annotations

import os
from pathlib import Path


def alive(pid: int) -> bool:
    """True while process ``pid`` exists and is not a zombie."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:
        return Path(f'/proc/{pid}/stat').read_text().split()[2] != 'Z'
    except OSError:
        return False


def warm_numba_kernels(timeout_s: float = 900.0, check: bool = False) -> None:
    """Compile numba's kernels once (core/jit_cache.py), unless warm already, for each copy of the
    package the tests run: the one this process imports, and the one a program started from
    anywhere else imports. They differ under ``colcon test``: pytest runs in the source folder and
    imports the checkout, while colcon's PYTHONPATH puts the installed copy
    (install/ament_formation/lib/python3.X/site-packages) before the .venv's editable checkout, so
    every console script runs the installed copy, whose kernels (numba keys its cache on the
    source file's path) would otherwise compile in each program at start, all at once.
    """
    import subprocess
    import sys
    import tempfile

    import ament_formation

    mine = Path(ament_formation.__file__).resolve().parents[1]  # the folder holding the package
    code = 'import sys; from ament_formation.core.sim.jit_warm import main; sys.exit(main())'
    with tempfile.TemporaryDirectory(prefix='af_warm_') as elsewhere:
        for cwd in (mine, elsewhere):  # '' (the cwd) comes first on a ``python -c`` sys.path
            subprocess.run([sys.executable, '-c', code], cwd=cwd, check=check, timeout=timeout_s)


DOMAIN_LOCKS = Path(os.environ.get('TMPDIR', '/tmp')) / 'ament_formation_domains'


def take_free_domain(avoid=()) -> tuple[int, int] | None:
    """A DDS domain id in 1..200 that no other run on this machine holds and not in ``avoid``:
    (id, fd of its lock; close it to release the id), or None.

    The lock files of scripts/ros_env.sh (flock on ``<id>.lock``, released when the fd closes):
    concurrent runs in one domain see each other's nodes and topics.
    """
    import fcntl
    import random

    try:
        DOMAIN_LOCKS.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    first = random.randrange(200)
    for i in range(200):
        domain = (first + i) % 200 + 1
        if domain in avoid:
            continue
        fd = os.open(DOMAIN_LOCKS / f'{domain}.lock', os.O_CREAT | os.O_WRONLY | os.O_APPEND)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return domain, fd
        except OSError:
            os.close(fd)
    return None
