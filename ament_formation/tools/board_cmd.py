"""`formation board --pty`: an emulated motor board (standalone wheel model) on a pty, so the
bridge can be tried without the rest of the system::

    formation board --pty --link /tmp/robot_0.tty [--corrupt 0.01] [--drop 0] [--delay 0]
    formation_bridge --ros-args -r __ns:=/robot_0 -p port:=/tmp/robot_0.tty

A robot on blocks for `formation board-check`: ``--motor`` drives each wheel through the
firmware's DC-motor model (firmware/src/config.h constants; wheel J 1.6e-3 kg·m², b 2e-3 N·m·s/rad,
as the simavr harness), ``--motor-kt-scale L,R`` gives the real motors other torque constants,
``--reverse-motor`` / ``--reverse-encoder left|right`` wire a wheel's motor or encoder reversed.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import signal
import tempfile
import threading
import time

import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.serial.byte_faults import FaultSpec
from ament_formation.core.serial.motor_board import BoardConfig, MotorBoard, Wiring
from ament_formation.core.serial.motor_constants import MotorConstants

WHEELS = ('left', 'right')


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'board', help='emulated motor board on a pty (standalone wheel model)'
    )
    p.add_argument('--pty', action='store_true', required=True, help='serve on a pseudo-terminal')
    p.add_argument(
        '--link',
        type=Path,
        default=None,
        help='stable symlink to the pty (default: <tmp>/formation_board_<pid>.tty)',
    )
    p.add_argument('--torque-limit', type=float, default=0.15, help='hard torque limit [N·m]')
    p.add_argument('--ticks-per-rev', type=int, default=1440)
    p.add_argument(
        '--drop', type=float, default=0.0, help='probability of dropping each byte (both ways)'
    )
    p.add_argument(
        '--corrupt',
        type=float,
        default=0.0,
        help='probability of corrupting each byte (both ways)',
    )
    p.add_argument(
        '--delay', type=float, default=0.0, help='probability of delaying each byte by --delay-s'
    )
    p.add_argument('--delay-s', type=float, default=0.02)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument(
        '--motor', action='store_true',
        help="wheels driven through the firmware's DC-motor model (a robot on blocks)",
    )
    p.add_argument(
        '--motor-kt-scale', default='1,1', metavar='L,R',
        help="real motors' torque constants over the firmware's, left,right (with --motor)",
    )
    p.add_argument('--reverse-motor', action='append', default=[], choices=WHEELS,
                   help="wire this wheel's motor reversed (repeatable)")
    p.add_argument('--reverse-encoder', action='append', default=[], choices=WHEELS,
                   help="wire this wheel's encoder reversed (repeatable)")
    p.add_argument(
        '--duration',
        type=float,
        default=0.0,
        help='stop after this many seconds (0: until Ctrl-C)',
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ament_formation.hw.pty_board import PtyBoard

    try:
        scale = tuple(float(v) for v in args.motor_kt_scale.split(','))
        if len(scale) == 1:
            scale = scale * 2
        wiring = Wiring(
            tuple(w in args.reverse_motor for w in WHEELS),
            tuple(w in args.reverse_encoder for w in WHEELS),
        )
        extra = {}
        if args.motor:
            extra = {
                'motor': MotorConstants(ticks_per_rev=args.ticks_per_rev),
                'wheel_inertia_kgm2': 1.6e-3,
                'wheel_damping_nms': 2e-3,
            }
        cfg = BoardConfig(
            ticks_per_rev=args.ticks_per_rev,
            hard_torque_limit_nm=args.torque_limit,
            plant_kt_scale=scale,
            wiring=wiring,
            **extra,
        )
        faults = FaultSpec(
            drop_prob=args.drop,
            corrupt_prob=args.corrupt,
            delay_prob=args.delay,
            delay_s=args.delay_s,
        )
    except ValueError as err:
        raise ConfigError(str(err)) from None
    if args.duration < 0:
        raise ConfigError(f'{args.duration} s is negative', '--duration')
    link = args.link or Path(tempfile.gettempdir()) / f'formation_board_{os.getpid()}.tty'
    board = MotorBoard(cfg, now_s=time.monotonic(), standalone=True)
    runner = PtyBoard(
        board,
        link_path=link,
        rx_faults=faults,
        tx_faults=faults,
        rng=np.random.default_rng(args.seed),
    )
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    with runner:
        runner.start()
        print(
            f'emulated motor board on {runner.port} -> {runner.slave_name} (Ctrl-C to stop)',
            flush=True,
        )
        try:
            done.wait(args.duration if args.duration > 0 else None)
        except KeyboardInterrupt:
            pass
        with runner.lock:
            s = board.status(time.monotonic())
        print(
            f'accepted commands {board.accepted_commands}, crc errors {s.crc_errors}, '
            f'frame errors {s.frame_errors}, watchdog trips {s.watchdog_trips}'
        )
    return 0
