"""Run metrics (docs/design.md §4 ``metrics.json``) from a recorded run and its scenario.

Distances use the exact Euclidean signed distance of the controlled point p to the prohibited
ellipse P_j (< 0 inside;
:func:`ament_formation.core.model.ellipse.signed_distance_to_ellipse`), not
the algebraic h. Robot pairs use the robot prohibited circle R_i + R_k + margin (S7).

Conventions (samples k = 0..T-1 at times t_k):

* an *interval* of a boolean signal is a maximal run of true samples; it lasts from its first true
  sample to the first false sample after it (or the last sample);
* ``prohibited_entries`` counts intervals with p inside P_j per (robot, obstacle) and per unordered
  robot pair; ``avoidance_entries`` counts intervals of ``avoiding`` (a re-target inside avoidance
  is not a new entry);
* ``formation_rms_settled_m``: RMS of |p_i - g_i| from 10 s after the last avoidance exit of any
  robot of i's team (or from t0 + 10 s when nobody in the team avoided) to the end; ``None`` when
  that window is empty. A follower's goal g_i hangs on its original parent, so its error includes
  every upstream detour: the formation is settled only when the whole team is (as spec S12
  measures it). ``formation_rms_after_own_exit_m`` is the same RMS from 10 s after the robot's
  own last exit (docs/design.md §4 read per robot).
"""

from __future__ import annotations

import math

import numpy as np

from ament_formation.core.model.ellipse import signed_distance_to_ellipse
from ament_formation.core.sim.trajectory import SimResult

SETTLE_DELAY_S = 10.0


def intervals(flag: np.ndarray, t_s: np.ndarray) -> list[tuple[float, float]]:
    """Maximal true runs of ``flag`` (T,) as (t_start, t_end) [s] (see module conventions)."""
    flag = np.asarray(flag, dtype=bool)
    if flag.size == 0:
        return []
    padded = np.concatenate([[False], flag, [False]])
    change = np.flatnonzero(np.diff(padded.astype(np.int8)))
    starts, stops = change[0::2], change[1::2]  # stop: index of first false sample after
    last = len(t_s) - 1
    return [(float(t_s[a]), float(t_s[min(b, last)])) for a, b in zip(starts, stops)]


def count_entries(flag: np.ndarray) -> int:
    """Number of maximal true runs of ``flag``."""
    flag = np.asarray(flag, dtype=bool)
    if flag.size == 0:
        return 0
    return int(flag[0]) + int(np.count_nonzero(flag[1:] & ~flag[:-1]))


def min_signed_distance(points, centers, phi, r1: float, r2: float) -> tuple[float, np.ndarray]:
    """Minimum over samples of the exact signed distance of ``points`` (T, 2) to one moving ellipse
    (centres (T, 2), orientation (T,), semi-axes r1, r2 [m]), and the inside flags (T,) bool.

    The exact distance (iterative) is evaluated only at samples that can hold the minimum, using
    bounds from the level q = sqrt(h + 1) of the point: the gap between the similar ellipses qE and
    E is at least |q - 1| min(r1, r2), and at most the distance |z| |1 - 1/q| to the radial
    boundary
    point. Same result as evaluating every sample.
    """
    z = np.asarray(points, dtype=float) - np.asarray(centers, dtype=float)
    c, s = np.cos(phi), np.sin(phi)
    u = c * z[:, 0] + s * z[:, 1]
    w = -s * z[:, 0] + c * z[:, 1]
    q = np.sqrt((u / r1) ** 2 + (w / r2) ** 2)
    inside = q < 1.0
    if len(q) == 0:
        return math.inf, inside
    with np.errstate(divide='ignore', invalid='ignore'):
        radial = np.where(
            q > 0.0, np.hypot(u, w) * np.abs(1.0 - 1.0 / q), min(r1, r2)
        )  # centre: r2
    gap = np.abs(q - 1.0) * min(r1, r2)
    lower = np.where(inside, -radial, gap)
    upper = np.where(inside, -gap, radial)
    cand = np.flatnonzero(lower <= np.nanmin(upper) + 1e-12)
    if len(cand) == 0:  # only with non-finite input: evaluate everything
        cand = np.arange(len(q))
    exact = signed_distance_to_ellipse(
        np.asarray(points, dtype=float)[cand],
        np.asarray(centers, dtype=float)[cand],
        np.asarray(phi, dtype=float)[cand],
        r1,
        r2,
    )
    return float(exact.min()), inside


