"""Shape of the code (issue 12): no function longer than MAX_LINES lines, no compiled (numba)
function with more than MAX_JIT_PARAMS parameters.

A ratchet: the functions over the limits when the check was introduced are listed in ``KNOWN`` with
their size then; they may only shrink (and leave the list when under the limits), and no other
function may cross a limit. The issue's target is an empty ``KNOWN``.
"""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / 'ament_formation'
MAX_LINES = 120
MAX_JIT_PARAMS = 15

# 'path:function' -> (lines, parameters) when the check was introduced; empty since issue 12
KNOWN: dict[str, tuple[int, int]] = {}


def shapes(root: Path = PKG) -> dict[str, tuple[int, int, bool]]:
    """'path:function' -> (lines, parameters, compiled) of every function in the package."""
    out = {}
    for path in sorted(root.rglob('*.py')):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                decorators = [ast.unparse(d) for d in node.decorator_list]
                jit = any('njit' in d or 'jit(' in d for d in decorators)
                key = f'{path.relative_to(root).as_posix()}:{node.name}'
                size = (node.end_lineno - node.lineno + 1, len(node.args.args), jit)
                out[key] = max(out.get(key, size), size)
    return out


def test_no_long_function_and_no_wide_compiled_function_beyond_the_ratchet():
    over = {}
    for key, (lines, params, jit) in shapes().items():
        if lines > MAX_LINES or (jit and params > MAX_JIT_PARAMS):
            over[key] = (lines, params)
    new = sorted(set(over) - set(KNOWN))
    assert not new, f'over {MAX_LINES} lines, or compiled with > {MAX_JIT_PARAMS} params: {new}'
    grown = [k for k, v in over.items() if v[0] > KNOWN[k][0] or v[1] > KNOWN[k][1]]
    assert not grown, f'grew: {[(k, over[k], KNOWN[k]) for k in grown]}'


def test_every_compiled_function_uses_the_numpy_error_model():
    """Issue 34: with Python's error model every float division tests for zero and may raise, and
    an exception exit keeps numba's reference counting of the arrays around it (atomic increments
    and decrements, most of the closed loop's time before). Explicit on every decorator: numba
    would otherwise inherit the flag from whichever caller compiles a kernel first.
    """
    missing = []
    for path in sorted(PKG.rglob('*.py')):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for d in node.decorator_list:
                    text = ast.unparse(d)
                    if 'njit' in text and "error_model='numpy'" not in text:
                        missing.append(f'{path.relative_to(PKG).as_posix()}:{node.name}')
    assert not missing, f"compiled without error_model='numpy': {missing}"
