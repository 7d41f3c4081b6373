"""Test helpers for the motor-board firmware: build it, run it in the simavr harness, talk to it.

Used by test/test_firmware.py and bench/bench_firmware.py. Not a test module itself.

- ``toolchain_missing()``: which of the Debian tools the firmware needs are absent.
- ``build_firmware(build_dir)``: ``make -C firmware BUILD=build_dir all host``.
- ``Harness``: firmware/build/host/formation_fw_sim as a subprocess (ended by its PID), its pty
  path, its status lines (one JSON object per 10 ms of emulated time) and its fault-injection
  control file.
- ``CodecLink``: the Python codec (ament_formation.core.serial.serial_protocol) on the pty, for
tests
  that need to speak to the board frame by frame.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import re
import select
import shutil
import signal
import subprocess
import time
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE_DIR = ROOT / 'firmware'
VECTORS_PATH = ROOT / 'docs' / 'serial-protocol-vectors.json'
SIMAVR_HEADER = Path('/usr/include/simavr/sim_avr.h')
# The harness is paced to the wall clock but runs slower than real time when the host is busy;
# tests assert in emulated time, and every wall-clock timeout is scaled by this upper bound.
WALL_TIMEOUT_SCALE = 5.0


def toolchain_missing() -> list[str]:
    """Names of the missing tools (empty when the firmware can be built and emulated)."""
    missing = [
        tool
        for tool in ('avr-gcc', 'avr-objcopy', 'avr-size', 'make', 'gcc')
        if shutil.which(tool) is None
    ]
    if not SIMAVR_HEADER.exists():
        missing.append('libsimavr-dev')
    return missing


def build_firmware(build_dir: Path) -> subprocess.CompletedProcess:
    """Build the firmware ELF/HEX and the host tools into ``build_dir``; raises on failure."""
    return subprocess.run(
        ['make', '-C', str(FIRMWARE_DIR), f'BUILD={build_dir}', 'all', 'host'],
        check=True,
        capture_output=True,
        text=True,
        timeout=180,
    )


def config_constants() -> dict[str, float]:
    """Numeric #defines of firmware/src/config.h (the motor model the tests check against)."""
    values: dict[str, float] = {}
    pattern = re.compile(r'^#define\s+(\w+)\s+\(?([-+0-9.eE]+)[fFuUlL]*\)?')
    for line in (FIRMWARE_DIR / 'src' / 'config.h').read_text().splitlines():
        m = pattern.match(line.strip())
        if m:
            values[m.group(1)] = float(m.group(2))
    return values


def expected_duty(torque_nm: float, wheel_speed_radps: float, c: dict[str, float]) -> float:
    """The documented DC-motor model (firmware/src/motor_model.h), duty clamped to [-1, 1]."""
    gear = c['MOTOR_GEAR_RATIO']
    kt = c['MOTOR_TORQUE_CONSTANT_NM_PER_A']
    current_a = torque_nm / (gear * c['MOTOR_GEAR_EFFICIENCY']) / kt
    volts = current_a * c['MOTOR_RESISTANCE_OHM'] + kt * gear * wheel_speed_radps
    return max(-1.0, min(1.0, volts / c['MOTOR_SUPPLY_V']))


