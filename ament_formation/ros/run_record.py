"""A recorded whole-system run (run.mcap) as the core's :class:`SimResult`, so metrics and figures
are computed exactly as for `formation sim` (docs/design.md §4), from the *ground truth* of the
twin.

Sources in the recording:
  /formation/graph          start_s (scenario time t = ROS time - start_s), graph events
  /formation/encounters     the teams' progress rates (a leader's goal is r(s), S17) and the
                            mission's end (the record ends there, or at the last truth sample)
  /world/truth/robot_<id>   states (nav_msgs/Odometry, stamped with the plant time)
  robot_<id>/wheel_torque   commanded torques (zero-order hold between commands)
  robot_<id>/mode           avoidance flags and mode events (log time of reception)
  robot_<id>/wheel_state, robot_<id>/pose   only their stamps (the gaps of each stage of a run)
Samples are taken on a regular grid of ``record_every_s`` from t = 0 to the last truth sample.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ament_formation.core.control.law_params import LawParams
from ament_formation.core.control.progress import new_progress, step
from ament_formation.core.control.rewiring import FormationGraph
from ament_formation.core.model.obstacles import ObstacleField
from ament_formation.core.sim.trajectory import SimResult
from ament_formation.ros import messages as msgs
from ament_formation.ros.recorder import read_messages

_PAUSED = ('stopped', 'hold')  # controller modes of a safety stop / a hold (nodes/controller.py)


def _zoh_index(sample_t: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Index of the last sample at or before each grid time (-1 when none)."""
    return np.searchsorted(sample_t, grid, side='right') - 1


def _read_topics(path, ids, stamps: dict | None = None):
    """The recording's messages by kind: (truth, torque, modes, graphs, decisions).

    truth {id: [(stamp, state)]}, torque {id: [(log time, tau)]}, modes {id: [(log time, mode)]},
    graphs [(log time, GraphMessage)], decisions [(log time, EncountersMessage)]; messages that
    fail to parse are skipped (not the truth).
    ``stamps`` (a dict, filled when given): {(stage, id): [header stamp [s]]} for the stages
    ``torque`` (the controller's command), ``wheel_state`` (the bridge's telemetry), ``pose`` (the
    tracker's), and {'received': [log time [s]]} of every truth, torque and wheel state message.
    """
    truth: dict[int, list] = {rid: [] for rid in ids}
    torque: dict[int, list] = {rid: [] for rid in ids}
    modes: dict[int, list] = {rid: [] for rid in ids}
    graphs: list[tuple[float, msgs.GraphMessage]] = []
    decisions: list[tuple[float, msgs.EncountersMessage]] = []
    truth_topics = {f'/world/truth/robot_{rid}': rid for rid in ids}
    torque_topics = {f'/robot_{rid}/wheel_torque': rid for rid in ids}
    mode_topics = {f'/robot_{rid}/mode': rid for rid in ids}
    stage_topics = {}
    if stamps is not None:
        stage_topics = {f'/robot_{rid}/{stage}': (stage, rid) for rid in ids for stage in _STAGES}
        stamps.setdefault('received', [])
    wanted = ['/formation/graph', '/formation/encounters', *truth_topics, *torque_topics,
              *mode_topics, *stage_topics]
    for topic, log_ns, msg in read_messages(path, wanted):
        if topic in truth_topics:
            state, stamp = msgs.state_from_odometry(msg)
            truth[truth_topics[topic]].append((stamp, state))
            if stamps is not None:
                stamps['received'].append(log_ns * 1e-9)
        elif topic in torque_topics:
            try:
                tau, stamp = msgs.torque_from_msg(msg)
            except ValueError:
                continue
            torque[torque_topics[topic]].append((log_ns * 1e-9, tau))
            if stamps is not None:
                stamps.setdefault(('torque', torque_topics[topic]), []).append(stamp)
                stamps['received'].append(log_ns * 1e-9)
        elif topic in stage_topics:
            stamps.setdefault(stage_topics[topic], []).append(msgs.stamp_to_s(msg.header.stamp))
            if stage_topics[topic][0] == 'wheel_state':
                stamps['received'].append(log_ns * 1e-9)
        elif topic in mode_topics:
            try:
                modes[mode_topics[topic]].append((log_ns * 1e-9, msgs.mode_from_msg(msg)))
            except ValueError:
                continue
        elif topic == '/formation/encounters':
            try:
                decisions.append((log_ns * 1e-9, msgs.encounters_from_msg(msg)))
            except ValueError:
                continue
        else:
            try:
                graphs.append((log_ns * 1e-9, msgs.graph_from_msg(msg)))
            except ValueError:
                continue
    return truth, torque, modes, graphs, decisions


