"""Who should decide robot-robot encounters? A measurement on the law of 513794e (issue 32).

`bench/run.sh bench_authority.py [--count 60] [--seed 7] [--families two_teams,crossing]`
runs the same generated scenarios with camera sensing twice:

* ``robots``: every robot decides its encounters itself on its own estimates (the coordinator's
  arbitration off, ``encounter_rate_hz = 0``): a rule that each robot computes on what it hears;
* ``coordinator``: as the system runs today (the coordinator assigns, a robot decides its own
  encounters in emergencies).

and reports, per setting, how often two robots disagree about their pair: the fraction of
encounter time (summed over robots, sampled every control period from each robot's own mode
events) in which robot i is in a mutual pair with k while k is not in a mutual pair with i, or i
yields to k while k yields to i (a loop), plus the campaign classes of the runs.
"""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import replace
from pathlib import Path
import sys
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ament_formation.core.scenario import families  # noqa: E402
from ament_formation.core.scenario.loader import parse_scenario  # noqa: E402
from ament_formation.core.sim import sensed  # noqa: E402
from ament_formation.core.sim.campaign import findings  # noqa: E402
from ament_formation.core.sim.metrics import compute_metrics  # noqa: E402


def timelines(result, dt_s: float = 0.01):
    """{robot id: (mode array, target array)} sampled every dt_s from the mode events."""
    t = np.arange(0.0, float(result.t_s[-1]) + 1e-9, dt_s)
    out = {}
    for rid in result.robot_ids:
        mode = np.zeros(t.size, dtype=np.int64)  # 0 C, 1 obstacle, 2 yield, 3 mutual
        tgt = np.full(t.size, -1, dtype=np.int64)
        for e in (e for e in result.mode_events if e['robot'] == rid):
            k = int(np.searchsorted(t, e['t_s'] - 1e-9))
            if e['event'] == 'enter':
                m = {'obstacle': 1, 'yield': 2, 'mutual': 3}[e['mode']]
                target = e['target']
                tid = int(target.split('_')[1]) if target.startswith('robot_') else -2
                mode[k:] = m
                tgt[k:] = tid
            else:
                mode[k:] = 0
                tgt[k:] = -1
        out[rid] = (mode, tgt)
    return out


def disagreement(result) -> tuple[float, float]:
    """(seconds of robot-robot encounter summed over robots, seconds of them in disagreement)."""
    tl = timelines(result)
    total = 0.0
    bad = 0.0
    for rid, (mode, tgt) in tl.items():
        robot = (mode == 2) | (mode == 3)
        total += robot.sum() * 0.01
        for k in set(tgt[robot].tolist()):
            if k not in tl:
                continue
            km, kt = tl[k]
            sel = robot & (tgt == k)
            mutual_broken = sel & (mode == 3) & ~((km == 3) & (kt == rid))
            yield_loop = sel & (mode == 2) & (km == 2) & (kt == rid)
            bad += (mutual_broken | yield_loop).sum() * 0.01
    return total, bad


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--count', type=int, default=60)
    ap.add_argument('--seed', type=int, default=7)
    ap.add_argument('--families', default='two_teams,crossing')
    ap.add_argument('--settings', default='robots,coordinator',
                    help='robots (every robot decides its encounters: the law of 513794e '
                    'only), coordinator')
    args = ap.parse_args()
    fams = args.families.split(',')
    settings = {
        name: sensed.SensingParams.preset('camera', encounter_rate_hz=rate)
        for name, rate in (('robots', 0.0), ('coordinator', 50.0))
        if name in args.settings.split(',')
    }
    for name, base in settings.items():
        total = bad = 0.0
        classes = Counter()
        t0 = time.monotonic()
        for idx in range(args.count):
            fam = fams[idx % len(fams)]
            mapping, _ = families.generate(fam, args.seed, idx)
            scenario = parse_scenario(mapping)
            res = sensed.simulate_sensed(scenario, replace(base, seed=idx))
            a, b = disagreement(res)
            total += a
            bad += b
            found = findings(compute_metrics(res, scenario), res, scenario)
            classes.update(found.keys())
        print(
            f'{name:12s} runs {args.count}  robot-encounter time {total:8.1f} s  '
            f'disagreeing {bad:7.1f} s ({100 * bad / max(total, 1e-9):.1f} %)  '
            f'classes {dict(classes)}  wall {time.monotonic() - t0:.0f} s',
            flush=True,
        )
    return 0


if __name__ == '__main__':
    sys.exit(main())
