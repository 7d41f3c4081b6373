"""Lint: the package's Python sources pass flake8 with ament_flake8's configuration.

The standard ament_python lint test: ``ament_flake8`` when it is installed (a ROS 2 Jazzy
install), else plain flake8 (``python -m flake8`` with the interpreter running the tests) with the
same configuration (setup.cfg ``[flake8]``: ament's extend-ignore list, max-line-length 99, google
import order, single quotes) and the plugins pinned in requirements.txt. Neither importable is a
failure, not a skip: both are declared test dependencies.

scripts/lint_fix.sh does the mechanical part of a fix (quotes, formatting, import order).
"""

import importlib.util
from pathlib import Path
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.flake8
@pytest.mark.linter
@pytest.mark.timeout(900)
def test_flake8(monkeypatch):
    try:
        from ament_flake8.main import main_with_errors
    except ImportError:
        main_with_errors = None
    if main_with_errors is not None:
        # setup.cfg [flake8] is ament_flake8.ini plus the folders that are not package sources
        monkeypatch.chdir(ROOT)
        rc, errors = main_with_errors(argv=['--config', str(ROOT / 'setup.cfg'), str(ROOT)])
        assert rc == 0, f'Found {len(errors)} code style errors / warnings:\n' + '\n'.join(
            errors[:50]
        )
        return
    # flake8 as a module of the interpreter running the tests (as ament_flake8 imports it): under
    # colcon test that interpreter is colcon's, whose bin/ (and PATH) has no flake8 script, while
    # flake8 and its plugins are importable there (package.xml test_depend, requirements.txt)
    if importlib.util.find_spec('flake8') is None:
        pytest.fail(
            f'neither ament_flake8 nor flake8 is importable by {sys.executable} (test '
            'dependencies: package.xml; requirements.txt pins flake8 and its plugins)'
        )
    proc = subprocess.run(
        [sys.executable, '-m', 'flake8', '--no-show-source', '--count', '--jobs', '2', '.'],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    lines = proc.stdout.strip().splitlines()
    assert proc.returncode == 0, (
        f'flake8 found {lines[-1] if lines else "?"} problems:\n' + '\n'.join(lines[:50])
    )