class Harness:
    """The simavr harness running the firmware ELF, UART on a pty; end it with ``close()``."""

    def __init__(
        self,
        build_dir: Path,
        work_dir: Path,
        *,
        freeze_wheels: bool = False,
        start_timeout_s: float = 10.0,
        extra_args: tuple[str, ...] = (),
    ) -> None:
        self.status_path = work_dir / 'fw_status.jsonl'
        self.control_path = work_dir / 'fw_control'
        self.set_mode('pass')
        self._offset = 0
        self._partial = ''
        self.lines: list[dict] = []
        cmd = [
            str(build_dir / 'host' / 'formation_fw_sim'),
            str(build_dir / 'motor_board.elf'),
            '--status',
            str(self.status_path),
            '--control',
            str(self.control_path),
        ]
        if freeze_wheels:
            cmd.append('--freeze-wheels')
        cmd += list(extra_args)  # e.g. --reverse-motor left, --kt-scale 1.3,1 (wiring faults)
        self.stderr_path = work_dir / 'fw_sim.stderr'
        with open(self.stderr_path, 'wb') as err:
            self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err)
        self.pty = self._read_pty_line(start_timeout_s)

    def _read_pty_line(self, timeout_s: float) -> str:
        fd = self.proc.stdout.fileno()
        buf = b''
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                break
            chunk = os.read(fd, 4096)
            if not chunk:
                break
            buf += chunk
            for line in buf.decode(errors='replace').splitlines():
                if line.startswith('PTY ') and buf.endswith(b'\n'):
                    return line.split()[1]
        self.close()
        raise RuntimeError(f'formation_fw_sim printed no PTY line within {timeout_s} s')

    def set_mode(self, mode: str) -> None:
        """Fault injection on the host -> board line: pass, cut or corrupt (atomic file swap)."""
        tmp = self.control_path.with_suffix('.tmp')
        tmp.write_text(mode + '\n')
        os.replace(tmp, self.control_path)

    def poll(self) -> list[dict]:
        """New status lines since the last call (also appended to ``self.lines``)."""
        if not self.status_path.exists():
            return []
        with open(self.status_path, encoding='utf-8') as f:
            f.seek(self._offset)
            chunk = f.read()
            self._offset = f.tell()
        text = self._partial + chunk
        parts = text.split('\n')
        self._partial = parts.pop()
        new = [json.loads(p) for p in parts if p]
        self.lines.extend(new)
        return new

    def latest(self) -> dict | None:
        self.poll()
        return self.lines[-1] if self.lines else None

    def wait_for(
        self,
        predicate: Callable[[dict], bool],
        timeout_s: float,
        pump: Callable[[], None] | None = None,
    ) -> dict:
        """First new status line for which ``predicate`` holds; ``pump`` runs between polls."""
        deadline = time.monotonic() + timeout_s * WALL_TIMEOUT_SCALE
        while time.monotonic() < deadline:
            if pump is not None:
                pump()
            for line in self.poll():
                if predicate(line):
                    return line
            if self.proc.poll() is not None:
                raise RuntimeError(
                    f'formation_fw_sim exited: {self.stderr_path.read_text(errors="replace")}'
                )
            time.sleep(0.002)
        raise TimeoutError(f'no harness status line met the condition within {timeout_s} s')

    def close(self) -> dict | None:
        """End the harness by its PID; returns its final status line."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5.0)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self.poll()
        return self.lines[-1] if self.lines else None


class CodecLink:
    """The Python codec speaking to the board over the harness pty (host side of the protocol)."""

    def __init__(self, pty: str) -> None:
        import serial

        from ament_formation.core.serial import serial_protocol as sp

        self.sp = sp
        self.port = serial.Serial(pty, 115200, timeout=0, dsrdtr=False, rtscts=False)
        self.decoder = sp.FrameDecoder()
        self.seq = 0
        self.frames: list = []
        self.received = bytearray()  # every byte read, for diagnosing rejections

    def send(self, msg) -> None:
        self.port.write(self.sp.encode_frame(msg, self.seq, leading_delimiter=True))
        self.seq = (self.seq + 1) & 0xFF

    def pump(self) -> list:
        data = self.port.read(4096)
        self.received += data
        new = self.decoder.feed(data)
        self.frames.extend(new)
        return new

    def wait_frame(self, msg_type, timeout_s: float, predicate=lambda f: True):
        deadline = time.monotonic() + timeout_s * WALL_TIMEOUT_SCALE
        while time.monotonic() < deadline:
            for frame in self.pump():
                if frame.msg.TYPE == msg_type and predicate(frame):
                    return frame
            time.sleep(0.002)
        raise TimeoutError(f'no {msg_type.name} frame within {timeout_s} s')

    def rejected_blocks(self) -> list[tuple[str, str]]:
        """(reason, block hex) of every received block the codec rejects."""
        out = []
        for block in bytes(self.received).split(b'\x00'):
            if block:
                res = self.sp.FrameDecoder()._decode_block(block)
                if isinstance(res, str):
                    out.append((res, block.hex()))
        return out

    def handshake(self, timeout_s: float = 3.0):
        """HELLO every 0.2 s until HELLO_ACK (docs/serial-protocol.md §5.1: bytes sent before the
        firmware has enabled its UART are lost, as on a real board); returns the HELLO_ACK frame.
        """
        deadline = time.monotonic() + timeout_s * WALL_TIMEOUT_SCALE
        while time.monotonic() < deadline:
            self.send(self.sp.Hello(self.sp.PROTOCOL_VERSION))
            try:
                return self.wait_frame(self.sp.MsgType.HELLO_ACK, 0.2 / WALL_TIMEOUT_SCALE)
            except TimeoutError:
                continue
        raise TimeoutError(f'no HELLO_ACK within {timeout_s} s')

    def close(self) -> None:
        self.port.close()
