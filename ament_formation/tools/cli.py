"""The `formation` command line: one entry point, one module per group of subcommands.

Each module named in ``_COMMAND_MODULES`` exposes ``register(subparsers)``, which adds its
subcommands and sets ``func(args) -> int`` on each. Bad user input raises
:class:`ament_formation.core.errors.ConfigError`: one line on stderr, exit code 2, no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from ament_formation.core.errors import ConfigError, one_line

_COMMAND_MODULES = (
    'ament_formation.tools.sim_cmd',  # sim, plot
    'ament_formation.tools.run_cmd',  # run
    'ament_formation.tools.calibrate_cmd',  # calibrate intrinsics|floor
    'ament_formation.tools.markers_cmd',  # markers (printable markers and ChArUco board)
    'ament_formation.tools.topic_cmd',  # topics, nodes, echo, hz
    'ament_formation.tools.board_cmd',  # board --pty (emulated motor board)
    'ament_formation.tools.board_check_cmd',  # board-check (wheel direction, encoder, motor)
    'ament_formation.tools.multihost_cmd',  # multihost (hosts in network namespaces)
    'ament_formation.tools.sweep_cmd',  # sweep (Monte Carlo campaigns, Dask)
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='formation',
        description='Formation control with sliding modes and elliptical limit cycles.',
    )
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    sub.required = True
    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as err:
            if err.name == name:  # that group is not part of this build
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ConfigError as err:
        print(one_line(f'formation {args.command}: {err}'), file=sys.stderr)  # < 300 chars
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == '__main__':
    sys.exit(main())
