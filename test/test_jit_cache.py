"""numba's cache folder is keyed by the core's sources (core/jit_cache.py): an edit anywhere in the
core gives a new folder, old folders are pruned, a user's NUMBA_CACHE_DIR is left alone, and every
process of the package (here: a fresh interpreter) uses that folder.
"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys
import time

import pytest

from ament_formation.core import jit_cache

ROOT = Path(__file__).resolve().parents[1]


def _core_copy(tmp_path: Path) -> Path:
    core = tmp_path / 'core'
    (core / 'sub').mkdir(parents=True)
    (core / 'kernels.py').write_text(
        'from numba import njit\n'
        'from ament_formation.core.sub.geometry import f\n'
        'from ament_formation.core import (\n    consts,\n)\n'
    )
    (core / 'sub' / '__init__.py').write_text('')
    (core / 'sub' / 'geometry.py').write_text(
        'import ament_formation.core.deep\n\ndef f():\n    return 2\n'
    )
    (core / 'deep.py').write_text('Y = 1\n')
    (core / 'consts.py').write_text('X = 1\n')
    (core / 'scenario.py').write_text('import yaml\n')  # no numba, not imported by numba code
    (core / 'notes.txt').write_text('not a source')
    return core


def test_numba_sources_are_the_numba_modules_and_what_they_import(tmp_path):
    core = _core_copy(tmp_path)
    names = [str(p.relative_to(core)) for p in jit_cache.numba_sources(core)]
    assert names == ['consts.py', 'deep.py', 'kernels.py', 'sub/geometry.py']
    shipped = {p.name for p in jit_cache.numba_sources()}
    assert {
        'smc.py',
        'limit_cycle.py',
        'dynamics.py',
        'ellipse.py',
        'switching.py',
        'arbitration.py',
        'law.py',
        'agent.py',
        'simulator.py',
        'twin.py',
        'params.py',
    } <= shipped
    assert 'jit_cache.py' not in shipped and 'loader.py' not in shipped


def test_hash_changes_with_any_source_numba_code_can_reach_and_only_with_those(tmp_path):
    core = _core_copy(tmp_path)
    h0 = jit_cache.source_hash(core)
    assert h0 == jit_cache.source_hash(core)  # deterministic
    (core / 'notes.txt').write_text('edited')
    (core / 'scenario.py').write_text('import yaml  # edited\n')
    assert jit_cache.source_hash(core) == h0  # nothing compiled code can see
    (core / 'deep.py').write_text('Y = 2\n')  # a constant two imports away
    h1 = jit_cache.source_hash(core)
    (core / 'consts.py').write_text('X = 2\n')  # a module imported in parentheses
    h2 = jit_cache.source_hash(core)
    (core / 'scenario.py').write_text('from numba import njit\n')  # becomes numba code
    h3 = jit_cache.source_hash(core)
    assert len({h0, h1, h2, h3}) == 4


def test_configure_sets_a_hashed_folder_and_prunes_old_ones(tmp_path):
    root = tmp_path / 'cache'
    old = []
    for k in range(4):
        p = root / f'numba-old{k}'
        p.mkdir(parents=True)
        os.utime(p, (1000.0 + k, 1000.0 + k))  # old3 is the most recently used
        old.append(p)
    (root / 'unrelated').mkdir()
    env = {'AMENT_FORMATION_CACHE_DIR': str(root)}
    path = jit_cache.configure(env)
    assert path == root / f'numba-{jit_cache.source_hash()}' and path.is_dir()
    assert env['NUMBA_CACHE_DIR'] == str(path)
    kept = sorted(p.name for p in root.glob('numba-*'))
    assert kept == sorted([path.name, 'numba-old3', 'numba-old2'])  # KEEP = 3 folders in all
    assert (root / 'unrelated').is_dir()
    # a second process finds the folder, marks it used, prunes nothing, and keeps the setting
    os.utime(path, (1000.0, 1000.0))
    assert jit_cache.configure(env) == path
    assert path.stat().st_mtime > time.time() - 60
    assert sorted(p.name for p in root.glob('numba-*')) == kept


def test_a_users_numba_cache_dir_is_left_alone(tmp_path):
    env = {
        'NUMBA_CACHE_DIR': str(tmp_path / 'mine'),
        'AMENT_FORMATION_CACHE_DIR': str(tmp_path / 'c'),
    }
    assert jit_cache.configure(env) is None
    assert env['NUMBA_CACHE_DIR'] == str(tmp_path / 'mine') and not (tmp_path / 'c').exists()


def test_an_unwritable_root_leaves_numbas_default(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('')
    env = {'AMENT_FORMATION_CACHE_DIR': str(blocker / 'cache')}  # below a regular file
    assert jit_cache.configure(env) is None and 'NUMBA_CACHE_DIR' not in env


def test_a_process_importing_the_package_uses_the_hashed_folder(tmp_path):
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ('NUMBA_CACHE_DIR', 'AMENT_FORMATION_NUMBA_CACHE_DIR')
    }
    env['AMENT_FORMATION_CACHE_DIR'] = str(tmp_path / 'cache')
    code = (
        'import ament_formation, numba.core.config as c, os; '
        "print(c.CACHE_DIR); print(os.environ['NUMBA_CACHE_DIR'])"
    )
    out = subprocess.run(
        [sys.executable, '-c', code],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=True,
    ).stdout.split()
    want = str(tmp_path / 'cache' / f'numba-{jit_cache.source_hash()}')
    assert out == [want, want]


def test_the_warm_parts_are_checked_and_a_bad_part_is_one_line(capsys):
    """setup.sh's warm runs the two parts in parallel processes (``--part``); a wrong name is
    refused with status 2 and one line, before anything compiles.
    """
    from ament_formation.core.sim import jit_warm

    assert jit_warm.PARTS == ('closed_loop', 'rest')
    assert jit_warm.main(['--part', 'everything']) == 2
    assert jit_warm.main(['--part']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ['jit_warm: --part needs one of closed_loop, rest'] * 2
    with pytest.raises(ValueError, match='unknown part'):
        jit_warm.warm('everything')