_STAGES = ('wheel_state', 'pose')  # read for their stamps only (besides torque)


def _stage_gaps(stamps: dict, ids, start_s: float, t_end: float) -> dict:
    """The longest pause [s] of each stage on [0, t_end] of scenario time: ``control_stamp``
    {id: of the torque commands' stamps (the controller stopped commanding)}, ``wheel_state``
    {id} (the bridge or the twin's board stopped), ``pose`` {id} (the camera or the tracker
    stopped), and ``recording`` (no truth, torque or wheel state message received by the
    recorder at all: the recorder, or the whole system, stopped).
    """
    out: dict = {}
    stages = (('torque', 'control_stamp'), ('wheel_state', 'wheel_state'), ('pose', 'pose'))
    for stage, key in stages:
        out[key] = {
            str(rid): _max_gap([t - start_s for t in stamps.get((stage, rid), [])], t_end)
            for rid in ids
        }
    out['recording'] = _max_gap([t - start_s for t in stamps.get('received', [])], t_end)
    return out


def _mission_start(path, graphs, truth: dict, ids) -> float:
    """start_s of the first graph message that has one; ValueError when none, or when a robot
    has no ground truth.
    """
    starts = [g.start_s for _, g in graphs if g.start_s is not None]
    if not starts:
        raise ValueError(f'{path}: no /formation/graph with a mission start (start_s)')
    start_s = starts[0]
    if any(not truth[rid] for rid in ids):
        missing = [rid for rid in ids if not truth[rid]]
        raise ValueError(f'{path}: no ground truth for robots {missing}')
    return start_s


def _sample_truth(truth_rid: list, start_s: float, grid: np.ndarray) -> np.ndarray:
    """One robot's ground-truth state on the grid (zero-order hold, the first sample before)."""
    ts = np.array([s for s, _ in truth_rid]) - start_s
    order = np.argsort(ts, kind='stable')
    ts, xs = ts[order], np.stack([x for _, x in truth_rid])[order]
    idx = np.clip(_zoh_index(ts, grid + 1e-9), 0, len(ts) - 1)
    return xs[idx]


def _sample_torque(torque_rid: list, start_s: float, grid: np.ndarray) -> np.ndarray:
    """One robot's commanded torques on the grid (zero-order hold, zero before the first)."""
    tt = np.array([s for s, _ in torque_rid]) - start_s
    tv = np.stack([v for _, v in torque_rid])
    j = _zoh_index(tt, grid)
    return np.where((j >= 0)[:, None], tv[np.clip(j, 0, None)], 0.0)


def _robot_modes(rid: int, modes_rid: list, start_s: float):
    """One robot's mode messages as (mode events, safety stops, avoidance flag times, flags).

    A safety stop or hold pauses the robot, not its avoidance decision (see load_run); a stop
    still under way at the end of the recording ends at None.
    """
    mode_events: list[dict] = []
    stops: list = []
    prev = None
    flags_t, flags_v = [], []
    stop_from = None
    for s, mode in modes_rid:
        t = s - start_s
        if mode.get('mode') in _PAUSED and prev is not None and t >= 0.0:
            # a safety stop or a hold pauses the robot, not its avoidance decision: the
            # avoidance it resumes is the same entry (stop-and-go is counted in safety_stops)
            if stop_from is None:
                stop_from = t
            flags_t.append(t)
            flags_v.append(prev[0])
            continue
        if stop_from is not None:
            stops.append((stop_from, t))
            stop_from = None
        av = bool(
            mode.get('avoiding', mode.get('mode') not in ('coordination', 'hold', 'stopped'))
        )
        key = (av, mode.get('target'), mode.get('direction')) if av else (False, None, None)
        if key != prev and t >= 0.0:
            if prev is not None and prev[0]:
                mode_events.append(
                    {
                        't_s': t,
                        'robot': rid,
                        'event': 'exit',
                        'target': prev[1],
                        'direction': prev[2],
                    }
                )
            if av:
                mode_events.append(
                    {
                        't_s': t,
                        'robot': rid,
                        'event': 'enter',
                        'target': mode.get('target'),
                        'direction': mode.get('direction'),
                    }
                )
        if t >= 0.0 or prev is None:
            prev = key
        flags_t.append(t)
        flags_v.append(av)
    if stop_from is not None:
        stops.append((stop_from, None))  # still stopped at the end of the recording
    return mode_events, stops, flags_t, flags_v


