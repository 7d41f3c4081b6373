"""Where numba keeps the compiled kernels (warming them once: core/sim/jit_warm.py).

numba's on-disk cache (``@njit(cache=True)``) keys a compiled function on its own source file
only: a change in another module it calls or whose constants it reads goes unnoticed, and the
stale machine code is loaded. So the package points numba at a folder named after a hash of the
core modules compiled code can depend on (:func:`numba_sources`: those importing numba and every
core module they import, transitively; :func:`configure`, called from ``ament_formation/__init__``
before anything imports numba): an edit of any of them gives a new, empty folder, and the kernels
are compiled afresh. Folders of older sources are pruned (the :data:`KEEP` most recently used
stay).

    $XDG_CACHE_HOME/ament_formation/numba-<hash>   (default ~/.cache/ament_formation/numba-<hash>)

A ``NUMBA_CACHE_DIR`` set by the user is left alone. ``AMENT_FORMATION_CACHE_DIR`` replaces the
``$XDG_CACHE_HOME/ament_formation`` root.

This module reads files and the environment only when called, and never prints.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
import re
import shutil
import sys

KEEP = 3  # numba-<hash> folders kept (most recently used first)
_MARK = 'AMENT_FORMATION_NUMBA_CACHE_DIR'  # what configure() set, to tell it from a user's choice
_CORE = Path(__file__).resolve().parent


_FROM = re.compile(r'^[ \t]*from[ \t]+([\w.]+)[ \t]+import[ \t]+(?:\(([^)]*)\)|([\w \t,]+))', re.M)
_IMPORT = re.compile(r'^[ \t]*import[ \t]+([\w.]+)', re.M)
_NUMBA = re.compile(r'^\s*(?:from\s+numba\b|import\s+numba\b)', re.M)


def numba_sources(core_dir: Path = _CORE) -> list[Path]:
    """The core modules compiled code can depend on: those that import numba and every core module
    they import, transitively (a jitted function reaches other modules' functions and constants
    only through its module's imports). This module itself is left out.
    """
    package = 'ament_formation.' + core_dir.name
    by_name: dict[str, Path] = {}
    for path in core_dir.rglob('*.py'):
        rel = path.relative_to(core_dir).with_suffix('')
        parts = rel.parts[:-1] if rel.name == '__init__' else rel.parts
        by_name['.'.join((package, *parts)).rstrip('.')] = path
    me = Path(__file__).resolve()
    todo = [
        p
        for p in by_name.values()
        if p.resolve() != me and _NUMBA.search(p.read_text(errors='replace'))
    ]
    seen: set[Path] = set()
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        text = path.read_text(errors='replace')
        candidates = _IMPORT.findall(text)
        for base, grouped, names in _FROM.findall(text):
            candidates.append(base)
            candidates += [
                f'{base}.{n.split()[0]}' for n in (grouped or names).split(',') if n.split()
            ]
        todo += [by_name[c] for c in candidates if c in by_name and by_name[c].resolve() != me]
    return sorted(seen)


def source_hash(core_dir: Path = _CORE) -> str:
    """sha256 (first 16 hex digits) over the relative paths and contents of
    :func:`numba_sources`.
    """
    h = hashlib.sha256()
    for path in numba_sources(core_dir):
        h.update(str(path.relative_to(core_dir)).encode())
        h.update(b'\0')
        h.update(path.read_bytes())
        h.update(b'\0')
    return h.hexdigest()[:16]


def cache_root(environ=os.environ) -> Path:
    """``$AMENT_FORMATION_CACHE_DIR``, else ``$XDG_CACHE_HOME/ament_formation`` (~/.cache/...)."""
    if environ.get('AMENT_FORMATION_CACHE_DIR'):
        return Path(environ['AMENT_FORMATION_CACHE_DIR'])
    xdg = environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(xdg) / 'ament_formation'


def prune(root: Path, keep_dir: Path, keep: int = KEEP) -> list[Path]:
    """Remove ``root/numba-*`` folders but ``keep_dir`` and the ``keep - 1`` most recently used
    others; return the removed ones. A process still using a removed folder recreates it when it
    saves (numba makes the directory again) or recompiles: nothing breaks.
    """
    others = [p for p in root.glob('numba-*') if p.is_dir() and p != keep_dir]
    others.sort(key=lambda p: p.stat().st_mtime, reverse=True)
    removed = []
    for p in others[max(keep - 1, 0):]:
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed


def configure(environ=os.environ) -> Path | None:
    """Point numba's cache at ``cache_root()/numba-<source_hash()>`` (made if missing, older
    folders pruned, marked used). Returns the folder, or None when the user set NUMBA_CACHE_DIR or
    no folder can be made (numba then keeps its default, next to the sources).
    """
    user = environ.get('NUMBA_CACHE_DIR')
    if user and environ.get(_MARK) != user:
        return None
    try:
        root = cache_root(environ)
        path = root / f'numba-{source_hash()}'
        if not path.is_dir():
            path.mkdir(parents=True, exist_ok=True)
            prune(root, path)
        else:
            os.utime(path)  # "recently used", for prune()
    except OSError:
        return None
    environ['NUMBA_CACHE_DIR'] = environ[_MARK] = str(path)
    config = sys.modules.get('numba.core.config')
    if config is not None:  # numba already imported: its config read the env already
        config.CACHE_DIR = str(path)
    return path


def _warm_stamp() -> Path | None:
    """File marking the current cache folder warm for this source tree (None: not configured)."""
    cache = os.environ.get('NUMBA_CACHE_DIR')
    if not cache:
        return None
    tree = hashlib.sha1(str(_CORE).encode()).hexdigest()[:12]
    return Path(cache) / f'warm-{tree}'


def is_warm() -> bool:
    stamp = _warm_stamp()
    return stamp is not None and stamp.exists()
