"""The closed loop with what the robots really have (issue 13: sensing in the fast simulator).

Where :func:`ament_formation.core.sim.simulator.simulate` closes the loop on the TRUE state at
every 1 ms step, :func:`simulate_sensed` runs each robot as the ROS system does, with the same core
objects the nodes hold:

* camera: every robot's pose of p captured at the scenario's ``camera.fps`` (or ``fps``), with
  Gaussian noise (``noise_m`` per axis, ``noise_rad`` on the heading), lost with probability
  ``drop_prob`` per robot and frame, delivered ``latency_s`` after capture with its capture stamp
  (the tracker's PoseStamped, docs/design.md §6);
* each robot's agent (core/control/agent.py, what nodes/controller.py runs: the S10.1
  estimator, the stops, the robots it hears, its own switching and the law) at
  ``control_rate_hz``, on the wheel samples of the period, the camera poses arrived by then and
  the other robots' broadcasts of the previous period (state, commanded acceleration, mode
  report), torque held (ZOH) until the next period; all robots in one compiled call;
* the coordinator (core/control/coordinator.py, what nodes/coordinator.py runs): S9 rewiring
  whenever the set of avoiding robots changes, the robot encounters, right of way and the
  references' progress at ``encounter_rate_hz``, published on change and every ``republish_s``;
* the plant: :class:`~ament_formation.core.sim.twin.PlantTwin` (RK4 at ``dt_s``, wheel encoders,
  disturbance, obstacle motion).

The agents' stops run as on the robots (a run never starves them at drop rates below about
0.5). Not modelled: encoder quantisation, clock offsets and DDS delays (a broadcast reaches the
robots that hear it by their next period; a robot coming into
hearing range is heard at once).

The record is the TRUE state (the same :class:`~ament_formation.core.sim.trajectory.SimResult` as
``simulate``); :attr:`SensedResult.sensing` adds the sensing figures (frames, drops, estimator
counters, estimate error).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace
import math
import time
from typing import Callable

import numpy as np

from ament_formation.core.control.agent import (
    AgentBatch,
    AgentParams,
    broadcast_k,
    frame_k,
    RUNNING,
    wheels_k,
)
from ament_formation.core.control.coordinator import Coordinator, Publisher
from ament_formation.core.control.progress import leader_reference, max_time_s
from ament_formation.core.errors import ConfigError, excerpt
from ament_formation.core.sim.trajectory import SimResult
from ament_formation.core.sim.twin import PlantTwin

# The tracker's measured accuracy (docs/camera.md "Marker size", 0.12 m markers): position p95
# 0.43 mm (radial: 2.448 sigma per axis), heading p95 0.30 deg (1.96 sigma), detection 100 %;
# capture -> pose p50 / p95 8.0 / 12.2 ms on a live MJPEG stream (docs/camera.md, "The real
# camera"): the p95.
MEASURED_NOISE_M = 0.43e-3 / 2.448  # 0.176 mm per axis
MEASURED_NOISE_RAD = math.radians(0.30) / 1.96  # 0.153 deg
MEASURED_LATENCY_S = 0.012
# issue 13's stress figures: 30 fps, 50 ms delay, 3 mm noise, 5 % drops; the heading noise keeps
# the measured ratio of heading to position noise (3 mm -> 2.6 deg)
STRESS_NOISE_M = 3.0e-3
STRESS_NOISE_RAD = STRESS_NOISE_M * MEASURED_NOISE_RAD / MEASURED_NOISE_M


@dataclass(frozen=True)
class SensingParams:
    """What the robots sense and how often they act (see the module docstring).

    ``fps`` camera frame rate [Hz] (None: the scenario's ``camera.fps``); ``latency_s`` capture to
    arrival at the controller [s]; ``noise_m`` standard deviation per axis of the camera position
    of p [m]; ``noise_rad`` of its heading [rad]; ``drop_prob`` probability that a robot's pose is
    missing from a frame, [0, 1); ``seed`` of the sensing noise and drops. The robot side, as in
    config/params: ``control_rate_hz`` (formation_controller, 100 Hz), ``camera_gain`` (its S10
    gain, 0.5), ``hear_all`` and ``hear_margin_m`` (its hearing range: parents, the assignment's
    partner and the robots whose camera pose is within kappa R_aa + 0.6 m, 0.3 m hysteresis),
    ``encounter_rate_hz`` and ``republish_s`` (formation_coordinator, 50 Hz, 1 s),
    ``coordinator_timeout_s`` (formation_controller, 2.5 s: assignments heard within it, the
    robot's own robot encounters are emergencies only, docs/law-changes.md §23).
    """

    fps: float | None = None
    latency_s: float = MEASURED_LATENCY_S
    noise_m: float = MEASURED_NOISE_M
    noise_rad: float = MEASURED_NOISE_RAD
    drop_prob: float = 0.0
    seed: int = 0
    control_rate_hz: float = 100.0
    camera_gain: float = 0.5
    encounter_rate_hz: float = 50.0
    republish_s: float = 1.0
    coordinator_timeout_s: float = 2.5
    hear_all: bool = False
    hear_margin_m: float = 0.6

    def __post_init__(self) -> None:
        def bad(name, value, what):
            raise ConfigError(f'must be {what} (got {excerpt(value)})', name)

        def number(v):
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

        if self.fps is not None and not (number(self.fps) and 0 < self.fps <= 1000):
            bad('fps', self.fps, 'a number in (0, 1000] Hz or None')
        for name, hi in (('latency_s', 10.0), ('noise_m', 1.0), ('noise_rad', math.pi)):
            v = getattr(self, name)
            if not (number(v) and 0 <= v <= hi):
                bad(name, v, f'a number in [0, {hi:g}]')
        if not (number(self.drop_prob) and 0 <= self.drop_prob < 1):
            bad('drop_prob', self.drop_prob, 'a number in [0, 1)')
        if not (isinstance(self.seed, int) and not isinstance(self.seed, bool) and self.seed >= 0):
            bad('seed', self.seed, 'an integer >= 0')
        for name, lo, hi in (
            ('control_rate_hz', 1.0, 1000.0),
            ('encounter_rate_hz', 0.0, 1000.0),
            ('republish_s', 1e-3, 60.0),
            ('coordinator_timeout_s', 0.0, 60.0),
        ):
            v = getattr(self, name)
            if not (number(v) and lo <= v <= hi):
                bad(name, v, f'a number in [{lo:g}, {hi:g}]')
        if not (number(self.camera_gain) and 0 < self.camera_gain <= 1):
            bad('camera_gain', self.camera_gain, 'a number in (0, 1]')
        if not isinstance(self.hear_all, bool):
            bad('hear_all', self.hear_all, 'true or false')
        if not (number(self.hear_margin_m) and 0 <= self.hear_margin_m <= 100):
            bad('hear_margin_m', self.hear_margin_m, 'a number in [0, 100] m')

    @classmethod
    def preset(cls, name: str, **overrides) -> 'SensingParams':
        """The figures called ``name`` in :data:`PRESETS` with ``overrides`` (fields; None values
        are ignored): ``camera`` the tracker's measured figures, ``camera-stress`` issue 13's
        30 fps, 50 ms, 3 mm, 5 % drops, ``camera-perfect`` no noise, latency or drops.
        """
        if name not in PRESETS:
            raise ConfigError(f'must be one of {sorted(PRESETS)} (got {excerpt(name)})', 'sensing')
        kept = {k: v for k, v in overrides.items() if v is not None}
        return replace(PRESETS[name], **kept)

    def frame_rate_hz(self, scenario) -> float:
        return float(self.fps if self.fps is not None else scenario.camera.fps)

    def as_dict(self, scenario=None) -> dict:
        out = dict(self.__dict__)
        if scenario is not None:
            out['fps'] = self.frame_rate_hz(scenario)
        return out


PRESETS = {
    'camera': SensingParams(),
    'camera-stress': SensingParams(
        fps=30.0,
        latency_s=0.050,
        noise_m=STRESS_NOISE_M,
        noise_rad=STRESS_NOISE_RAD,
        drop_prob=0.05,
    ),
    'camera-perfect': SensingParams(latency_s=0.0, noise_m=0.0, noise_rad=0.0, drop_prob=0.0),
}


@dataclass
class SensedResult(SimResult):
    """A :class:`SimResult` (TRUE state) plus ``sensing``: {params, prestart_frames (fused by
    every robot at rest before t = 0), frames (from t = 0), poses_sent, poses_dropped, estimator:
    summed counters (pre-start frames included), estimate_error_m: {rms, max} of |p_hat - p| at
    the control periods}.
    """

    sensing: dict = field(default_factory=dict)


class _Camera:
    """Captures, noise, drops and delivery of the tracker's poses (seeded)."""

    def __init__(self, n: int, sensing: SensingParams, dt_s: float):
        self.n = n
        self.s = sensing
        self.rng = np.random.default_rng(sensing.seed)
        self.queue: deque = deque()  # (arrival_s, stamp_s, poses (N, 3), kept (N,))
        self.frames = 0
        self.sent = 0
        self.dropped = 0
        self.lat_s = sensing.latency_s

    def capture(self, stamp_s: float, true_pose: np.ndarray) -> None:
        """A frame at ``stamp_s`` of (N, 3) true poses [x_m, y_m, theta_rad] of p."""
        u = self.rng.random(self.n)  # always drawn: a drop rate does not change the noise
        e = self.rng.standard_normal((self.n, 3))
        pose = true_pose.copy()
        pose[:, :2] += self.s.noise_m * e[:, :2]
        pose[:, 2] = (pose[:, 2] + self.s.noise_rad * e[:, 2] + math.pi) % (2 * math.pi) - math.pi
        kept = u >= self.s.drop_prob
        self.frames += 1
        self.sent += int(kept.sum())
        self.dropped += self.n - int(kept.sum())
        self.queue.append((stamp_s + self.lat_s, stamp_s, pose, kept))

    def deliver(self, now_s: float) -> list:
        """Every frame arrived by ``now_s``: [(poses (N, 3), kept (N,), capture stamp)]."""
        q = self.queue
        out = []
        while q and q[0][0] <= now_s + 1e-12:
            _arr, stamp, pose, kept = q.popleft()
            out.append((pose, kept, stamp))
        return out


PRESTART_FRAMES = 10  # frames the estimators fuse before the mission starts (robots at rest)


class _Loop:
    """The state of one sensed run (see :func:`simulate_sensed`): the twin, the camera, every
    robot's agent (one :class:`AgentBatch`: what each robot's computer runs) and the
    coordinator.
    """

    def __init__(self, scenario, sensing: SensingParams, dt_s: float):
        self.sc = scenario
        self.twin = PlantTwin(scenario, dt_s)
        self.ids = tuple(sorted(int(r.id) for r in scenario.robots))
        twin_row = {int(rid): q for q, rid in enumerate(self.twin.ids)}
        self.rows = np.array([twin_row[rid] for rid in self.ids], dtype=np.int64)
        self.params = AgentParams(control_rate_hz=sensing.control_rate_hz,
                                  camera_gain=sensing.camera_gain, hear_all=sensing.hear_all,
                                  hear_margin_m=sensing.hear_margin_m,
                                  coordinator_timeout_s=sensing.coordinator_timeout_s)
        self.agents = AgentBatch(scenario, self.ids, self.params)
        self.coord = Coordinator(scenario)
        self.publisher = Publisher(sensing.republish_s)
        self.camera = _Camera(len(self.ids), sensing, dt_s)
        n = len(self.ids)
        self.sent = np.zeros(n, dtype=np.bool_)  # the previous period's broadcasts
        self.bx, self.ba, self.bmode = np.zeros((n, 5)), np.zeros((n, 2)), np.zeros((n, 3))
        self.b_t = 0.0
        self.reports: list = [None] * n
        self.mode_events: list[dict] = []
        self.graph_events = [{'t_s': 0.0, 'parents': _parents_json(self.coord.parents)}]
        self.err_sq = self.err_max = 0.0
        self.err_n = 0

    def true_pose(self) -> np.ndarray:
        return self.twin.state[self.rows, :3]

    def prestart(self, fps: float) -> None:
        """The estimators fuse frames of the robots at rest before the mission starts; the
        coordinator's graph (mission start at t = 0) and first message reach every robot.
        """
        pose = self.true_pose()
        st, sc = self.agents.state, self.agents.static
        zeros = np.zeros((len(self.ids), 2))
        for j in range(PRESTART_FRAMES):
            stamp = (j - PRESTART_FRAMES) / fps
            wheels_k(stamp, zeros, zeros, st, sc)
            self.camera.capture(stamp, pose)
            self.agents.tick(stamp)
            for _pose, _kept, _stamp in self.camera.deliver(math.inf):
                frame_k(_stamp, _pose, _kept, st, sc, self.params.hear_all,
                        self.params.hear_hysteresis_m)
        self.agents.tick(-1e-3)
        self.camera.frames = self.camera.sent = self.camera.dropped = 0  # mission frames only
        self.agents.set_graph(self.coord.parents, 0.0)
        self.agents.assign(0.0, {}, None)
        self.sent[:] = True
        self.bx[:] = self.agents.out.state
        self.b_t = 0.0

    def tick(self, t_s: float, arbitrate: bool) -> None:
        """One control period of every robot, then the coordinator."""
        tw, ag = self.twin, self.agents
        st, sc = ag.state, ag.static
        wheels_k(t_s, tw.wheel_angle_rad[self.rows], tw.wheel_rate_radps[self.rows], st, sc)
        for pose, kept, stamp in self.camera.deliver(t_s):  # the frames arrived by now
            frame_k(stamp, pose, kept, st, sc, self.params.hear_all,
                    self.params.hear_hysteresis_m)
        broadcast_k(self.b_t, self.bx, self.ba, self.bmode, self.sent, st, sc,
                    self.params.hear_all)
        ag.tick(t_s)
        out = ag.out
        truth = tw.state[self.rows, :2]
        e = np.hypot(out.state[:, 0] - truth[:, 0], out.state[:, 1] - truth[:, 1])
        self.err_sq += float(e @ e)
        self.err_max = max(self.err_max, float(e.max()))
        self.err_n += len(e)
        self.mode_events.extend(ag.events)
        self.bx[:], self.ba[:], self.bmode[:] = out.state, out.accel, out.mode
        self.b_t = t_s
        running = st.status == RUNNING
        self.bmode[~running] = (0.0, -1.0, 1.0)
        for r, rid in enumerate(self.ids):
            self.coord.state(rid, out.state[r], t_s)
            key = (int(st.status[r]), *out.mode[r].tolist())
            if key != self.reports[r]:
                self.reports[r] = key
                self.coord.report(rid, ag.mode_dict(r))
        parents = self.coord.reported_avoiding()
        if parents is not None:
            ag.set_graph(parents, 0.0)
            graph = _parents_json(parents)
            if graph != self.graph_events[-1]['parents']:  # a change of the graph (as simulate)
                self.graph_events.append({'t_s': round(t_s, 9), 'parents': graph})
        if arbitrate:
            assignments, rates = self.coord.decide(t_s)
            if self.publisher.due(t_s, assignments, rates):
                ag.assign(t_s, assignments, rates)

    def estimator_counters(self) -> dict:
        total: dict = {}
        for r in range(len(self.ids)):
            for k, v in self.agents.counters(r).items():
                total[k] = total.get(k, 0) + v
        return total


def _parents_json(parents: dict) -> dict:
    return {str(c): (None if p is None else int(p)) for c, p in sorted(parents.items())}


def simulate_sensed(
    scenario,
    sensing: SensingParams,
    dt_s: float = 0.001,
    record_every_s: float = 0.01,
    progress: Callable[[float, float], None] | None = None,
    hold_s: float = 0.0,
) -> SensedResult:
    """Run ``scenario`` with camera sensing, every robot's agent at its control period and the
    coordinator (module docstring) until the mission ends (the coordinator's references at
    their ends, S17.3) and ``hold_s`` [s] longer (in full), or until :func:`max_time_s` when the
    mission does not end; return the TRUE record.

    ``sensing``: :class:`SensingParams` (e.g. ``SensingParams.preset('camera')``); ``dt_s``:
    plant integration step [s] (RK4, torque held between control periods; the control period
    1 / ``sensing.control_rate_hz`` is a whole number of steps); ``record_every_s``: the
    record's period; ``progress``: callable(t_s, duration_s) about every 5 s of simulated time.
    """
    wall0 = time.perf_counter()
    if not (isinstance(dt_s, (int, float)) and math.isfinite(dt_s) and 0 < dt_s <= 0.01):
        raise ValueError(f'dt_s: must be a finite number in (0, 0.01] s (got {dt_s!r})')
    fps = sensing.frame_rate_hz(scenario)
    ctrl_every = max(1, int(round(1.0 / (sensing.control_rate_hz * dt_s))))
    rec_every = max(1, int(round(record_every_s / dt_s)))
    arb_every = (0 if sensing.encounter_rate_hz <= 0
                 else max(1, int(round(1.0 / (sensing.encounter_rate_hz * dt_s)))))
    cap_every = 1.0 / (fps * dt_s)
    loop = _Loop(scenario, sensing, dt_s)
    loop.prestart(fps)
    loop.twin.start()
    n, m = len(loop.ids), len(scenario.obstacles)
    rec = _Record(n, m, int((scenario.duration_s + 10.0) / record_every_s))
    tw, rows = loop.twin, loop.rows
    inv = np.argsort(rows)  # twin rows -> sorted-id rows
    k_cap = int(round(max_time_s(scenario.duration_s) / dt_s))
    k_end, k, next_frame, next_progress = k_cap, 0, 0, 5.0
    step = math.gcd(ctrl_every, rec_every)
    while k < k_end:
        t = k * dt_s
        if k >= next_frame * cap_every - 1e-9:
            loop.camera.capture(t, loop.true_pose())
            next_frame += 1
        if k % ctrl_every == 0:
            loop.tick(t, arb_every > 0 and k % arb_every == 0)
            end = loop.coord.mission_end_s
            if end is not None and k_end == k_cap:
                k_end = k + int(round(hold_s / dt_s)) + 1  # the hold in full (S17.3)
        if k % rec_every == 0:
            rec.add(tw, rows, loop)
        nxt = min(k_end, (k // step + 1) * step, int(math.ceil(next_frame * cap_every - 1e-9)))
        tw.advance((nxt - k) * dt_s, loop.agents.out.torque[inv])
        k = nxt
        if progress is not None and t >= next_progress:
            progress(t, scenario.duration_s)
            next_progress += 5.0
    if progress is not None:
        progress(k * dt_s, scenario.duration_s)
    cam = loop.camera
    t_rec = np.arange(rec.n) * rec_every * dt_s
    return SensedResult(
        scenario_name=scenario.name, robot_ids=loop.ids,
        obstacle_names=tuple(o.name for o in scenario.obstacles), t_s=t_rec,
        state=rec.state[:rec.n], torque_nm=rec.torque[:rec.n],
        goal_m=_true_goals(scenario, loop, t_rec, rec), avoiding=rec.avoid[:rec.n],
        saturated=rec.sat[:rec.n], obstacle_center_m=rec.oc[:rec.n],
        obstacle_phi_rad=rec.ophi[:rec.n], mode_events=loop.mode_events,
        graph_events=loop.graph_events, reaching=[], dt_s=dt_s,
        wall_time_s=time.perf_counter() - wall0, mission_end_s=loop.coord.mission_end_s,
        nominal_duration_s=float(scenario.duration_s), progress_s=rec.progress[:rec.n],
        sensing={
            'params': sensing.as_dict(scenario), 'prestart_frames': PRESTART_FRAMES,
            'frames': cam.frames, 'poses_sent': cam.sent, 'poses_dropped': cam.dropped,
            'estimator': loop.estimator_counters(),
            'estimate_error_m': {'rms': math.sqrt(loop.err_sq / max(1, loop.err_n)),
                                 'max': loop.err_max},
        },
    )


class _Record:
    """The TRUE record of a sensed run, grown as it goes."""

    def __init__(self, n: int, m: int, rows: int):
        self.n = 0
        self.state, self.torque = np.zeros((rows, n, 5)), np.zeros((rows, n, 2))
        self.avoid, self.sat = np.zeros((rows, n), bool), np.zeros((rows, n), bool)
        self.oc, self.ophi = np.zeros((rows, m, 2)), np.zeros((rows, m))
        self.progress = np.zeros((rows, n))
        self.s = np.zeros((rows, n))

    def add(self, tw, rows, loop) -> None:
        if self.n == self.state.shape[0]:
            for name in ('state', 'torque', 'avoid', 'sat', 'oc', 'ophi', 'progress'):
                a = getattr(self, name)
                setattr(self, name, np.concatenate([a, np.zeros_like(a)]))
        q = self.n
        self.state[q] = tw.state[rows]
        self.torque[q] = loop.agents.out.torque
        self.avoid[q] = loop.agents.out.mode[:, 0] != 0
        self.sat[q] = loop.agents.out.saturated
        if self.oc.shape[1]:
            obs = tw.obstacle_states()
            self.oc[q] = obs.center_m
            self.ophi[q] = obs.phi_rad
        c = loop.coord
        self.progress[q] = np.where(c.refs.row >= 0, c.progress.s, 0.0)
        self.n += 1


def _true_goals(scenario, loop, t_s: np.ndarray, rec: _Record) -> np.ndarray:
    """(T, N, 2) formation goals of the TRUE states: a leader's r(s) at the coordinator's
    progress, a follower's original parent + delta.
    """
    ids, state = loop.ids, rec.state[:rec.n]
    coord = loop.coord
    row = {rid: i for i, rid in enumerate(ids)}
    goal = np.zeros((len(t_s), len(ids), 2))
    out = np.zeros(6)
    for i, rid in enumerate(ids):
        p0 = coord.graph.original_parent.get(rid)
        if p0 is None:
            for q in range(len(t_s)):
                leader_reference(coord.refs, i, rec.progress[q, i], 0.0, 0.0, out)
                goal[q, i] = out[:2]
        else:
            goal[:, i] = state[:, row[p0], :2] + coord.graph.offset(rid, p0)
    return goal
