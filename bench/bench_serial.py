"""Serial link benchmark: codec speed, and command -> telemetry round trip through the bridge node
and the emulated motor board over a real pty.

    .venv/bin/python bench/bench_serial.py [--commands 1000]

Prints µs per encode / decode of a TORQUE_CMD frame next to a baseline (struct.pack / unpack of the
same 4-byte body, run in the same process), and the round-trip p50/p99 next to the wire time the
same two frames need at 115200 baud (a pty has no baud rate: the wire time is not simulated).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import struct
import sys
import tempfile
import time
import timeit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ament_formation.core.serial import serial_protocol as sp  # noqa: E402


def codec_table(number: int = 20000) -> list[tuple[str, float]]:
    msg = sp.TorqueCommand(1234, -567)
    wire = sp.encode_frame(msg, 7, leading_delimiter=True)
    dec = sp.FrameDecoder()

    def per_call_us(fn) -> float:
        return min(timeit.repeat(fn, number=number, repeat=5)) / number * 1e6

    base_pack = per_call_us(lambda: struct.pack('<hh', 1234, -567))
    base_unpack = per_call_us(lambda: struct.unpack('<hh', b'\xd2\x04\xc9\xfd'))
    enc = per_call_us(lambda: sp.encode_frame(msg, 7, leading_delimiter=True))
    decode = per_call_us(lambda: dec.feed(wire))
    return [
        ('encode TORQUE_CMD frame', enc, base_pack, 'struct.pack body'),
        ('decode TORQUE_CMD frame (feed)', decode, base_unpack, 'struct.unpack body'),
    ]


def round_trip(n_commands: int) -> tuple[float, float, float, int]:
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault(
        'FASTRTPS_DEFAULT_PROFILES_FILE',
        str(Path(__file__).resolve().parents[1] / 'config' / 'fastdds_localhost.xml'),
    )
    os.environ.setdefault('ROS_DOMAIN_ID', str(os.getpid() % 200 + 1))
    import numpy as np
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from ament_formation.core.serial import serial_link as sl
    from ament_formation.core.serial.motor_board import MotorBoard
    from ament_formation.hw.pty_board import PtyBoard
    from ament_formation.nodes.bridge import BridgeNode
    from ament_formation.ros.executors import spin_until
    from ament_formation.ros.qos import QOS_CONTROL

    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(os.environ['ROS_DOMAIN_ID']))
    tmp = Path(tempfile.mkdtemp(prefix='bench_serial_'))
    runner = PtyBoard(MotorBoard(now_s=time.monotonic()), link_path=tmp / 'board.tty')
    runner.open()
    runner.start()
    ex = SingleThreadedExecutor(context=ctx)
    bridge = BridgeNode(
        context=ctx,
        namespace='robot_0',
        parameter_overrides=[Parameter('port', value=runner.port)],
    )
    helper = Node('bench_helper', namespace='robot_0', context=ctx)
    pub = helper.create_publisher(JointState, 'wheel_torque', QOS_CONTROL)
    ex.add_node(bridge)
    ex.add_node(helper)
    try:
        if not spin_until(ex, lambda: bridge.link.state == sl.UP, 5.0):
            raise RuntimeError('link did not come up')
        bridge.link.rtt_s.clear()
        sent = [0]

        def tick():
            if sent[0] < n_commands:
                msg = JointState()
                msg.effort = [0.001 * (sent[0] % 100), -0.001 * (sent[0] % 100)]
                pub.publish(msg)
                sent[0] += 1

        helper.create_timer(0.01, tick)
        spin_until(ex, lambda: sent[0] >= n_commands, n_commands * 0.02 + 5.0)
        spin_until(ex, lambda: False, 0.05)
        rtt = np.array(bridge.link.rtt_s) * 1e3
        return (
            float(np.percentile(rtt, 50)),
            float(np.percentile(rtt, 99)),
            float(rtt.max()),
            rtt.size,
        )
    finally:
        ex.remove_node(bridge)
        ex.remove_node(helper)
        bridge.destroy_node()
        helper.destroy_node()
        ex.shutdown(timeout_sec=1.0)
        runner.close()
        rclpy.try_shutdown(context=ctx)
        tmp.rmdir()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--commands', type=int, default=1000)
    args = ap.parse_args()
    print('codec (best of 5, µs per call)')
    print(f'{"operation":34s} {"µs":>8s} {"baseline µs":>12s} {"ratio":>7s}  baseline')
    for name, us, base, base_name in codec_table():
        print(f'{name:34s} {us:8.2f} {base:12.3f} {us / base:7.1f}  {base_name}')
    wire_ms = (13 + 18) * 10 / 115200 * 1e3
    p50, p99, worst, n = round_trip(args.commands)
    print(
        f'\ncommand -> telemetry round trip, bridge + emulated board over a pty '
        f'({n} samples, 100 Hz)'
    )
    print(f'{"":24s} {"ms":>8s} {"x wire time":>12s}')
    print(
        f'{"wire time @115200":24s} {wire_ms:8.2f} {1.0:12.2f}   '
        '(TORQUE_CMD 13 B + TELEMETRY 18 B, 8N1, protocol v2)'
    )
    print(f'{"p50":24s} {p50:8.2f} {p50 / wire_ms:12.2f}')
    print(f'{"p99":24s} {p99:8.2f} {p99 / wire_ms:12.2f}')
    print(f'{"max":24s} {worst:8.2f} {worst / wire_ms:12.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
