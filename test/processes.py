"""Process helpers shared by the tests that start programs: where a program is, whether a process
is alive, numba's kernels compiled before the programs start, a DDS domain of one's own.
"""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import sys
import sysconfig

PACKAGE = 'ament_formation'


def program_dirs() -> list[Path]:
    """Where :func:`program` looks, in order: the folders of ``PATH``; the running interpreter's
    scripts folder (where pip puts an environment's console scripts; scripts/setup.sh links the
    package's there); ``<prefix>/lib/ament_formation`` of every prefix of ``AMENT_PREFIX_PATH``
    (a sourced ``install/setup.bash``: where colcon build puts the console scripts and ``ros2 run``
    looks), and of the installation this process imported the package from.
    """
    dirs = [Path(d) for d in os.environ.get('PATH', '').split(os.pathsep) if d]
    dirs.append(Path(sysconfig.get_path('scripts')))
    dirs.append(Path(sys.executable).parent)
    prefixes = [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    try:
        from ament_formation.core.config_files import share_dir

        share = share_dir()
        if share is not None:
            prefixes.append(share.parents[1])
    except ImportError:  # pragma: no cover - the package is importable wherever tests run
        pass
    dirs.extend(prefix / 'lib' / PACKAGE for prefix in prefixes)
    unique = []
    for d in dirs:
        if d not in unique:
            unique.append(d)
    return unique


def program(name: str) -> str:
    """Absolute path of the program ``name`` (a console script of the package such as
    ``formation`` or ``formation_world``, or another tool such as ``dask``): the first executable
    file of that name in :func:`program_dirs`. The same lookup serves the project's own runs
    (scripts/test.sh puts its environment's bin/ first on PATH) and a ROS 2 workspace (the
    installed ``install/ament_formation/lib/ament_formation``), never a path into a ``.venv`` by
    name. Raises FileNotFoundError naming the folders it searched.
    """
    for d in program_dirs():
        path = d / name
        if path.is_file() and os.access(path, os.X_OK):
            return str(path)
    found = shutil.which(name)  # PATH entries that are not plain folders (e.g. relative ones)
    if found:
        return str(Path(found).resolve())
    raise FileNotFoundError(
        f'program {name!r} not found on PATH, beside {sys.executable} or in '
        f'<prefix>/lib/{PACKAGE} of AMENT_PREFIX_PATH; run scripts/setup.sh, or source a '
        "workspace's install/setup.bash after colcon build"
    )


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
    """A DDS domain id in 1..101 (ROS's safe range on Linux) that no other run on this machine
    holds and not in ``avoid``: (id, fd of its lock; close it to release the id), or None.

    The lock files of scripts/ros_env.sh (flock on ``<id>.lock``, released when the fd closes):
    concurrent runs in one domain see each other's nodes and topics.
    """
    import fcntl
    import random

    try:
        DOMAIN_LOCKS.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    first = random.randrange(101)
    for i in range(101):
        domain = (first + i) % 101 + 1
        if domain in avoid:
            continue
        fd = os.open(DOMAIN_LOCKS / f'{domain}.lock', os.O_CREAT | os.O_WRONLY | os.O_APPEND)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return domain, fd
        except OSError:
            os.close(fd)
    return None
