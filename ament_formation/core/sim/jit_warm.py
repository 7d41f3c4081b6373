"""Warming numba's cache once at set-up (the cache folder itself: core/jit_cache.py).

:func:`main` (``scripts/setup.sh`` runs it after installing, and whenever the core changed)
compiles every kernel the programs use once (in two processes at once where there are two
CPUs, then a pass that checks the cache is complete), so that the processes of a run load
machine code instead of all compiling it at the same time. Only :func:`main` prints.
"""

from __future__ import annotations

import os
from pathlib import Path
import sys

from ament_formation.core.jit_cache import _warm_stamp, is_warm


PARTS = ('closed_loop', 'rest')  # what --part compiles: two halves of about equal cost


def warm(part: str | None = None) -> None:
    """Compile (or load) every numba kernel the programs and ``formation sim`` use, by building
    what they build: the simulator and the camera-sensing one (its compiled loop) on a short run
    of each shipped scenario, the robot agents and the coordinator of each (as the nodes run
    them), the world's plant twin and the tracker's corner refinement. numba compiles a kernel's
    whole call tree on its first call, so one call of each entry point covers the branches not
    taken.

    ``part``: only one of :data:`PARTS`: ``'closed_loop'`` the ideal-sensing simulator (about 75 s
    cold on this project's machines), ``'rest'`` everything else (the sensed loop, agents,
    coordinator, twin, vision and geometry kernels; about 95 s).
    """
    if part is not None and part not in PARTS:
        raise ValueError(f'unknown part {part!r} (one of {", ".join(PARTS)})')
    import dataclasses

    from ament_formation.core.config_files import config_dir
    from ament_formation.core.scenario.loader import load_scenario
    from ament_formation.core.sim.simulator import simulate

    scenarios = [load_scenario(path)
                 for path in sorted((config_dir() / 'scenarios').glob('*.yaml'))]
    if part in (None, 'closed_loop'):
        for sc in scenarios:
            simulate(dataclasses.replace(sc, duration_s=0.05))
    if part in (None, 'rest'):
        _warm_rest(scenarios)


def _warm_rest(scenarios) -> None:
    """Every kernel but the ideal-sensing simulator's (:func:`warm`)."""
    import dataclasses

    import numpy as np

    from ament_formation.core.control.agent import AgentBatch
    from ament_formation.core.control.coordinator import Coordinator
    from ament_formation.core.sim.sensed import SensingParams, simulate_sensed
    from ament_formation.core.sim.twin import PlantTwin
    from ament_formation.core.vision import corner_refinement

    corner_refinement.warm_up()
    _warm_geometry()
    for sc in scenarios:
        simulate_sensed(dataclasses.replace(sc, duration_s=0.05), SensingParams.preset('camera'))
        twin = PlantTwin(sc)
        twin.pose_rates()
        twin.obstacle_states()
        coord = Coordinator(sc)
        for r in sc.robots:
            coord.state(r.id, np.array([*r.initial_pose, 0.0, 0.0]), 0.0)
        coord.decide(0.0)
        # every robot in one batch (the team, the sensed loop) and one robot alone (a robot's
        # controller): a one-row batch's arrays are C- and F-contiguous at once, so numba types
        # them differently and would compile again in each controller at start
        for hosted in (sc.robot_ids, sc.robot_ids[:1]):
            agents = AgentBatch(sc, hosted)
            agents.set_graph(coord.parents, 0.0)
            agents.assign(0.0, {}, coord.rates())
            for r in sorted(sc.robots, key=lambda r: r.id):
                if r.id in hosted:
                    agents.wheel(r.id, 0.0, (0.0, 0.0), (0.0, 0.0))
                    agents.camera(r.id, 0.0, np.asarray(r.initial_pose, dtype=float))
            agents.tick(0.01)
            agents.share(0.01)
            agents.needed(hosted[0])  # the nodes' hearing (S10.2), called on its own


def _warm_parts_in_parallel() -> bool:
    """Compile the :data:`PARTS` in one process each, at the same time (one per CPU this process
    may use, when there are two or more; numba compiles on one core). Returns whether they ran;
    a part that fails is said on stderr and left to the serial pass of :func:`main`.
    """
    import subprocess
    import time

    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    if cpus < 2:
        return False
    import ament_formation

    home = Path(ament_formation.__file__).resolve().parents[1]  # this copy of the package first
    code = 'import sys; from ament_formation.core.sim.jit_warm import main; sys.exit(main())'
    procs = [(part, subprocess.Popen([sys.executable, '-c', code, '--part', part], cwd=home))
             for part in PARTS]
    t0 = time.monotonic()
    for part, proc in procs:
        if proc.wait() != 0:
            print(f'setup: warning: compiling part {part!r} failed (exit {proc.returncode}); '
                  'the serial pass compiles it', file=sys.stderr)
    print(f'setup: both parts compiled in {time.monotonic() - t0:.0f} s', file=sys.stderr)
    return True


def _warm_geometry() -> None:
    """The validator's and the obstacle merge's kernels (the shipped scenarios may not reach
    them: no pair of their obstacles is near, none merges).
    """
    import numpy as np

    from ament_formation.core.model.ellipse import ellipses_overlap, enclosing_ellipse
    from ament_formation.core.model.obstacles import first_overlaps, obstacle_arrays, ObstacleSpec

    ellipses_overlap([[0.0, 0.0]], [0.0], [[1.0, 0.5]], [[1.2, 0.0]], [0.5], [[0.5, 0.2]])
    enclosing_ellipse(np.random.default_rng(0).normal(size=(12, 2)))
    c0, vel, amp, omega, phi0, phid, axes, _ = obstacle_arrays(
        [ObstacleSpec('a', (0.0, 0.0), (0.3, 0.1)), ObstacleSpec('b', (0.5, 0.0), (0.3, 0.1))]
    )
    first_overlaps(np.zeros(1), c0, vel, amp, omega, phi0, phid, axes, np.array([[0, 1]]))


def main(argv: list[str] | None = None) -> int:
    """Warm the cache unless it is warm already (``--force``: warm anyway); say so on stderr.

    Cold, on two or more CPUs, the two :data:`PARTS` compile in parallel processes first; then
    one serial pass here loads what they saved and compiles what they did not (numba keeps a
    function's signatures in one index file per function, and two processes saving into it at
    once can each keep only its own: the pass puts back whatever a race dropped).
    ``--part NAME``: compile that part only (what the parallel processes run); no stamp.
    """
    argv = sys.argv[1:] if argv is None else argv
    if '--part' in argv:
        at = argv.index('--part')
        if at + 1 >= len(argv) or argv[at + 1] not in PARTS:
            print(f'jit_warm: --part needs one of {", ".join(PARTS)}', file=sys.stderr)
            return 2
        warm(argv[at + 1])
        return 0
    if is_warm() and '--force' not in argv:
        return 0
    import time

    path = os.environ.get('NUMBA_CACHE_DIR', "numba's default")
    print(f'setup: compiling the numba kernels once (about 3 CPU minutes; cache {path})',
          file=sys.stderr)
    t0 = time.monotonic()
    _warm_parts_in_parallel()
    warm()
    stamp = _warm_stamp()
    if stamp is not None:
        stamp.touch()
    print(f'setup: numba kernels compiled in {time.monotonic() - t0:.0f} s', file=sys.stderr)
    return 0