def _obstacle_axes(result: SimResult, scenario) -> np.ndarray:
    by_name = {o.name: o for o in scenario.obstacles}
    return np.array(
        [by_name[name].semi_axes_m for name in result.obstacle_names], dtype=float
    ).reshape(-1, 2)


def pair_distances(result: SimResult, a, b) -> np.ndarray:
    """(T, P) distances |p_a - p_b| [m] of the robot pairs (``a``, ``b``) (P,) (indices)."""
    p = result.state[:, :, :2]
    return np.hypot(p[:, a, 0] - p[:, b, 0], p[:, a, 1] - p[:, b, 1])


def json_ready(value):
    """Numpy scalars/arrays and containers to plain JSON types (non-finite floats to None)."""
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_ready(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        f = float(value)
        return f if math.isfinite(f) else None
    return value


def settle_start(t_s: np.ndarray, exits_s: list[float]) -> float:
    """Start of the settled window: the last exit + SETTLE_DELAY_S, or t0 + SETTLE_DELAY_S."""
    t0 = float(t_s[0]) if len(t_s) else 0.0
    return (max(exits_s) if exits_s else t0) + SETTLE_DELAY_S


def _rms_from(err: np.ndarray, t_s: np.ndarray, start_s: float):
    window = t_s >= start_s - 1e-9
    return float(np.sqrt(np.mean(err[window] ** 2))) if np.any(window) else None


def _team(scenario, rid: int) -> int:
    try:
        return scenario.team_leader(rid)
    except (KeyError, AttributeError):
        return rid


FAR_FROM_GOAL_M = 0.5  # a robot farther from its free goal when the mission ends did not arrive


def goal_in_q(scenario, result: SimResult, i: int) -> bool:
    """Whether robot i's final goal lies inside the protected region Q of an obstacle the law
    avoids (there it cannot settle: it is parked on the limit cycle or beside it). Obstacles
    avoided as one (docs/law-changes.md §18) count as their enclosing ellipse (static).
    """
    law = scenario.avoided_obstacles()
    if not law:
        return False
    g = result.goal_m[-1, i]
    kappa = scenario.avoidance.protected_scale
    rows = {name: j for j, name in enumerate(result.obstacle_names)}
    for obs in law:
        j = rows.get(obs.name)
        if j is None:  # an enclosing ellipse: it stands still
            c, phi = np.asarray(obs.center_m), obs.orientation_rad
        else:
            c, phi = result.obstacle_center_m[-1, j], result.obstacle_phi_rad[-1, j]
        z = g - c
        u = math.cos(phi) * z[0] + math.sin(phi) * z[1]
        w = -math.sin(phi) * z[0] + math.cos(phi) * z[1]
        r1, r2 = kappa * obs.semi_axes_m[0], kappa * obs.semi_axes_m[1]
        if (u / r1) ** 2 + (w / r2) ** 2 <= 1.0:
            return True
    return False


def compute_metrics(result: SimResult, scenario) -> dict:
    """docs/design.md §4 metrics of a run.

    Parameters
    ----------
    result : the recorded run (T samples, N robots, M obstacles)
    scenario : the :class:`~ament_formation.core.scenario.loader.Scenario` it ran (semi-axes of
    P_j,
        body radii and keep-out margin)

    Returns
    -------
    dict with keys scenario, sim_time_s, wall_time_s, prohibited_entries, min_clearance_m,
    min_inter_robot_distance_m, robots, mode_events, graph_events (plus extras:
    prohibited_entry_events, reaching_ratio_max, robot_pair_min_distance_m).
    """
    t = np.asarray(result.t_s, dtype=float)
    ids = list(result.robot_ids)
    names = list(result.obstacle_names)
    n = len(ids)
    by_id = {r.id: r for r in scenario.robots}

    # obstacles: signed distances and entries into P
    axes = _obstacle_axes(result, scenario)
    min_dist = np.full((n, len(names)), np.inf)  # (N, M)
    entries = 0
    entry_events: list[dict] = []
    for i, rid in enumerate(ids):
        for j, name in enumerate(names):
            min_dist[i, j], inside = min_signed_distance(
                result.state[:, i, :2],
                result.obstacle_center_m[:, j],
                result.obstacle_phi_rad[:, j],
                float(axes[j, 0]),
                float(axes[j, 1]),
            )
            for t0, _t1 in intervals(inside, t):
                entry_events.append({'t_s': t0, 'robot': rid, 'target': name})
            entries += count_entries(inside)

    # robot pairs: distances and entries into the robot prohibited circle (S7), all pairs at once
    a_of, b_of = np.triu_indices(n, 1)
    pdist = pair_distances(result, a_of, b_of)  # (T, P)
    radius = np.array([by_id[rid].params.body_radius_m for rid in ids])
    margin = scenario.avoidance.agent_keepout_margin_m
    inside = pdist < (radius[a_of] + radius[b_of] + margin)
    if len(t):
        entries += int(np.count_nonzero(inside[0]) + np.count_nonzero(inside[1:] & ~inside[:-1]))
    for p in np.flatnonzero(inside.any(axis=0)):  # the pairs that entered
        for t0, _t1 in intervals(inside[:, p], t):
            target = f'robot_{ids[b_of[p]]}'
            entry_events.append({'t_s': t0, 'robot': ids[a_of[p]], 'target': target})
    lowest = pdist.min(axis=0) if len(t) else [None] * len(a_of)
    pair_min: dict[str, float] = {
        f'{ids[a]}-{ids[b]}': None if d is None else float(d)
        for a, b, d in zip(a_of, b_of, lowest)
    }
    entry_events.sort(key=lambda e: (e['t_s'], e['robot']))

    err = result.formation_error_m  # (T, N)
    spans_of = {
        rid: intervals(np.asarray(result.avoiding[:, i], dtype=bool), t)
        for i, rid in enumerate(ids)
    }
    team_of = {rid: _team(scenario, rid) for rid in ids}
    robots: dict[str, dict] = {}
    for i, rid in enumerate(ids):
        spans = spans_of[rid]
        own_start = settle_start(t, [b for _a, b in spans])
        team_exits = [b for k in ids if team_of[k] == team_of[rid] for _a, b in spans_of[k]]
        start = settle_start(t, team_exits)
        rms = _rms_from(err[:, i], t, start)
        torque = np.abs(result.torque_nm[:, i, :])
        robots[str(rid)] = {
            'min_clearance_m': {name: float(min_dist[i, j]) for j, name in enumerate(names)},
            'avoidance_time_s': float(sum(b - a for a, b in spans)),
            'avoidance_entries': len(spans),
            'longest_avoidance_s': float(max((b - a for a, b in spans), default=0.0)),
            'avoiding_at_end': bool(len(t) and result.avoiding[-1, i]),
            'formation_rms_settled_m': rms,
            'settled_from_s': float(start),
            'formation_rms_after_own_exit_m': _rms_from(err[:, i], t, own_start),
            'final_error_m': float(err[-1, i]) if len(t) else None,
            'goal_in_q_at_end': bool(len(t)) and goal_in_q(scenario, result, i),
            'peak_torque_nm': [float(torque[:, 0].max()), float(torque[:, 1].max())]
            if len(t)
            else [0.0, 0.0],
            'saturated_fraction': float(np.mean(result.saturated[:, i])) if len(t) else 0.0,
        }

    ratios = [
        r['t_reach_s'] / r['bound_s']
        for r in result.reaching
        if r.get('bound_s') and r.get('t_reach_s') is not None and r['bound_s'] > 0
    ]
    finite_pairs = [v for v in pair_min.values() if v is not None]
    metrics = {
        'scenario': result.scenario_name,
        'sim_time_s': float(t[-1] - t[0]) if len(t) else 0.0,
        'wall_time_s': float(result.wall_time_s),
        'prohibited_entries': int(entries),
        'min_clearance_m': float(min_dist.min()) if min_dist.size else None,
        'min_inter_robot_distance_m': min(finite_pairs) if finite_pairs else None,
        'robots': robots,
        'mode_events': list(result.mode_events),
        'graph_events': list(result.graph_events),
        'prohibited_entry_events': entry_events,
        'robot_pair_min_distance_m': pair_min,
        'reaching_ratio_max': max(ratios) if ratios else None,
        'mission_end_s': getattr(result, 'mission_end_s', None),
        'mission_ratio': None
        if getattr(result, 'mission_end_s', None) is None
        else result.mission_end_s / scenario.duration_s,
    }
    return json_ready({**metrics, **motion_metrics(result, scenario)})


def motion_metrics(result: SimResult, scenario) -> dict:
    """How fast and how far the robots went: ``peak_speed_mps`` {robot: max |v|} and, when the
    scenario declares its floor, ``floor_excursion_m``: the largest distance by which a robot's
    body (radius ``body_radius_m`` around p) reached past the floor's edge (<= 0: always on it).
    """
    ids = list(result.robot_ids)
    speed = np.abs(result.state[:, :, 3]) if len(result.t_s) else np.zeros((1, len(ids)))
    out = {'peak_speed_mps': {str(rid): float(speed[:, i].max()) for i, rid in enumerate(ids)}}
    floor = getattr(scenario, 'floor', None)
    if floor is not None and len(result.t_s):
        radius = {r.id: r.params.body_radius_m for r in scenario.robots}
        rad = np.asarray([radius[rid] for rid in ids])
        x, y = result.state[:, :, 0], result.state[:, :, 1]
        past = np.maximum.reduce(
            [
                floor.x_m[0] - (x - rad),
                x + rad - floor.x_m[1],
                floor.y_m[0] - (y - rad),
                y + rad - floor.y_m[1],
            ]
        )
        out['floor_excursion_m'] = float(past.max())
    return out


# ------------------------------------------------------------------------------------------------
# Checks: what every run must achieve, plus the scenario's ``expect:`` block
# (core/scenario/loader.py)
# ------------------------------------------------------------------------------------------------

COMPLETE_TOLERANCE_S = 0.05  # a run is complete when its mission ended (S17.3)


def check(name: str, ok: bool, value, limit, op: str, detail: str | None = None) -> dict:
    """One check result as written to metrics.json ``checks``: name, ok, value, limit, op (how
    value compares with limit: "<=", ">=", "in", "=="), and an optional one-line detail.
    """
    out = {
        'name': name,
        'ok': bool(ok),
        'value': json_ready(value),
        'limit': json_ready(limit),
        'op': op,
    }
    if detail:
        out['detail'] = detail
    return out


def _le(name, value, limit, missing='not measured'):
    if value is None:
        return check(name, False, None, limit, '<=', missing)
    return check(name, value <= limit, value, limit, '<=')


def _ge(name, value, limit, missing='not measured'):
    if value is None:
        return check(name, False, None, limit, '>=', missing)
    return check(name, value >= limit, value, limit, '>=')


def check_run(
    metrics: dict, scenario, extra: list[dict] | None = None, measured: bool = True
) -> dict:
    """Check a run's ``metrics`` (from :func:`compute_metrics`) and add ``checks``, ``ok`` and
    ``failure`` to it (returned too). ``formation sim`` and ``formation run`` call the same
    function;
    ``extra`` are checks only the caller can make (a process that died, a gap in the recording),
    listed first.

    Every run: ``completed`` (the mission ended: every reference reached its end, S17.3,
    ``mission_end_s`` against its free traversal ``duration_s``), ``prohibited_entries`` (0),
    ``contact``
    (no two robot footprints overlap: |p_a - p_b| >= R_a + R_b for every pair), ``reached_goals``
    (when the mission ended, every robot within :data:`FAR_FROM_GOAL_M` of its goal, a goal inside
    an avoided obstacle's Q excepted: robots that stood still do not pass). Then the scenario's
    ``expect:`` block (:class:`~ament_formation.core.scenario.loader.ExpectSpec`). ``failure`` is
    one line
    naming the failed checks (None when ``ok``). ``measured=False`` (nothing was recorded): only
    ``extra`` and ``completed``.
    """
    checks = list(extra or [])
    end = metrics.get('mission_end_s')
    checks.append(check('completed', end is not None, end, float(scenario.duration_s), '>=',
                        None if end is not None else 'the mission did not end (no team back '
                        'in formation at the end of its reference)'))
    if not measured:
        return _verdict(metrics, checks)
    checks.append(_le('prohibited_entries', metrics.get('prohibited_entries'), 0))

    radius = {str(r.id): r.params.body_radius_m for r in scenario.robots}
    worst = None  # (gap, pair, distance, contact distance)
    for pair, dist in (metrics.get('robot_pair_min_distance_m') or {}).items():
        a, b = pair.split('-')
        touch = radius[a] + radius[b]
        gap = math.inf if dist is None else dist - touch
        if worst is None or gap < worst[0]:
            worst = (gap, pair, dist, touch)
    if worst is not None:
        checks.append(
            check('contact', worst[0] >= 0.0, worst[2], worst[3], '>=', f'robots {worst[1]}')
        )

    robots = metrics.get('robots') or {}
    if end is not None:  # a run that stopped short fails `completed` already
        far = {rid: r['final_error_m'] for rid, r in robots.items()
               if r.get('final_error_m') is not None and not r.get('goal_in_q_at_end')}
        if far:
            rid, err = max(far.items(), key=lambda kv: kv[1])
            checks.append(check('reached_goals', err <= FAR_FROM_GOAL_M, err, FAR_FROM_GOAL_M,
                                '<=', f'R{rid} ends {err:.2f} m from its goal'))
    if getattr(scenario, 'floor', None) is not None:
        checks.append(_le('on_floor', metrics.get('floor_excursion_m'), 0.0))
    e = scenario.expect
    for rid, limit in e.settled_rms_max_m:
        checks.append(
            _le(
                f'settled_rms_m[R{rid}]',
                robots.get(str(rid), {}).get('formation_rms_settled_m'),
                limit,
                missing='no settled window (run shorter than the last avoidance exit + 10 s)',
            )
        )
    for rid, limit in e.final_error_max_m:
        checks.append(
            _le(f'final_error_m[R{rid}]', robots.get(str(rid), {}).get('final_error_m'), limit)
        )
    for rid, (lo, hi) in e.avoidance_entries:
        n = robots.get(str(rid), {}).get('avoidance_entries')
        checks.append(
            check(f'avoidance_entries[R{rid}]', n is not None and lo <= n <= hi, n, [lo, hi], 'in')
        )
    if e.min_clearance_m is not None:
        checks.append(_ge('min_clearance_m', metrics.get('min_clearance_m'), e.min_clearance_m))
    if e.min_inter_robot_distance_m is not None:
        checks.append(
            _ge(
                'min_inter_robot_distance_m',
                metrics.get('min_inter_robot_distance_m'),
                e.min_inter_robot_distance_m,
            )
        )

    return _verdict(metrics, checks)


def _verdict(metrics: dict, checks: list[dict]) -> dict:
    metrics['checks'] = checks
    metrics['ok'] = all(c['ok'] for c in checks)
    metrics['failure'] = (
        None if metrics['ok'] else '; '.join(describe_check(c) for c in checks if not c['ok'])
    )
    return metrics


def _fmt(value) -> str:
    if isinstance(value, float):
        return f'{value:.4g}'
    if isinstance(value, list):
        return '[' + ', '.join(_fmt(v) for v in value) + ']'
    return str(value)


def describe_check(c: dict) -> str:
    """A check as one short phrase: "settled_rms_m[R1] 0.0424 > 0.02" or its detail when no
    value.
    """
    if c.get('value') is None and c.get('detail'):
        return f'{c["name"]}: {c["detail"]}'
    if c['ok']:
        rel = {'<=': '<=', '>=': '>=', 'in': 'in', '==': '=='}[c['op']]
    else:
        rel = {'<=': '>', '>=': '<', 'in': 'not in', '==': '!='}[c['op']]
    text = f'{c["name"]} {_fmt(c["value"])} {rel} {_fmt(c["limit"])}'
    return f'{text} ({c["detail"]})' if c.get('detail') and not c['ok'] else text
