"""Locate files shipped with the package: its config/, docs/ and scripts/ folders.

From a source checkout (a clone, or the ``pip install -e`` of scripts/setup.sh's .venv, which
installs no data_files) they are the checkout's own folders next to the package. Installed by
``colcon build`` they are in ``<prefix>/share/ament_formation/`` (setup.py data_files): the share
folder of the installation this module was imported from, else the one the ament index names
(when ament_index_python is importable). ``config/params/<node>.yaml`` are the nodes' params files;
``scripts/`` holds the launchers (``scripts/launch_*.sh``), which `formation run` starts.
This module is ROS-free: ament_index_python is pure Python and optional.
"""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import sys

PACKAGE = 'ament_formation'
_PACKAGE_DIR = Path(__file__).resolve().parents[1]  # .../ament_formation (the Python package)


def source_root() -> Path | None:
    """The source checkout this module was imported from, or None (an installed copy).

    A checkout is recognised by its package.xml and setup.py next to the package, not by a
    ``config`` folder alone (an installed copy's site-packages may hold anything).
    """
    root = _PACKAGE_DIR.parent
    if (root / 'package.xml').is_file() and (root / 'setup.py').is_file():
        return root
    return None


def share_dir() -> Path | None:
    """``share/ament_formation`` of this installation (``<prefix>/lib/pythonX.Y/site-packages/
    ament_formation`` -> ``<prefix>/share/ament_formation``), else the ament index's, else None.
    """
    prefix = _PACKAGE_DIR.parents[3] if len(_PACKAGE_DIR.parents) > 3 else None
    if prefix is not None and (prefix / 'share' / PACKAGE / 'package.xml').is_file():
        return prefix / 'share' / PACKAGE
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(PACKAGE))
    except Exception:  # noqa: BLE001 - ament index absent or package not registered
        return None


def package_dir(name: str) -> Path:
    """The package's ``name`` folder (``config``, ``docs`` or ``scripts``): the source checkout's,
    else the installed ``share/ament_formation/<name>``. Raises FileNotFoundError naming it.
    """
    for base in (source_root(), share_dir()):
        if base is not None and (base / name).is_dir():
            return base / name
    raise FileNotFoundError(
        f'{name}/ of {PACKAGE} not found (neither a source checkout nor an installed share folder)'
    )


def config_dir() -> Path:
    """The package's config directory (source checkout first, then the installed share
    directory, then ``$AMENT_FORMATION_CONFIG_DIR``).
    """
    try:
        return package_dir('config')
    except FileNotFoundError:
        pass
    env = os.environ.get('AMENT_FORMATION_CONFIG_DIR')
    if env and Path(env).is_dir():
        return Path(env)
    raise FileNotFoundError(
        'config/ of ament_formation not found (set AMENT_FORMATION_CONFIG_DIR)'
    )


def params_file(node: str) -> Path:
    """The params file of node ``node`` (``config/params/<node>.yaml``: ``/**/<node>:
    ros__parameters:`` with every parameter and its default), for ``--ros-args --params-file``.
    """
    return config_file(f'params/{node}.yaml')


def config_file(relative: str) -> Path:
    """Path of ``config/<relative>``; raises FileNotFoundError naming it when absent."""
    path = config_dir() / relative
    if not path.exists():
        raise FileNotFoundError(f'{path}: no such config file')
    return path


def script_file(name: str) -> Path:
    """Path of ``scripts/<name>`` (a launcher); raises FileNotFoundError naming it when absent."""
    path = package_dir('scripts') / name
    if not path.exists():
        raise FileNotFoundError(f'{path}: no such script')
    return path


def docs_file(name: str) -> Path:
    """Path of ``docs/<name>`` (it need not exist yet: a generator writes it)."""
    return package_dir('docs') / name


def program_file(name: str) -> str:
    """The console script ``name`` of this package (``formation_world``, ...): beside this
    interpreter (a venv's bin/: scripts/setup.sh links them there), else the installed
    ``<prefix>/lib/ament_formation/<name>`` (where colcon build puts them and ``ros2 run`` looks),
    else ``name`` as found on PATH.
    """
    here = Path(sys.executable).parent / name
    if here.exists():
        return str(here)
    share = share_dir()
    if share is not None:
        installed = share.parents[1] / 'lib' / PACKAGE / name
        if installed.exists():
            return str(installed)
    return shutil.which(name) or name
