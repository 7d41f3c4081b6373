"""Another OpenCV for the tests: OpenCV 4.6 (what Debian 12 and Ubuntu 24.04 ship as
python3-opencv) installed with ``pip install --target`` into a cache folder, put in front of the
venv's packages through PYTHONPATH in a subprocess. NumPy 1.26 comes with it (the 4.6 wheels are
built for NumPy 1.x; also what those platforms ship).

Used by test/test_opencv_versions.py and bench/bench_opencv46.py. Not a test module itself.

- ``overlay(contrib=True)``: the folder (installed on first use, then reused offline), or None
  when pip cannot install it (no network and no cached wheel).
- ``env(folder)``: the environment of a subprocess that imports that OpenCV.
"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys

OPENCV_46 = '4.6.0.66'
NUMPY_FOR_46 = '1.26.4'


def cache_dir() -> Path:
    base = os.environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(base) / 'ament_formation'


def overlay(contrib: bool = True, timeout_s: float = 600.0) -> Path | None:
    """``opencv-contrib-python-headless`` (with cv2.aruco) or ``opencv-python-headless`` (without:
    4.6 had ArUco only in contrib) 4.6.0.66 and numpy 1.26.4 in a cache folder; None if pip
    cannot install them.
    """
    name = 'opencv-contrib-python-headless' if contrib else 'opencv-python-headless'
    folder = cache_dir() / f'{name}-{OPENCV_46}'
    done = folder / '.installed'
    if done.exists():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    try:
        res = subprocess.run(
            [sys.executable, '-m', 'pip', 'install', '--quiet', '--no-deps', '--upgrade',
             '--target', str(folder), f'{name}=={OPENCV_46}', f'numpy=={NUMPY_FOR_46}'],
            capture_output=True, text=True, timeout=timeout_s,
        )
    except subprocess.TimeoutExpired:
        return None
    if res.returncode != 0:
        return None
    done.write_text(f'{name}=={OPENCV_46} numpy=={NUMPY_FOR_46}\n')
    return folder


def env(folder: Path) -> dict[str, str]:
    """os.environ with ``folder`` first on PYTHONPATH (its cv2 and numpy win)."""
    out = dict(os.environ)
    out['PYTHONPATH'] = os.pathsep.join(
        [str(folder)] + [p for p in out.get('PYTHONPATH', '').split(os.pathsep) if p]
    )
    return out
