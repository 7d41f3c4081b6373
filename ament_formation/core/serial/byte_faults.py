"""Fault injection on a byte stream (one direction of a serial link): drop, corrupt or delay bytes
with given probabilities. Order is preserved, as on a real UART: a delayed byte holds back the
bytes behind it. Randomness comes from the numpy Generator passed in.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FaultSpec:
    """Per-byte fault probabilities of one direction; ``delay_s`` [s] is how long a delayed byte
    waits.
    """

    drop_prob: float = 0.0
    corrupt_prob: float = 0.0
    delay_prob: float = 0.0
    delay_s: float = 0.02

    def __post_init__(self) -> None:
        for name in ('drop_prob', 'corrupt_prob', 'delay_prob'):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f'FaultSpec.{name}: {value} is not a probability in [0, 1]')
        if not 0.0 <= self.delay_s <= 10.0:
            raise ValueError(f'FaultSpec.delay_s: {self.delay_s} s not in [0, 10] s')

    @property
    def active(self) -> bool:
        return self.drop_prob > 0 or self.corrupt_prob > 0 or self.delay_prob > 0


class ByteFaults:
    """Apply a :class:`FaultSpec` to bytes passing through; counts what it did."""

    def __init__(self, spec: FaultSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self.dropped = 0
        self.corrupted = 0
        self.delayed = 0
        self._held: deque[tuple[float, bytes]] = deque()

    def pass_bytes(self, data: bytes, now_s: float) -> bytes:
        """Bytes that leave the faulty line at ``now_s`` given ``data`` entering it now."""
        spec = self.spec
        if data and spec.active:
            arr = np.frombuffer(data, dtype=np.uint8).copy()
            u = self.rng.random((3, arr.size))
            corrupt = u[1] < spec.corrupt_prob
            if corrupt.any():
                arr[corrupt] ^= self.rng.integers(1, 256, size=int(corrupt.sum()), dtype=np.uint8)
                self.corrupted += int(corrupt.sum())
            keep = u[0] >= spec.drop_prob
            self.dropped += int(arr.size - keep.sum())
            delay_at = np.flatnonzero((u[2] < spec.delay_prob) & keep)
            arr = arr[keep]
            if delay_at.size:
                first = int(np.searchsorted(np.flatnonzero(keep), delay_at[0]))
                self.delayed += 1
                data, suffix = arr[:first].tobytes(), arr[first:].tobytes()
            else:
                data, suffix = arr.tobytes(), b''
        else:
            suffix = b''
        if self._held:  # bytes behind a delayed byte wait for it
            self._hold(data, now_s)
            data = b''
        self._hold(suffix, now_s + spec.delay_s)
        return data + self.release(now_s)

    def _hold(self, data: bytes, release_s: float) -> None:
        if not data:
            return
        if self._held:
            release_s = max(release_s, self._held[-1][0])
        self._held.append((release_s, data))

    def release(self, now_s: float) -> bytes:
        """Held bytes whose delay has run out by ``now_s`` (in order)."""
        out = bytearray()
        while self._held and self._held[0][0] <= now_s:
            out += self._held.popleft()[1]
        return bytes(out)

    def clear(self) -> None:
        """Forget held bytes (the port was closed)."""
        self._held.clear()


MUTATION_KINDS = (
    'bit_flips',
    'byte_replaced',
    'byte_inserted',
    'byte_deleted',
    'burst',
    'bytes_replaced',
)


def mutate(data: bytes, rng, only: str | None = None) -> tuple[bytes, str]:
    """One random corruption of ``data`` (a frame's bytes) and its kind (MUTATION_KINDS), each
    with probability 1/7 except bit flips (2/7): 1-3 bit flips, one byte replaced, one byte
    inserted, one byte deleted, a burst of up to 16 bits, or 2-4 bytes anywhere replaced (line
    noise beyond what a CRC-16 is guaranteed to catch). ``rng`` is a ``random.Random`` (fast scalar
    draws; seeded by the caller). ``only`` (a MUTATION_KINDS name) restricts it to that kind. The
    result can equal ``data``; callers skip those.
    """
    b = bytearray(data)
    n = len(b)
    kind = (
        rng.randrange(7)
        if only is None
        else {k: i + (i > 0) for i, k in enumerate(MUTATION_KINDS)}[only]
    )
    if kind <= 1:
        for pos in rng.sample(range(n * 8), rng.randint(1, 3)):
            b[pos >> 3] ^= 1 << (pos & 7)
        return bytes(b), MUTATION_KINDS[0]
    if kind == 2:
        b[rng.randrange(n)] ^= rng.randint(1, 255)
        return bytes(b), MUTATION_KINDS[1]
    if kind == 3:
        b.insert(rng.randint(0, n), rng.randint(1, 255))
        return bytes(b), MUTATION_KINDS[2]
    if kind == 4:
        del b[rng.randrange(n)]
        return bytes(b), MUTATION_KINDS[3]
    if kind == 5:
        start = rng.randrange(n * 8)
        for pos in range(start, min(start + rng.randint(2, 16), n * 8)):
            if pos == start or rng.random() < 0.5:
                b[pos >> 3] ^= 1 << (pos & 7)
        return bytes(b), MUTATION_KINDS[4]
    for pos in rng.sample(range(n), min(n, rng.randint(2, 4))):
        b[pos] ^= rng.randint(1, 255)
    return bytes(b), MUTATION_KINDS[5]
