"""Firmware resource figures: Flash/RAM of the AVR build and worst-case main-loop / interrupt
durations in CPU cycles, measured in simavr, against the 10 ms control period (160 000 cycles).

Run: .venv/bin/python bench/bench_firmware.py [--seconds S]

Two runs of the same firmware in the same process:
  baseline  handshake only, no torque commands, wheels still (the idle board)
  loaded    TORQUE_CMD at 100 Hz (of emulated time) with torques that spin both wheels (encoder
  edges at several kHz),
            HEARTBEAT at 1 Hz, CONFIG, and a burst of corrupted frames (receive-error path)
Cycle counts come from the harness (firmware/sim/harness.c): interrupt vector entry to RETI, and
the main loop's busy stretches (GPIOR0 marker), with and without interrupt preemption.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import re
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test'))
sys.path.insert(0, str(ROOT))

from firmware_sim import (  # noqa: E402
    build_firmware,
    CodecLink,
    FIRMWARE_DIR,
    Harness,
    toolchain_missing,
)

CONTROL_PERIOD_CYCLES = 160_000


def run(build: Path, seconds: float, loaded: bool) -> dict:
    with tempfile.TemporaryDirectory(prefix='bench_fw_') as tmp:
        h = Harness(build, Path(tmp))
        link = CodecLink(h.pty)
        sp = link.sp
        try:
            link.handshake()
            if loaded:
                link.send(sp.Config(1500, 200, 10))
            start = h.latest()['t_s']
            last_cmd = last_hb = 0.0
            corrupted_sent = False
            while h.latest()['t_s'] - start < seconds:
                now = h.lines[-1]['t_s']  # paced in emulated time: 100 Hz for the board
                if loaded and now - last_cmd >= 0.01:
                    link.send(sp.TorqueCommand(1500, -1500))
                    last_cmd = now
                if loaded and now - last_hb >= 1.0:
                    link.send(sp.Heartbeat(int(now * 1000) & 0xFFFFFFFF))
                    last_hb = now
                if loaded and not corrupted_sent and h.lines[-1]['t_s'] - start > seconds / 2:
                    frame = bytearray(
                        sp.encode_frame(sp.TorqueCommand(100, 100), 0, leading_delimiter=True)
                    )
                    frame[3] ^= 0x10
                    link.port.write(bytes(frame) * 20)
                    corrupted_sent = True
                link.pump()
                time.sleep(0.002)
            return h.latest()
        finally:
            link.close()
            h.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seconds', type=float, default=3.0, help='emulated seconds per run')
    args = ap.parse_args()
    missing = toolchain_missing()
    if missing:
        print(
            f'bench_firmware: missing {", ".join(missing)}: run scripts/install_firmware_deps.sh',
            file=sys.stderr,
        )
        return 2
    with tempfile.TemporaryDirectory(prefix='bench_fw_build_') as tmp:
        build = Path(tmp)
        build_firmware(build)
        size = subprocess.run(
            ['make', '-s', '-C', str(FIRMWARE_DIR), f'BUILD={build}', 'size'],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        flash = int(re.search(r'Program:\s+(\d+) bytes', size).group(1))
        ram = int(re.search(r'Data:\s+(\d+) bytes', size).group(1))
        base = run(build, args.seconds, loaded=False)
        load = run(build, args.seconds, loaded=True)

    print(
        f'Flash {flash} B / 32768 B ({100 * flash / 32768:.1f} %), '
        f'static RAM {ram} B / 2048 B ({100 * ram / 2048:.1f} %)'
    )
    rejected = (
        load['board']['crc_errors'] + load['board']['frame_errors'] + load['board']['type_errors']
    )
    print(
        f'loaded run: wheels at {load["wheel_radps"][0]:.1f} / '
        f'{load["wheel_radps"][1]:.1f} rad/s, '
        f'{load["isr_count"].get("PCINT2", 0)} encoder interrupts, '
        f'{load["telemetry_count"]} TELEMETRY, '
        f'frames rejected by the board {rejected}'
    )
    print()
    print(
        f'{"measure (CPU cycles, worst case)":40s} {"baseline":>10s} {"loaded":>10s} '
        f'{"ratio":>7s} {"% of 10 ms":>10s}'
    )
    rows = [
        ('main loop busy, incl. interrupts', 'loop_max_cycles'),
        ('main loop busy, own code only', 'loop_max_own_cycles'),
    ]
    for label, key in rows:
        b, l_ = base[key], load[key]
        print(
            f'{label:40s} {b:10d} {l_:10d} {l_ / max(b, 1):7.2f} '
            f'{100 * l_ / CONTROL_PERIOD_CYCLES:9.2f}%'
        )
    for vec in sorted(set(base['isr_max_cycles']) | set(load['isr_max_cycles'])):
        b, l_ = base['isr_max_cycles'].get(vec, 0), load['isr_max_cycles'].get(vec, 0)
        print(
            f'{"ISR " + vec:40s} {b:10d} {l_:10d} {l_ / max(b, 1):7.2f} '
            f'{100 * l_ / CONTROL_PERIOD_CYCLES:9.2f}%'
        )
    for label, key in (
        ('CPU busy in main loop (mean)', 'loop_busy_cycles'),
        ('CPU in interrupts (mean)', 'isr_cycles'),
    ):
        b, l_ = base[key] / base['cycle'], load[key] / load['cycle']
        print(f'{label:40s} {100 * b:9.2f}% {100 * l_:9.2f}% {l_ / max(b, 1e-9):7.2f}')
    print(
        f'\ncontrol period: {CONTROL_PERIOD_CYCLES} cycles (10 ms at 16 MHz); '
        f'emulated {load["t_s"]:.2f} s in {load["wall_s"]:.2f} s wall (loaded run)'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
