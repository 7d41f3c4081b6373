"""Test-wide setup: DDS stays on loopback, each run has its own domain and log folder.

The environment is set here, before any test module imports rclpy, so that running
``pytest`` directly (without scripts/test.sh) is just as contained.
"""

from __future__ import annotations

import os
from pathlib import Path
import tempfile

import pytest

_ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault(
    'FASTRTPS_DEFAULT_PROFILES_FILE', str(_ROOT / 'config' / 'fastdds_localhost.xml')
)
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
os.environ.setdefault('ROS_DOMAIN_ID', str(os.getpid() % 200 + 1))
if 'ROS_LOG_DIR' not in os.environ:
    os.environ['ROS_LOG_DIR'] = tempfile.mkdtemp(prefix='ament_formation_ros_log_')

# CI runs (CI=true) draw the same hypothesis examples every time, so a red CI run is reproducible;
# local runs keep exploring new examples.
try:
    from hypothesis import settings as _hyp_settings

    _hyp_settings.register_profile('ci', derandomize=True, print_blob=True)
    if os.environ.get('CI'):
        _hyp_settings.load_profile('ci')
except ImportError:  # pragma: no cover - hypothesis is pinned in requirements.txt
    pass


@pytest.fixture(scope='session', autouse=True)
def _numba_kernels_compiled_once():
    """Numba's kernels compiled once (core/jit_cache.py), before any test starts processes, if
    the core changed since scripts/setup.sh did it: not in every started process at once.
    """
    import subprocess
    import sys

    subprocess.run(
        [sys.executable, '-c', 'from ament_formation.core.jit_cache import main; main()'],
        check=False,
        timeout=900,
    )


@pytest.fixture
def ros_context():
    """A private rclpy Context on this run's domain; shut down after the test."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(os.environ['ROS_DOMAIN_ID']))
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.fixture
def executor(ros_context):
    """A single-threaded executor bound to the private context."""
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=ros_context)
    try:
        yield ex
    finally:
        ex.shutdown(timeout_sec=1.0)
