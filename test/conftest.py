"""Test-wide setup: DDS stays on loopback, each run has its own domain and log folder.

The environment is set here, before any test module imports rclpy, so that running
``pytest`` directly (without scripts/test.sh) is just as contained.
"""

from __future__ import annotations

import atexit
import os
from pathlib import Path
import shutil
import tempfile

from processes import take_free_domain
import pytest

_ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
# the default of scripts/ros_env.sh and `formation run` (shared memory, 4 MB segments)
os.environ.setdefault(
    'FASTRTPS_DEFAULT_PROFILES_FILE', str(_ROOT / 'config' / 'fastdds_localhost_shm.xml')
)
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
# the real-robot launchers refuse their lab-network default under it (scripts/launch_common.sh):
# a test that forgets --loopback fails instead of leaving loopback (the multi-host tests drop it
# inside the network namespaces they make)
os.environ['AMENT_FORMATION_LOOPBACK_ONLY'] = '1'
os.environ.setdefault('ROS_DOMAIN_ID', str(os.getpid() % 101 + 1))  # ROS's safe range: 0..101
if 'ROS_LOG_DIR' not in os.environ:  # pytest run directly: a log folder removed at exit
    os.environ['ROS_LOG_DIR'] = tempfile.mkdtemp(prefix='ament_formation_ros_log_')
    atexit.register(shutil.rmtree, os.environ['ROS_LOG_DIR'], ignore_errors=True)

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
    the core changed since scripts/setup.sh did it: not in every started process at once. Under
    colcon test, for the installed copy the programs run as well (processes.warm_numba_kernels).
    """
    from processes import warm_numba_kernels

    warm_numba_kernels(timeout_s=900.0)


@pytest.fixture(scope='module', autouse=True)
def _module_dds_domain():
    """Each test module on a DDS domain of its own, and the Fast DDS shared memory its processes
    left (a killed process leaves its port segments and, possibly locked, port mutexes) removed
    once no live process uses it: a later module never meets a dead participant's segments.

    With the rules of ``formation run`` (ros/shm.py): an entry goes only when no live process
    maps or holds open any entry of its group. The other worker's run is live meanwhile, and its
    participants' liveness files (``_el``, only held open) and port mutexes (neither mapped nor
    open between uses) appeared since this module began too: removing them by "not mapped"
    alone, as this fixture once did, made Fast DDS take that run's participants for dead and
    stop delivering to them for good (docs/executors.md, "The stall found").
    """
    from ament_formation.ros import shm

    session_domain = os.environ['ROS_DOMAIN_ID']
    taken = take_free_domain(avoid=(int(session_domain),))
    if taken is not None:
        os.environ['ROS_DOMAIN_ID'] = str(taken[0])
    before = shm.snapshot()
    try:
        yield
    finally:
        os.environ['ROS_DOMAIN_ID'] = session_domain
        shm.cleanup(before)
        if taken is not None:
            os.close(taken[1])


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


# whole systems of processes timed by the wall clock (a control loop's gaps, a launch's start
# within a minute): scripts/test.sh runs them after the rest, one at a time (marker ``alone``)
ALONE_MODULES = frozenset({
    'test_board_check', 'test_launch_deploy', 'test_launch_multi_machine', 'test_launch_sim',
    'test_live_view', 'test_multihost', 'test_params_files', 'test_programs', 'test_readme_lab',
    'test_system', 'test_tracker_source',
})


def pytest_collection_modifyitems(config, items):
    for item in items:
        module = getattr(item, 'module', None)
        if module is not None and module.__name__.rpartition('.')[2] in ALONE_MODULES:
            item.add_marker(pytest.mark.alone)
