"""The libraries' lowest versions (core/requirements.py): the one line a program says at start when
one is missing or too old, the same minimums in package.xml, and a real console script refusing.
"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import types
import xml.etree.ElementTree as ET

from processes import program
import pytest

from ament_formation.core import requirements as req
from ament_formation.tools import entry

ROOT = Path(__file__).resolve().parents[1]


def _importer(**modules):
    """An import function that returns fake modules (a version string) or raises (an exception)."""

    def load(name):
        got = modules.get(name)
        if isinstance(got, BaseException):
            raise got
        if got is None:
            raise ModuleNotFoundError(f'No module named {name!r}', name=name)
        return types.SimpleNamespace(__version__=got)

    return load


@pytest.mark.parametrize(
    ('text', 'version'),
    [
        ('1.26.4', (1, 26, 4)),
        ('4.6.0', (4, 6, 0)),
        ('0.68.1+dfsg', (0, 68, 1)),
        ('2.0.0rc1', (2, 0, 0)),
        ('4.10.0-dev', (4, 10, 0)),
        ('unknown', None),
    ],
)
def test_versions_are_parsed_by_their_release_numbers(text, version):
    assert req.parse_version(text) == version


def test_met_requirements_give_no_line():
    load = _importer(numpy='1.26.4', numba='0.68.1', yaml='6.0.1', cv2='4.6.0', serial='3.5')
    assert req.problems(req.REQUIRED + (req.OPENCV, req.SERIAL), load) == []
    assert req.problems(req.REQUIRED, _importer(numpy='2.4.6', numba='0.68.0', yaml='6.0')) == []


def test_too_old_names_found_version_and_what_to_install():
    lines = req.problems(req.REQUIRED, _importer(numpy='1.24.2', numba='0.68.1', yaml='6.0.1'))
    assert lines == [
        'needs NumPy >= 1.26, found 1.24.2: install python3-numpy (>= 1.26) or '
        "pip install 'numpy>=1.26' (docs/package.md)"
    ]
    (line,) = req.problems((req.OPENCV,), _importer(cv2='4.5.4'))
    assert 'needs OpenCV >= 4.6, found 4.5.4' in line and 'python3-opencv' in line
    assert "'opencv-python-headless>=4.6'" in line


def test_missing_and_broken_imports_are_one_line():
    (missing,) = req.problems((req.NUMBA,), _importer())
    assert missing.startswith('needs numba >= 0.68, not installed: install python3-numba')
    broken = ImportError('Numba needs NumPy 1.22 or greater.\n  Got NumPy 1.21.')
    (line,) = req.problems((req.NUMBA,), _importer(numba=broken))
    assert 'fails to import (Numba needs NumPy 1.22 or greater. Got NumPy 1.21.)' in line
    assert '\n' not in line and '\n' not in missing
    # a dependency of the module missing is that dependency's failure, not "not installed"
    dep = ModuleNotFoundError("No module named 'llvmlite'", name='llvmlite')
    (line,) = req.problems((req.NUMBA,), _importer(numba=dep))
    assert 'fails to import' in line and 'llvmlite' in line


def test_this_environment_meets_every_requirement():
    every = req.REQUIRED + tuple(x for _m, extra in entry.PROGRAMS.values() for x in extra)
    assert req.problems(every) == []


def test_package_xml_declares_the_same_minimums():
    """Package.xml's version_gte (rosdep's view) and the programs' check agree."""
    deps = {
        e.text.strip(): e.get('version_gte')
        for e in ET.parse(ROOT / 'package.xml').getroot()
        if e.tag in ('depend', 'exec_depend')
    }
    for r in (req.NUMPY, req.NUMBA, req.YAML, req.OPENCV, req.SERIAL):
        assert deps.get(r.apt) == r.minimum_text, r.apt


def test_a_program_refuses_a_too_old_numpy_in_one_line(tmp_path):
    """The real console script, with a NumPy 1.24.2 first on its path: exit 1, one line."""
    fake = tmp_path / 'numpy'
    fake.mkdir()
    (fake / '__init__.py').write_text("__version__ = '1.24.2'\n")
    path = os.pathsep.join([str(tmp_path), os.environ.get('PYTHONPATH', '')])
    env = dict(os.environ, PYTHONPATH=path)
    for name in ('formation', 'formation_controller'):
        out = subprocess.run(
            [program(name), '--help'], env=env, capture_output=True, text=True, timeout=120
        )
        assert out.returncode == 1, out
        assert out.stdout == ''
        assert out.stderr.splitlines() == [
            f'{name}: needs NumPy >= 1.26, found 1.24.2: install python3-numpy (>= 1.26) or '
            "pip install 'numpy>=1.26' (docs/package.md)"
        ]
