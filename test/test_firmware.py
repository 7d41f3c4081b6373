"""Motor-board firmware (firmware/): host-compiled protocol against the vectors, the AVR build and
its size, and the firmware running in simavr behind a pty.

Time: measured in *emulated* time (the harness stamps every status line and every TELEMETRY frame
with the AVR cycle counter / 16 MHz); the harness is paced to the wall clock, so tests wait in
wall time with timeouts, but rates and delays are asserted in emulated time, which host load
cannot skew.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import time

import pytest

from firmware_sim import (FIRMWARE_DIR, VECTORS_PATH, CodecLink, Harness, build_firmware, config_constants,
                          expected_duty, toolchain_missing)

CONTROL_PERIOD_CYCLES = 160_000      # 10 ms at 16 MHz


@pytest.fixture(scope="module")
def build_dir(tmp_path_factory):
    missing = toolchain_missing()
    if missing:
        if os.environ.get("AMENT_FORMATION_NO_FIRMWARE_TOOLCHAIN"):
            pytest.skip(f"firmware toolchain unavailable ({', '.join(missing)}) and apt unusable here")
        pytest.fail(f"firmware toolchain missing ({', '.join(missing)}): run scripts/install_firmware_deps.sh")
    out = tmp_path_factory.mktemp("firmware_build")
    build_firmware(out)
    return out


@pytest.fixture
def harness(build_dir, tmp_path):
    h = Harness(build_dir, tmp_path)
    yield h
    h.close()


@pytest.fixture
def frozen_harness(build_dir, tmp_path):
    h = Harness(build_dir, tmp_path, freeze_wheels=True)
    yield h
    h.close()


# ---------------------------------------------------------------------------------------------
# host-compiled protocol.c against docs/serial-protocol-vectors.json


def _run_driver(build_dir, lines: list[str]) -> list[str]:
    res = subprocess.run([str(build_dir / "host" / "protocol_vectors")], input="\n".join(lines) + "\n",
                         capture_output=True, text=True, timeout=30, check=True)
    return res.stdout.splitlines()


def _decode_blocks(output: list[str]) -> list[tuple[list[dict], dict]]:
    """Parse the driver's D answers: per command, (frames, rejected counters)."""
    blocks, frames = [], []
    for line in output:
        if line.startswith("F "):
            parts = line.split()
            frame = {"type": parts[1]}
            frame.update({k: int(v) for k, v in (p.split("=") for p in parts[2:])})
            frames.append(frame)
        elif line.startswith("R"):
            rejected = {k: int(v) for k, v in (p.split("=") for p in line.split()[1:])}
        elif line == "END":
            blocks.append((frames, rejected))
            frames = []
    return blocks


def test_every_vector_passes_in_host_compiled_c(build_dir):
    doc = json.loads(VECTORS_PATH.read_text())
    valid, invalid, streams = doc["valid"], doc["invalid"], doc["streams"]
    assert len(valid) >= 10 and len(invalid) >= 5 and len(streams) >= 1
    lines = [f"D {v['hex']}" for v in valid + invalid + streams]
    for v in valid:
        m = v["message"]
        fields = " ".join(f"{k}={val}" for k, val in m.items() if k != "type")
        lines.append(f"E {m['type']} {v['version']} {v['seq']} {int(v['leading_delimiter'])} {fields}")
    lines += [f"C {v['raw_hex'][:-4]}" for v in valid]
    lines += [f"X {_block(v['hex'])}" for v in valid]
    lines.append("C " + b"123456789".hex())
    out = _run_driver(build_dir, lines)

    decoded = _decode_blocks([o for o in out if o[0] in "FRE" and not o.startswith("ERR")])
    n_dec = len(valid) + len(invalid) + len(streams)
    assert len(decoded) == n_dec
    for v, (frames, rejected) in zip(valid, decoded[:len(valid)]):
        expect = dict(v["message"], version=v["version"], seq=v["seq"])
        assert frames == [expect], v["name"]
        assert rejected == {}, v["name"]
    for v, (frames, rejected) in zip(invalid, decoded[len(valid):len(valid) + len(invalid)]):
        assert frames == [], v["name"]
        assert rejected == {v["reject"]: 1}, v["name"]
    for v, (frames, rejected) in zip(streams, decoded[len(valid) + len(invalid):]):
        got = [{k: x for k, x in f.items() if k not in ("version", "seq")} for f in frames]
        assert got == v["frames"], v["name"]
        assert rejected == v["rejected"], v["name"]

    encoded = [o[2:] if o.startswith("H ") else o for o in out if o.startswith(("H ", "ERR"))]
    assert encoded == [v["hex"] for v in valid]
    crcs = [o.split()[1] for o in out if o.startswith("C ")]
    assert crcs[:-1] == [v["crc16"] for v in valid]
    assert crcs[-1] == "0x29b1"                       # CRC-16/CCITT-FALSE check value
    raws = [o.split()[1] for o in out if o.startswith("X ")]
    assert raws == [v["raw_hex"] for v in valid]


def _block(wire_hex: str) -> str:
    """The COBS block of a single-frame wire string (delimiters removed)."""
    data = bytes.fromhex(wire_hex)
    return data.strip(b"\x00").hex()


# ---------------------------------------------------------------------------------------------
# AVR build


