"""numba's cache folder is keyed by the core's sources (core/jit_cache.py): an edit anywhere in the
core gives a new folder, old folders are pruned, a user's NUMBA_CACHE_DIR is left alone, and every
process of the package (here: a fresh interpreter) uses that folder."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from ament_formation.core import jit_cache

ROOT = Path(__file__).resolve().parents[1]


def _core_copy(tmp_path: Path) -> Path:
    core = tmp_path / "core"
    (core / "sub").mkdir(parents=True)
    (core / "kernels.py").write_text("X = 1\n")
    (core / "sub" / "geometry.py").write_text("def f():\n    return 2\n")
    (core / "notes.txt").write_text("not a source")
    return core


def test_hash_changes_with_any_core_source_and_only_with_sources(tmp_path):
    core = _core_copy(tmp_path)
    h0 = jit_cache.source_hash(core)
    assert h0 == jit_cache.source_hash(core)                  # deterministic
    (core / "notes.txt").write_text("edited")
    assert jit_cache.source_hash(core) == h0                   # not a .py file
    (core / "sub" / "geometry.py").write_text("def f():\n    return 3\n")   # a module numba code calls
    h1 = jit_cache.source_hash(core)
    assert h1 != h0
    (core / "extra.py").write_text("")                         # a new module
    h2 = jit_cache.source_hash(core)
    assert len({h0, h1, h2}) == 3
    (core / "extra.py").rename(core / "extra2.py")             # same bytes, other name
    assert jit_cache.source_hash(core) != h2


def test_configure_sets_a_hashed_folder_and_prunes_old_ones(tmp_path):
    root = tmp_path / "cache"
    old = []
    for k in range(4):
        p = root / f"numba-old{k}"
        p.mkdir(parents=True)
        os.utime(p, (1000.0 + k, 1000.0 + k))                 # old3 is the most recently used
        old.append(p)
    (root / "unrelated").mkdir()
    env = {"AMENT_FORMATION_CACHE_DIR": str(root)}
    path = jit_cache.configure(env)
    assert path == root / f"numba-{jit_cache.source_hash()}" and path.is_dir()
    assert env["NUMBA_CACHE_DIR"] == str(path)
    kept = sorted(p.name for p in root.glob("numba-*"))
    assert kept == sorted([path.name, "numba-old3", "numba-old2"])   # KEEP = 3 folders in all
    assert (root / "unrelated").is_dir()
    # a second process finds the folder, marks it used, prunes nothing, and keeps the setting
    os.utime(path, (1000.0, 1000.0))
    assert jit_cache.configure(env) == path
    assert path.stat().st_mtime > time.time() - 60
    assert sorted(p.name for p in root.glob("numba-*")) == kept


def test_a_users_numba_cache_dir_is_left_alone(tmp_path):
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "mine"), "AMENT_FORMATION_CACHE_DIR": str(tmp_path / "c")}
    assert jit_cache.configure(env) is None
    assert env["NUMBA_CACHE_DIR"] == str(tmp_path / "mine") and not (tmp_path / "c").exists()


def test_an_unwritable_root_leaves_numbas_default(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    env = {"AMENT_FORMATION_CACHE_DIR": str(blocker / "cache")}   # below a regular file
    assert jit_cache.configure(env) is None and "NUMBA_CACHE_DIR" not in env


def test_a_process_importing_the_package_uses_the_hashed_folder(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "AMENT_FORMATION_NUMBA_CACHE_DIR")}
    env["AMENT_FORMATION_CACHE_DIR"] = str(tmp_path / "cache")
    code = ("import ament_formation, numba.core.config as c, os; "
            "print(c.CACHE_DIR); print(os.environ['NUMBA_CACHE_DIR'])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         timeout=120, check=True).stdout.split()
    want = str(tmp_path / "cache" / f"numba-{jit_cache.source_hash()}")
    assert out == [want, want]