def _progress(scenario, index: dict, grid: np.ndarray, decisions: list, start_s: float):
    """(T, N) the progress s of each leader's reference on the grid (0 for followers): the rate
    targets the coordinator published (S17.2), followed as a leader's agent follows them.
    """
    law = LawParams.for_scenario(scenario).compiled()
    n = len(index)
    pr = new_progress(n)
    out = np.zeros((len(grid), n))
    times = np.array([s - start_s for s, _ in decisions])
    leaders = [index[r.id] for r in scenario.robots if r.leader]
    rows = {index[r.id]: r.id for r in scenario.robots if r.leader}
    for q, t in enumerate(grid):
        j = int(np.searchsorted(times, t, side='right')) - 1
        for i in leaders:
            target = decisions[j][1].rates.get(rows[i], 1.0) if j >= 0 else 1.0
            step(pr, i, 0.0 if q == 0 else grid[q] - grid[q - 1], target, scenario.duration_s,
                 law)
            out[q, i] = pr.s[i]
    return out


def _goals(scenario, index: dict, grid: np.ndarray, state: np.ndarray,
           progress: np.ndarray) -> np.ndarray:
    """Goals: leader r(s) at its progress (S17); follower p of its original parent + delta
    (S1).
    """
    graph = FormationGraph.from_scenario(scenario)
    goal = np.zeros((len(grid), len(index), 2))
    for r in scenario.robots:
        k = index[r.id]
        if r.leader and r.path is not None:
            goal[:, k] = np.asarray(r.path.reference(progress[:, k])[0]).reshape(-1, 2)
        else:
            parent = graph.original_parent[r.id]
            goal[:, k] = state[:, index[parent], :2] + graph.offset(r.id, parent)
    return goal


def _obstacle_samples(scenario, grid: np.ndarray):
    """(field, centres (T, M, 2), orientations (T, M)) of the scenario's obstacles on the grid."""
    field = ObstacleField(scenario.obstacles)
    m = len(field)
    oc = np.zeros((len(grid), m, 2))
    ophi = np.zeros((len(grid), m))
    if m:
        for i, t in enumerate(grid):
            o = field.at(float(t))
            oc[i], ophi[i] = o.center_m, o.phi_rad
    return field, oc, ophi


def _graph_events(graphs: list, start_s: float) -> list[dict]:
    """The graph messages as events: one per change of the parents, repeats skipped."""
    graph_events = []
    last_rev = None
    for s, g in graphs:
        if g.revision == last_rev or s - start_s < -1e-9 and graph_events:
            continue
        if (
            last_rev is not None
            and graph_events
            and graph_events[-1]['parents'] == _parents_json(g.parents)
        ):
            last_rev = g.revision
            continue
        last_rev = g.revision
        graph_events.append({'t_s': max(0.0, s - start_s), 'parents': _parents_json(g.parents)})
    return graph_events


