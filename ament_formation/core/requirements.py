"""The Python libraries the programs need, with the lowest versions they work with, and the one
line a program says at start when one is missing or too old (what to install).

package.xml declares the same minimums (``version_gte``) for rosdep; requirements.txt pins the
versions the project's own set-up tests. The lowest versions are the ones tested (docs/package.md
"Versions"): NumPy 1.26 (Ubuntu 24.04's python3-numpy, ROS 2 Jazzy's tier-1 platform) with the
pinned numba, and OpenCV 4.6 (Ubuntu 24.04's and Debian 12's python3-opencv).
ROS-free and pure: :func:`problems` returns the lines, the programs' entry points print them
(ament_formation/tools/entry.py).
"""

from __future__ import annotations

from dataclasses import dataclass
import importlib
import re
from typing import Callable


@dataclass(frozen=True)
class Requirement:
    """A library the programs import: ``module`` (import name), the lowest ``minimum`` version
    that works, the Debian/Ubuntu package (``apt``, also package.xml's rosdep key) and the PyPI
    name (``pip``) that provide it.
    """

    label: str
    module: str
    minimum: tuple[int, ...]
    apt: str
    pip: str

    def __post_init__(self):
        if not self.minimum or any(int(p) < 0 for p in self.minimum):
            raise ValueError(f'{self.label}: minimum: expected a version, got {self.minimum!r}')

    @property
    def minimum_text(self) -> str:
        return '.'.join(map(str, self.minimum))

    def how_to_install(self) -> str:
        return (
            f'install {self.apt} (>= {self.minimum_text}) or '
            f"pip install '{self.pip}>={self.minimum_text}' (docs/package.md)"
        )


NUMPY = Requirement('NumPy', 'numpy', (1, 26), 'python3-numpy', 'numpy')
NUMBA = Requirement('numba', 'numba', (0, 68), 'python3-numba', 'numba')
OPENCV = Requirement('OpenCV', 'cv2', (4, 6), 'python3-opencv', 'opencv-python-headless')
YAML = Requirement('PyYAML', 'yaml', (6, 0), 'python3-yaml', 'PyYAML')
SERIAL = Requirement('pyserial', 'serial', (3, 5), 'python3-serial', 'pyserial')

# what every program needs: the core (NumPy, numba's kernels) and its YAML files
REQUIRED = (NUMPY, NUMBA, YAML)


def parse_version(text: str) -> tuple[int, ...] | None:
    """The leading release numbers of a version string ('1.26.4' -> (1, 26, 4), '4.6.0-dev' ->
    (4, 6, 0), '0.68.1+dfsg' -> (0, 68, 1)), or None when it does not start with a number.
    """
    m = re.match(r'\s*v?(\d+(?:\.\d+)*)', str(text))
    if m is None:
        return None
    return tuple(int(p) for p in m.group(1).split('.'))


def problem(req: Requirement, importer: Callable = importlib.import_module) -> str | None:
    """None when ``req`` imports at ``minimum`` or later, else one line saying what is wrong and
    what to install. An import that fails for another reason (numba refusing the installed NumPy,
    a broken binary, a library that raises on import) is reported with its own message.
    """
    try:
        module = importer(req.module)
    except Exception as err:  # noqa: BLE001 - any failure to import is this line, not a traceback
        missing = isinstance(err, ModuleNotFoundError) and err.name == req.module
        if missing:
            return (
                f'needs {req.label} >= {req.minimum_text}, not installed: '
                f'{req.how_to_install()}'
            )
        reason = ' '.join(str(err).split())
        return (
            f'needs {req.label} >= {req.minimum_text}, which fails to import ({reason}): '
            f'{req.how_to_install()}'
        )
    found = getattr(module, '__version__', None)
    version = parse_version(found) if found is not None else None
    if version is None:
        return None  # no version to compare (a vendor build): trust it
    if version < req.minimum:
        return (
            f'needs {req.label} >= {req.minimum_text}, found {found}: {req.how_to_install()}'
        )
    return None


def problems(
    reqs: tuple[Requirement, ...] = REQUIRED, importer: Callable = importlib.import_module
) -> list[str]:
    """[the line of :func:`problem`] for the first requirement not met, in order, or [] when all
    are met: a later library may need an earlier one (numba needs NumPy), so its import is not
    tried once an earlier one failed.
    """
    for req in reqs:
        line = problem(req, importer)
        if line is not None:
            return [line]
    return []
