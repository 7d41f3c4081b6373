"""ament_formation: sliding-mode formation control with elliptical limit-cycle avoidance (ROS 2
Jazzy).
"""

__version__ = '0.1.0'

# numba's compiled kernels go to a folder keyed by a hash of the core's sources, set before
# anything imports numba (core/jit_cache.py): an edit of any core module recompiles, no manual
# step.
from ament_formation.core import jit_cache as _jit_cache  # noqa: E402

_jit_cache.configure()
