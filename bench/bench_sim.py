"""Benchmark of the closed-loop simulator (ament_formation.core.sim.simulator).

Prints a table:
1. JIT compile time (first call in a fresh process with an empty numba cache) versus the steady
   state;
2. paper.yaml (its mission, >= 55 s at 1 kHz, 2 robots): whole closed loop incl. switching +
   metrics, wall time;
3. N = 1000 robots (100 random ten-robot formations among random obstacles) for a mission of a few
   seconds (the run lasts until it ends): robot-steps/s of the compiled loop, against a per-robot
   scalar Python loop of the same law (``goal_k``, ``robot_law_k`` and the RK4/disturbance
   kernels called robot by robot from Python) in the same run, as a ratio.

Run: .venv/bin/python bench/bench_sim.py [--robots 1000] [--seconds 3] [--no-compile]
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np


def random_formations(n_robots: int, seed: int = 0, duration_s: float = 3.0) -> dict:
    """A scenario mapping: teams of ten (leader + 9 followers, 0.5 m grid) on a 4 m lattice, each
    heading +x at 0.05 m/s with an obstacle 0.45-0.8 m ahead of its leader and one on a wing.
    """
    rng = np.random.default_rng(seed)
    team_size = 10
    n_teams = max(1, n_robots // team_size)
    cols = int(math.ceil(math.sqrt(n_teams)))
    robots, edges, obstacles = [], [], []
    slots = [(0.0, 0.0)] + [(-0.5 * (1 + q // 3), 0.5 * (q % 3 - 1)) for q in range(9)]
    rid = 0
    for team in range(n_teams):
        ox, oy = 4.0 * (team % cols), 4.0 * (team // cols)
        lead = rid
        for q, (sx, sy) in enumerate(slots):
            entry = {
                'id': rid,
                'slot_m': [sx, sy],
                'marker_id': rid,
                'initial_pose': [
                    ox + sx + rng.normal(0, 0.02),
                    oy + sy + rng.normal(0, 0.02),
                    rng.normal(0, 0.05),
                ],
            }
            if q == 0:
                entry.update(
                    leader=True,
                    path={
                        'type': 'line',
                        'start_m': [ox, oy],
                        'heading_rad': 0.0,
                        'speed_mps': 0.05,
                    },
                )
            else:
                parent = lead if q <= 3 else rid - 3
                edges.append([parent, rid])
            robots.append(entry)
            rid += 1
        obstacles.append(
            {
                'name': f'O{team}a',
                'center_m': [ox + rng.uniform(0.5, 0.7), oy + rng.uniform(-0.1, 0.1)],
                'semi_axes_m': [0.25, 0.12],
                'orientation_rad': float(rng.uniform(0, math.pi)),
                'angular_velocity_radps': float(rng.choice([0.0, 0.05])),
            }
        )
        obstacles.append(
            {
                'name': f'O{team}b',
                'center_m': [ox + 0.2, oy + rng.uniform(1.3, 1.5)],
                'semi_axes_m': [0.2, 0.12],
                'orientation_rad': 0.0,
                'velocity_mps': [0.0, -0.02],
            }
        )
    return {
        'name': f'random{len(robots)}',
        'duration_s': duration_s,
        'robots': robots,
        'graph': {'edges': edges},
        'obstacles': obstacles,
        'disturbance': {'accel_bound': [0.05, 0.5], 'seed': seed},
    }


def scalar_baseline(scenario, n_steps: int) -> float:
    """Robot-steps/s of a per-robot scalar Python loop over the same law: per step, from Python,
    the obstacles, each leader's reference at its nominal progress, and robot by robot its goal
    (goal_k), its torque (robot_law_k, in coordination, against its neighbour list of the last
    decision), the disturbance and its RK4 step (the compiled kernels the simulator runs).
    """
    from ament_formation.core.control.law import goal_k, mode_row, robot_law_k, RobotTracking
    from ament_formation.core.control.law_params import LawParams
    from ament_formation.core.control.progress import leader_reference, tabulate
    from ament_formation.core.control.switching import new_modes
    from ament_formation.core.model.disturbance import disturbance_k
    from ament_formation.core.model.dynamics import (
        point_velocity_k,
        rk4_step_k,
        robot_plant_k,
        ROW_D,
    )
    from ament_formation.core.model.obstacles import obstacle_states, ObstacleSnapshot
    from ament_formation.core.sim import simulator as S

    dt = 0.001
    law = LawParams.for_scenario(scenario)
    setup = S._Setup(scenario, dt, law)
    prm, plant, oa = setup.prm, setup.plant, setup.obstacles
    dec_every = max(1, int(round(law.decision_period_s / dt)))
    n = setup.n
    x = setup.state0.copy()
    acmd, pd, ref = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 6))
    torque = np.zeros((n, 2))
    parent, offset, order = setup.parents_from(setup.graph.rewire(set()))
    refs = tabulate(setup.paths, scenario.duration_s)
    modes = new_modes(n)
    known = np.ones(n, dtype=np.bool_)
    m = oa.axes.shape[0]
    ob = ObstacleSnapshot(np.zeros((m, 2)), np.zeros((m, 2)), np.zeros((m, 2)), np.zeros(m),
                          np.zeros(m), np.zeros(m), oa.axes, oa.static)
    t0 = time.perf_counter()
    for k in range(n_steps + 1):  # step 0 loads the compiled kernels: not timed
        if k == 1:
            t0 = time.perf_counter()
        t = k * dt
        obstacle_states(t, oa.c0, oa.v, oa.amp, oa.w, oa.phi0, oa.phid, ob.c, ob.v, ob.a, ob.phi,
                        ob.phi_dot, ob.phi_ddot)
        if k % dec_every == 0:
            nb = S.neighbour_lists(x[:, :2].copy(), known, plant.rbody, prm, ob.c, oa,
                                   dec_every * dt)
        for i in range(n):
            pd[i] = point_velocity_k(x[i, 2], x[i, 3], x[i, 4], plant.coeffs[ROW_D, i])
        for i in setup.leaders:
            leader_reference(refs, i, t, 1.0, 0.0, ref[i])
        for i in order:  # parents first (S4 feed-forward of this sample's a_j)
            gx, gy, gdx, gdy, _vx, _vy = goal_k(i, x, pd, ref, setup.orig_parent,
                                                setup.orig_offset, prm)
            track = RobotTracking(int(parent[i]), (offset[i, 0], offset[i, 1]),
                                  tuple(float(v) for v in ref[i]), (gx, gy), (gdx, gdy))
            out = robot_law_k(i, t, x, pd, acmd, plant.rbody, plant.coeffs, ob,
                              nb.idx[nb.start[i]:nb.start[i + 1]],
                              nb.ob_idx[nb.ob_start[i]:nb.ob_start[i + 1]], track,
                              mode_row(modes, i), prm)
            torque[i] = out[0], out[1]
            acmd[i] = out[5], out[6]
        for i in range(n):
            g0 = disturbance_k(t, plant.d_amp[i], plant.d_freq[i], plant.d_phase[i])
            gh = disturbance_k(t + 0.5 * dt, plant.d_amp[i], plant.d_freq[i], plant.d_phase[i])
            g1 = disturbance_k(t + dt, plant.d_amp[i], plant.d_freq[i], plant.d_phase[i])
            x[i] = rk4_step_k(tuple(x[i]), (torque[i, 0], torque[i, 1]), g0, gh, g1, dt,
                              robot_plant_k(plant.coeffs, i))
    return n * n_steps / (time.perf_counter() - t0)


def compile_times() -> tuple[float, float]:
    """(first call [s], second call [s], child CPU [s]) of simulate(paper) in a fresh process with
    an empty numba cache.
    """
    code = (
        'import time;from ament_formation.core.scenario.loader import load_scenario;'
        'from ament_formation.core.config_files import config_file;'
        'from ament_formation.core.sim.simulator import simulate;'
        "sc=load_scenario(config_file('scenarios/paper.yaml'));"
        't=time.perf_counter();simulate(sc);a=time.perf_counter()-t;'
        't=time.perf_counter();simulate(sc);b=time.perf_counter()-t;print(a,b)'
    )
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=tmp)
        out = subprocess.run(
            [sys.executable, '-c', code], env=env, capture_output=True, text=True, check=True
        ).stdout.split()
    cpu = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime - before
    return float(out[0]), float(out[1]), cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--robots', type=int, default=1000)
    ap.add_argument('--seconds', type=float, default=3.0, help='simulated time of the N-robot run')
    ap.add_argument('--baseline-steps', type=int, default=5)
    ap.add_argument('--no-compile', action='store_true', help='skip the cold-cache compile run')
    args = ap.parse_args()

    from ament_formation.core.config_files import config_file
    from ament_formation.core.scenario.loader import load_scenario, parse_scenario
    from ament_formation.core.sim.metrics import compute_metrics
    from ament_formation.core.sim.simulator import simulate

    rows = []
    if not args.no_compile:
        first, second, cpu = compile_times()
        rows.append(
            (
                'JIT compile + first paper run (cold cache)',
                f'{first:8.2f} s',
                f'whole child process {cpu:.1f} CPU s (incl. imports)',
            )
        )
        rows.append(
            (
                'second paper run, same process',
                f'{second:8.3f} s',
                f'compile ~ {first - second:.1f} s',
            )
        )
    paper = load_scenario(config_file('scenarios/paper.yaml'))
    simulate(paper)  # warm (loads the numba cache)
    best = math.inf
    for _ in range(3):
        t0 = time.perf_counter()
        res = simulate(paper)
        m = compute_metrics(res, paper)
        best = min(best, time.perf_counter() - t0)
    paper_s = res.mission_end_s if res.mission_end_s is not None else float(res.t_s[-1])
    rows.append(
        (
            f'paper.yaml mission {paper_s:.1f} s @ 1 kHz, 2 robots, sim + metrics',
            f'{best:8.3f} s',
            f'{paper_s / best:6.0f}x real time (target <= 1 s)',
        )
    )

    sc = parse_scenario(random_formations(args.robots, duration_s=args.seconds))
    n = len(sc.robots)
    simulate(parse_scenario(random_formations(20, duration_s=0.05)))  # warm
    t0 = time.perf_counter()
    c0 = time.process_time()
    res = simulate(sc, record_every_s=0.1)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    from ament_formation.core.control.progress import max_time_s

    # the run lasts until its mission ends (or the simulator's cap when it does not)
    sim_s = res.mission_end_s if res.mission_end_s is not None else max_time_s(args.seconds)
    steps = int(round(sim_s / 0.001))
    rate = n * steps / wall
    enters = sum(1 for e in res.mode_events if e['event'] == 'enter')
    base = scalar_baseline(sc, args.baseline_steps)
    rows.append(
        (
            f'N = {n} robots, {len(sc.obstacles)} obstacles, mission {sim_s:.2f} s @ 1 kHz',
            f'{wall:8.2f} s',
            f'{rate / 1e6:6.2f} M robot-steps/s wall '
            f'({n * steps / cpu / 1e6:.2f} M/s per CPU s; target >= 1 M); '
            f'{enters} avoidance entries, decisions at 100 Hz',
        )
    )
    rows.append(
        (
            '  per-robot scalar Python loop, same law',
            f'{base / 1e3:8.1f} k/s',
            f'compiled / scalar = {rate / base:6.0f}x',
        )
    )
    width = max(len(r[0]) for r in rows)
    print(f'{"case".ljust(width)}  {"result":>10}  notes')
    for name, value, note in rows:
        print(f'{name.ljust(width)}  {value:>10}  {note}')
    assert m['prohibited_entries'] == 0


if __name__ == '__main__':
    main()
