"""Benchmark of the closed-loop simulator (ament_formation.core.sim.simulator).

Prints a table:
1. JIT compile time (first call in a fresh process with an empty numba cache) versus the steady
   state;
2. paper.yaml (55 s at 1 kHz, 2 robots): whole closed loop incl. switching + metrics, wall time;
3. N = 1000 robots (100 random ten-robot formations among random obstacles) for a few simulated
   seconds: robot-steps/s of the compiled loop, against a per-robot scalar Python loop of the same
   law (``robot_law`` and the RK4/disturbance kernels called robot by robot from Python) in the
   same run, as a ratio.

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
    """Robot-steps/s of a per-robot scalar Python loop over the same law (robot_law + RK4
    kernels).
    """
    from ament_formation.core.control.automaton import AutomatonState, SwitchingParams
    from ament_formation.core.control.law import LawRobots, robot_law, Tracking
    from ament_formation.core.model.disturbance import disturbance_k
    from ament_formation.core.model.dynamics import rk4_step_k, RobotPlant
    from ament_formation.core.model.obstacles import obstacle_states, ObstacleSnapshot
    from ament_formation.core.sim import simulator as S

    setup = S._Setup(scenario, 0.001, SwitchingParams(avoidance=scenario.avoidance))
    n = setup.n
    x = setup.state.copy()
    acmd = np.zeros((n, 2))
    pd = np.zeros((n, 2))
    goal = np.zeros((n, 2))
    goal_dot = np.zeros((n, 2))
    parents = setup.graph.rewire(set())
    parent, offset, order = setup.parents_from(parents)
    tab = setup.reference_table(0, n_steps + 1, 0.001)
    ref = np.zeros((n, 6))
    m = len(setup.obstacle_names)
    oc, ov, oa = np.zeros((m, 2)), np.zeros((m, 2)), np.zeros((m, 2))
    ophi, ophid, ophidd = np.zeros(m), np.zeros(m), np.zeros(m)
    law = robot_law
    robots = LawRobots(x, pd, acmd, setup.rbody, setup.coeffs)
    tracking = Tracking(parent, offset, ref, goal, goal_dot)
    automaton = AutomatonState(n).arrays()
    obs_now = ObstacleSnapshot(oc, ov, oa, ophi, ophid, ophidd, setup.oaxes, setup.ostatic)
    t0 = time.perf_counter()
    for k in range(n_steps):
        t = k * 0.001
        obstacle_states(
            t,
            setup.ob_c0,
            setup.ob_v,
            setup.ob_amp,
            setup.ob_w,
            setup.ob_phi0,
            setup.ob_phid,
            oc,
            ov,
            oa,
            ophi,
            ophid,
            ophidd,
        )
        S.reference_at(k, S.REF_SUB, 0.001, tab, ref, setup.leader_rows)
        for i in range(n):
            pd[i] = S.point_velocity_k(x[i, 2], x[i, 3], x[i, 4], setup.coeffs[4, i])
        for i in order:
            out = law(i, t, robots, tracking, automaton, obs_now, setup.gains, setup.prm)
            acmd[i, 0], acmd[i, 1] = out[5], out[6]
            g0 = disturbance_k(t, setup.d_amp[i], setup.d_freq[i], setup.d_phase[i])
            gh = disturbance_k(t + 0.0005, setup.d_amp[i], setup.d_freq[i], setup.d_phase[i])
            g1 = disturbance_k(t + 0.001, setup.d_amp[i], setup.d_freq[i], setup.d_phase[i])
            c = setup.coeffs[:, i]
            x[i] = rk4_step_k(tuple(x[i]), (out[0], out[1]), g0, gh, g1, 0.001, RobotPlant(*c[:6]))
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
    rows.append(
        (
            'paper.yaml 55 s @ 1 kHz, 2 robots, sim + metrics',
            f'{best:8.3f} s',
            f'{paper.duration_s / best:6.0f}x real time (target <= 1 s)',
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
    steps = int(round(args.seconds / 0.001))
    rate = n * steps / wall
    enters = sum(1 for e in res.mode_events if e['event'] == 'enter')
    base = scalar_baseline(sc, args.baseline_steps)
    rows.append(
        (
            f'N = {n} robots, {len(sc.obstacles)} obstacles, {args.seconds:g} s @ 1 kHz',
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
