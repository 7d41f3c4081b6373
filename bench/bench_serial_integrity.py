"""Link integrity: mutated frames through the decoder — how many corrupted frames are accepted
(and how many of those are torque commands, i.e. would move a wheel)?

    .venv/bin/python bench/bench_serial_integrity.py [--frames 10000000] [--v1-frames 1000000]
                                                     [--workers 2] [--seed 1]

Each trial takes one valid frame (half TORQUE_CMD, half any message type, random fields and
sequence numbers, COBS-encoded), applies one random corruption (core/serial/byte_faults.mutate:
1-3 bit flips, a byte replaced / inserted / deleted, a burst of up to 16 bits, 2-4 bytes replaced),
and
feeds it between two
delimiters to a FrameDecoder. Any frame the decoder returns is a corrupted frame accepted. Version
2
(CRC-32C) is measured with --frames trials, version 1 (CRC-16, the baseline) with --v1-frames.
Prints one JSON line per protocol version (counts, rate, wall time).
"""

from __future__ import annotations

import argparse
import json
from multiprocessing import Pool
import os
from pathlib import Path
import random
import sys
import time

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ament_formation.core.serial import cobs  # noqa: E402
from ament_formation.core.serial import serial_protocol as sp  # noqa: E402
from ament_formation.core.serial.byte_faults import mutate, MUTATION_KINDS  # noqa: E402

POOL_SIZE = 4096


def _random_message(rng: random.Random, torque: bool) -> sp.Message:
    import dataclasses

    classes = list(sp.MESSAGE_CLASSES.values())
    cls = sp.TorqueCommand if torque else classes[rng.randrange(len(classes))]
    limits = {'B': (0, 0xFF), 'H': (0, 0xFFFF), 'I': (0, 0xFFFFFFFF), 'h': (-0x8000, 0x7FFF)}
    values = []
    for f, code in zip(dataclasses.fields(cls), cls.FORMAT[1:]):
        lo, hi = limits[code]
        hi = {'flags': sp.FLAGS_DEFINED, 'engage': 1, 'reason': sp.STOP_HOST_SHUTDOWN}.get(
            f.name, hi
        )
        if f.name in ('protocol_version', 'ticks_per_rev', 'telemetry_period_ms'):
            lo = 1
        if f.name == 'protocol_version':
            hi = 15
        # half the fields small (many zero bytes -> many COBS code bytes), half anywhere
        values.append(
            rng.randint(lo, hi) if rng.random() < 0.5 else rng.randint(max(lo, -3), min(hi, 3))
        )
    return cls(*values)


def run_chunk(args: tuple[int, int, int, str | None]) -> dict:
    """``n`` trials of protocol ``version`` with seed ``seed`` (mutations of kind ``only``, or
    all): counts.
    """
    n, version, seed, only = args
    rng = random.Random(seed)
    pool = []
    for k in range(POOL_SIZE):
        msg = _random_message(rng, torque=k % 2 == 0)
        if version == 1 and isinstance(msg, sp.Stop):
            msg = sp.TorqueCommand(rng.randint(-0x8000, 0x7FFF), rng.randint(-0x8000, 0x7FFF))
        pool.append(cobs.encode(sp.raw_frame(msg, rng.randrange(256), version)))
    dec = sp.FrameDecoder(accepted_version=version)
    feed = dec.feed
    accepted: list[dict] = []
    unchanged = 0
    for _ in range(n):
        block = pool[rng.randrange(POOL_SIZE)]
        bad, kind = mutate(block, rng, only)
        if bad == block:
            unchanged += 1
            continue
        out = feed(b'\x00' + bad + b'\x00')
        for frame in out:
            accepted.append(
                {
                    'kind': kind,
                    'original': block.hex(),
                    'mutated': bad.hex(),
                    'decoded': frame.msg.to_dict(),
                }
            )
    return {'trials': n - unchanged, 'accepted': accepted, 'rejected': dict(dec.rejected)}


def measure(total: int, version: int, workers: int, seed: int, only: str | None = None) -> dict:
    chunk = 250_000
    jobs = [
        (min(chunk, total - i), version, seed * 1_000_003 + k, only)
        for k, i in enumerate(range(0, total, chunk))
    ]
    t0 = time.monotonic()
    cpu0 = os.times()
    if workers > 1:
        with Pool(workers) as p:
            parts = p.map(run_chunk, jobs, chunksize=1)
    else:
        parts = [run_chunk(j) for j in jobs]
    wall = time.monotonic() - t0
    cpu1 = os.times()
    cpu = (
        cpu1.user
        + cpu1.children_user
        + cpu1.system
        + cpu1.children_system
        - cpu0.user
        - cpu0.children_user
        - cpu0.system
        - cpu0.children_system
    )
    trials = sum(p['trials'] for p in parts)
    accepted = [a for p in parts for a in p['accepted']]
    rejected: dict[str, int] = {}
    for p in parts:
        for k, v in p['rejected'].items():
            rejected[k] = rejected.get(k, 0) + v
    torque = [a for a in accepted if a['decoded']['type'] == 'TORQUE_CMD']
    return {
        'protocol_version': version,
        'check': 'CRC-16/CCITT-FALSE' if version == 1 else 'CRC-32C',
        'mutations': only or 'all kinds',
        'mutated_frames': trials,
        'accepted_corrupted_frames': len(accepted),
        'accepted_corrupted_torque_commands': len(torque),
        'accepted_per_million': 1e6 * len(accepted) / max(trials, 1),
        'rejected': rejected,
        'wall_s': round(wall, 1),
        'cpu_s': round(cpu, 1),
        'workers': workers,
        'us_per_frame_cpu': round(1e6 * cpu / max(trials, 1), 2),
        'examples': accepted[:5],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--frames', type=int, default=10_000_000, help='version-2 trials')
    ap.add_argument(
        '--v1-frames', type=int, default=1_000_000, help='version-1 (CRC-16) baseline trials'
    )
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument(
        '--only',
        choices=MUTATION_KINDS,
        default=None,
        help="one kind of corruption only (bytes_replaced: beyond a CRC-16's guarantees)",
    )
    a = ap.parse_args()
    for n, version in ((a.v1_frames, 1), (a.frames, sp.PROTOCOL_VERSION)):
        if n > 0:
            print(json.dumps(measure(n, version, a.workers, a.seed, a.only)), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