def test_make_builds_hex_and_elf_within_flash_and_ram(build_dir):
    assert (build_dir / "motor_board.elf").stat().st_size > 0
    hex_lines = (build_dir / "motor_board.hex").read_text().splitlines()
    assert hex_lines[0].startswith(":") and hex_lines[-1] == ":00000001FF"   # Intel HEX, EOF record
    res = subprocess.run(["make", "-s", "-C", str(FIRMWARE_DIR), f"BUILD={build_dir}", "size"],
                         capture_output=True, text=True, timeout=60, check=True)
    flash = int(re.search(r"Program:\s+(\d+) bytes", res.stdout).group(1))
    ram = int(re.search(r"Data:\s+(\d+) bytes", res.stdout).group(1))
    print(f"firmware: Flash {flash} B of 32768 ({100 * flash / 32768:.1f} %), "
          f"RAM {ram} B of 2048 ({100 * ram / 2048:.1f} %) static")
    assert 1000 < flash <= 32768 - 512            # leaves the 512-byte Optiboot bootloader section
    assert 100 < ram <= 2048 - 512                # at least 512 bytes left for the stack


# ---------------------------------------------------------------------------------------------
# firmware in simavr, spoken to with the Python codec over the pty


def test_codec_link_handshake_config_estop(harness):
    link = CodecLink(harness.pty)
    sp = link.sp
    try:
        link.send(sp.Hello(1))
        ack = link.wait_frame(sp.MsgType.HELLO_ACK, 3.0)
        assert ack.msg == sp.HelloAck(1, 1, 0, 1440, 1500, 1500, 200, 10)
        tel = link.wait_frame(sp.MsgType.TELEMETRY, 1.0)
        assert tel.msg.flags & sp.FLAG_RESET == 0 and tel.msg.flags & sp.FLAG_WATCHDOG

        # CONFIG beyond the ranges comes back clamped: limit to the hard limit, watchdog to 500 ms
        link.send(sp.Config(9000, 900, 2))
        cack = link.wait_frame(sp.MsgType.CONFIG_ACK, 1.0)
        assert cack.msg == sp.ConfigAck(1500, 500, 5)
        link.send(sp.Config(1000, 200, 10))
        assert link.wait_frame(sp.MsgType.CONFIG_ACK, 1.0).msg == sp.ConfigAck(1000, 200, 10)

        # over-limit torque is clamped to the configured limit and flagged
        link.send(sp.TorqueCommand(1500, -200))
        tel = link.wait_frame(sp.MsgType.TELEMETRY, 1.0, lambda f: f.msg.cmd_seq == link.seq - 1)
        assert tel.msg.flags & sp.FLAG_CLAMPED and not tel.msg.flags & sp.FLAG_WATCHDOG
        st = link.wait_frame(sp.MsgType.STATUS, 1.0)
        assert (st.msg.left_applied_e4nm, st.msg.right_applied_e4nm) == (1000, -200)

        # e-stop: torque zero at once, commands ignored while engaged, zero after release
        link.send(sp.EmergencyStop(1))
        harness.wait_for(lambda s: s["duty"] == [0.0, 0.0], 1.0, link.pump)
        link.send(sp.TorqueCommand(800, 800))
        st = link.wait_frame(sp.MsgType.STATUS, 1.0, lambda f: f.msg.cmd_seq == link.seq - 1)
        assert st.msg.flags & sp.FLAG_ESTOP and (st.msg.left_applied_e4nm, st.msg.right_applied_e4nm) == (0, 0)
        link.send(sp.EmergencyStop(0))
        st = link.wait_frame(sp.MsgType.STATUS, 1.0, lambda f: not f.msg.flags & sp.FLAG_ESTOP)
        assert (st.msg.left_applied_e4nm, st.msg.right_applied_e4nm) == (0, 0)

        # heartbeat is echoed unchanged
        link.send(sp.Heartbeat(0xDEADBEEF))
        assert link.wait_frame(sp.MsgType.HEARTBEAT, 1.0).msg.stamp_ms == 0xDEADBEEF
        assert link.decoder.rejected["crc"] == 0
    finally:
        link.close()


def test_torque_to_duty_follows_motor_model_with_frozen_wheels(frozen_harness):
    """Wheels held still: duty = tau R / (G eta k_t V) exactly, rounded to the PWM step."""
    c = config_constants()
    top = round(c["F_CPU"] / (2 * c["PWM_FREQUENCY_HZ"]))
    link = CodecLink(frozen_harness.pty)
    sp = link.sp
    try:
        link.send(sp.Hello(1))
        link.wait_frame(sp.MsgType.HELLO_ACK, 3.0)
        for left, right in ((1000, -500), (-1500, 1200), (400, 0)):
            want = [round(expected_duty(t * 1e-4, 0.0, c) * top) for t in (left, right)]

            pump = _command_pump(link, sp.TorqueCommand(left, right))
            line = frozen_harness.wait_for(lambda s, want=want: s["pwm_counts"] == want, 2.0, pump)
            assert line["pwm_top"] == top == 400
            assert line["duty"] == pytest.approx([w / top for w in want], abs=1e-4)
            assert want[0] != 0
    finally:
        link.close()


def _command_pump(link, msg, period_s: float = 0.01):
    """A pump for Harness.wait_for: sends ``msg`` every ``period_s`` (100 Hz) and reads frames."""
    last = [-1.0]

    def pump():
        now = time.monotonic()
        if now - last[0] >= period_s:
            link.send(msg)
            last[0] = now
        link.pump()

    return pump
