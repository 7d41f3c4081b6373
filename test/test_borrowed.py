"""Arrays read without reference counting (core/borrowed.py): the same data, shape and strides as
the owner's, reads and writes reaching the owner's memory, nested tuples and named tuples, and
owners kept alive by :func:`keep_alive` while the borrowed copies are in use; and that the
compiled loops which borrow (the closed-loop simulator, the camera-sensing loop, the robot
agent's period) say so where they do it.
"""

from __future__ import annotations

from collections import namedtuple
from pathlib import Path

from numba import njit
import numpy as np

from ament_formation.core.borrowed import borrowed, keep_alive

Pair = namedtuple('Pair', ['a', 'b'])
PKG = Path(__file__).resolve().parents[1] / 'ament_formation'


@njit(cache=False)
def _sum_and_scale(pair, scale, extra):
    p, (e,) = borrowed((pair, (extra,)))
    total = 0.0
    for i in range(p.a.shape[0]):
        total += p.a[i] + p.b[i, 1]
        p.a[i] *= scale  # a write through the borrowed copy reaches the owner
    return total + e[0], p.a.shape[0], p.b.strides[0]


@njit(cache=False)
def _allocated_here(n):
    own = (np.arange(n * 1.0), np.ones((n, 3)))
    a, b = borrowed(own)
    acc = 0.0
    for _ in range(50):  # work after the last direct use of own: keep_alive must hold it
        tmp = np.zeros(n)  # allocations meanwhile reuse freed memory if own were gone
        for i in range(n):
            tmp[i] = a[i] * b[i, 2]
        acc += tmp.sum()
    keep_alive(own)
    return acc


def test_borrowed_arrays_read_and_write_the_owners_memory():
    a = np.arange(5.0)
    b = np.arange(10.0).reshape(5, 2)
    total, n, stride = _sum_and_scale(Pair(a, b), 2.0, np.array([100.0]))
    assert total == np.arange(5.0).sum() + b[:, 1].sum() + 100.0
    assert (n, stride) == (5, b.strides[0])
    assert np.array_equal(a, 2.0 * np.arange(5.0))


def test_arrays_allocated_in_the_function_stay_alive_through_keep_alive():
    n = 4096
    assert _allocated_here(n) == 50.0 * np.arange(n * 1.0).sum()


def test_the_hot_loops_borrow_their_arguments():
    # the loops whose arrays are read without counting (issue 34); a borrowed array never
    # leaves them: each returns scalars or writes into its arguments
    for rel, fn in (('core/sim/simulator.py', 'def _run_segment('),
                    ('core/sim/sensed_loop.py', 'def run_k('),
                    ('core/control/agent.py', 'def agent_tick_k(')):
        src = (PKG / rel).read_text()
        body = src[src.index(fn):]
        body = body[:body.index('\n\n\n')]
        assert '= borrowed(' in body, rel
