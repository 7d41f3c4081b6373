"""The console scripts' entry points (setup.py): each checks the libraries its program needs
(core/requirements.py) before importing the program, so a missing or too old NumPy, numba,
OpenCV, ... is one line on stderr naming what to install and exit status 1, never an import
traceback; then it runs the program's ``main()``.
"""

from __future__ import annotations

import importlib
import sys

from ament_formation.core import requirements as req

# program -> (module with its main(), libraries it needs beyond req.REQUIRED)
PROGRAMS = {
    'formation': ('ament_formation.tools.cli', ()),
    'formation_world': ('ament_formation.nodes.world', (req.OPENCV,)),
    'formation_tracker': ('ament_formation.nodes.tracker', (req.OPENCV,)),
    'formation_controller': ('ament_formation.nodes.controller', ()),
    'formation_bridge': ('ament_formation.nodes.bridge', (req.SERIAL,)),
    'formation_coordinator': ('ament_formation.nodes.coordinator', ()),
    'formation_team': ('ament_formation.nodes.team', (req.SERIAL,)),
    'formation_live_view': ('ament_formation.nodes.live_view', (req.OPENCV,)),
}


def run(program: str) -> int:
    """Check ``program``'s libraries, then run its main(); 1 with one line when one is not met."""
    module, extra = PROGRAMS[program]
    lines = req.problems(req.REQUIRED + extra)
    if lines:
        print(f'{program}: {lines[0]}', file=sys.stderr)
        return 1
    return importlib.import_module(module).main()


def formation() -> int:
    return run('formation')


def formation_world() -> int:
    return run('formation_world')


def formation_tracker() -> int:
    return run('formation_tracker')


def formation_controller() -> int:
    return run('formation_controller')


def formation_bridge() -> int:
    return run('formation_bridge')


def formation_coordinator() -> int:
    return run('formation_coordinator')


def formation_team() -> int:
    return run('formation_team')


def formation_live_view() -> int:
    return run('formation_live_view')