def load_run(
    path: str | Path, scenario, record_every_s: float = 0.01, stats: dict | None = None,
    hold_s: float = 0.0,
) -> SimResult:
    """Read ``path`` (run.mcap) into a SimResult on scenario time, up to the mission's end plus
    ``hold_s`` (or the last ground truth); ValueError when the recording lacks the mission start
    or the ground truth.

    ``stats`` (a dict, filled when given): ``truth_max_gap_s`` the longest pause [s, scenario time]
    between consecutive ground-truth samples of any robot from t = 0 to the end of the recording
    (the world or the recorder stalled), ``truth_max_gap_at_s`` where it starts,
    ``truth_end_s`` the scenario time of the last sample every robot has, and ``torque_max_gap_s``
    {robot id: the longest pause [s] of its recorded wheel_torque commands over the same span,
    the end included (a stalled or dead controller)}, ``stage_gaps`` (the longest pause of each
    stage of the run, :func:`_stage_gaps`), ``safety_stops`` {robot id: [(from_s, to_s)]
    intervals of scenario time in which its controller reported a safety stop or hold}.

    Avoidance (``avoiding``, mode events) follows the controllers' mode messages; a safety stop or
    hold in the middle of an avoidance does not end it (the robot resumes the same avoidance), so
    ``avoidance_entries`` counts avoidance decisions, and stop-and-go shows in ``safety_stops``.
    """
    ids = tuple(r.id for r in scenario.robots)
    index = {rid: k for k, rid in enumerate(ids)}
    stamps: dict | None = {} if stats is not None else None
    truth, torque, modes, graphs, decisions = _read_topics(path, ids, stamps)
    start_s = _mission_start(path, graphs, truth, ids)
    ends = [m.mission_end_s for _, m in decisions if m.mission_end_s is not None]
    mission_end = ends[0] if ends else None

    t_end = min(max(s for s, _ in truth[rid]) for rid in ids) - start_s
    if stats is not None:
        stats.update(_truth_gaps(truth, ids, start_s, t_end))
        stats['torque_max_gap_s'] = {
            rid: _max_gap([s - start_s for s, _ in torque[rid]], t_end) for rid in ids
        }
    if mission_end is not None:
        t_end = min(t_end, mission_end + hold_s)
    if stats is not None:
        stats['stage_gaps'] = _stage_gaps(stamps, ids, start_s, t_end)
    grid = np.arange(0.0, max(t_end, 0.0) + 1e-9, record_every_s)
    n, big_t = len(ids), len(grid)
    state = np.zeros((big_t, n, 5))
    tau = np.zeros((big_t, n, 2))
    avoiding = np.zeros((big_t, n), dtype=bool)
    mode_events: list[dict] = []
    stops: dict[int, list] = {}
    for rid in ids:
        k = index[rid]
        state[:, k] = _sample_truth(truth[rid], start_s, grid)
        if torque[rid]:
            tau[:, k] = _sample_torque(torque[rid], start_s, grid)
        events, stops[rid], flags_t, flags_v = _robot_modes(rid, modes[rid], start_s)
        mode_events.extend(events)
        if flags_t:
            j = _zoh_index(np.array(flags_t), grid)
            avoiding[:, k] = np.where(j >= 0, np.array(flags_v)[np.clip(j, 0, None)], False)
    if stats is not None:
        stats['safety_stops'] = {
            rid: [
                (a, min(b, t_end) if b is not None else t_end) for a, b in stops[rid] if a <= t_end
            ]
            for rid in ids
        }
    mode_events.sort(key=lambda e: (e['t_s'], e['robot']))

    tau_max = np.array([r.params.torque_limit_nm for r in scenario.robots])
    saturated = np.max(np.abs(tau), axis=2) >= tau_max[None, :] * (1.0 - 1e-6)
    progress = _progress(scenario, index, grid, decisions, start_s)
    goal = _goals(scenario, index, grid, state, progress)
    field, oc, ophi = _obstacle_samples(scenario, grid)
    graph_events = _graph_events(graphs, start_s)

    return SimResult(
        scenario_name=scenario.name,
        robot_ids=ids,
        obstacle_names=field.names,
        t_s=grid,
        state=state,
        torque_nm=tau,
        goal_m=goal,
        avoiding=avoiding,
        saturated=saturated,
        obstacle_center_m=oc,
        obstacle_phi_rad=ophi,
        mode_events=mode_events,
        graph_events=graph_events,
        dt_s=record_every_s,
        mission_end_s=mission_end,
        nominal_duration_s=float(scenario.duration_s),
        progress_s=progress,
    )


def _truth_gaps(truth: dict, ids, start_s: float, t_end: float) -> dict:
    """Longest gap between ground-truth stamps on [0, t_end] of scenario time (see load_run)."""
    worst, at = 0.0, None
    for rid in ids:
        ts = np.sort(np.array([s for s, _ in truth[rid]]) - start_s)
        ts = np.concatenate([[0.0], ts[(ts > 0.0) & (ts <= t_end)]])
        if len(ts) > 1:
            gaps = np.diff(ts)
            k = int(np.argmax(gaps))
            if gaps[k] > worst:
                worst, at = float(gaps[k]), float(ts[k])
    return {'truth_max_gap_s': worst, 'truth_max_gap_at_s': at, 'truth_end_s': float(t_end)}


def _max_gap(times_s, t_end: float) -> float:
    """Longest pause [s] between the sample times on [0, t_end], counting 0 and t_end as edges."""
    ts = np.sort(np.asarray(times_s, dtype=float))
    ts = np.concatenate([[0.0], ts[(ts > 0.0) & (ts < t_end)], [max(t_end, 0.0)]])
    return float(np.max(np.diff(ts)))


def _parents_json(parents: dict) -> dict:
    return {str(c): (None if p is None else int(p)) for c, p in sorted(parents.items())}
