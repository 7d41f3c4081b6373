"""Compare two ``metrics.json`` files of ``formation sim``: every number to a relative tolerance
(default 1e-9; absolute 1e-15 near zero) and the mode/graph event lists exactly (times to the
same tolerance). Keys that measure the machine, not the run (``wall_time_s`` ...), are skipped.

Run: .venv/bin/python bench/compare_metrics.py BEFORE/metrics.json AFTER/metrics.json [--rtol R]
Exit 0 when identical, 1 with one line per difference otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

SKIP = {'wall_time_s', 'wall_s', 'real_time_factor'}


def differences(a, b, rtol: float = 1e-9, path: str = '') -> list[str]:
    """Every place where ``a`` and ``b`` (parsed JSON) differ, as 'path: a != b' lines."""
    if isinstance(a, bool) or isinstance(b, bool) or a is None or b is None:
        return [] if a == b else [f'{path}: {a!r} != {b!r}']
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        if math.isnan(a) and math.isnan(b) or a == b:
            return []
        if abs(a - b) <= max(rtol * max(abs(a), abs(b)), 1e-15):
            return []
        return [f'{path}: {a!r} != {b!r}']
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k in SKIP:
                continue
            if k not in a or k not in b:
                out.append(f'{path}/{k}: only in {"after" if k in b else "before"}')
                continue
            out += differences(a[k], b[k], rtol, f'{path}/{k}')
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f'{path}: {len(a)} items != {len(b)} items']
        out = []
        for q, (x, y) in enumerate(zip(a, b)):
            out += differences(x, y, rtol, f'{path}[{q}]')
        return out
    return [] if a == b else [f'{path}: {a!r} != {b!r}']


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('before')
    ap.add_argument('after')
    ap.add_argument('--rtol', type=float, default=1e-9)
    args = ap.parse_args(argv)
    with open(args.before) as f:
        a = json.load(f)
    with open(args.after) as f:
        b = json.load(f)
    diff = differences(a, b, args.rtol)
    for line in diff:
        print(line)
    n_ev = len(a.get('mode_events', [])), len(a.get('graph_events', []))
    print(
        f'compare: {"identical" if not diff else f"{len(diff)} differences"} '
        f'(rtol {args.rtol:g}; {n_ev[0]} mode events, {n_ev[1]} graph events)'
    )
    return 1 if diff else 0


if __name__ == '__main__':
    sys.exit(main())
