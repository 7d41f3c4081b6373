"""Locate files shipped in the package's config/ folder.

Installed with colcon, config lives in ``share/ament_formation/config`` (found through the ament
index when it is importable); ``config/params/<node>.yaml`` are the nodes' params files. With ``pip
install -e`` (the .venv of scripts/setup.sh) data_files
are not installed, so the fallback is the source tree's ``config/`` next to the package.
This module is ROS-free: ament_index_python is pure Python and optional.
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE = 'ament_formation'


def config_dir() -> Path:
    """The package's config directory (source checkout first, then the ament share directory)."""
    source = Path(__file__).resolve().parents[2] / 'config'
    if source.is_dir():
        return source
    try:
        from ament_index_python.packages import get_package_share_directory

        share = Path(get_package_share_directory(PACKAGE)) / 'config'
        if share.is_dir():
            return share
    except Exception:  # noqa: BLE001 - ament index absent or package not registered
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
