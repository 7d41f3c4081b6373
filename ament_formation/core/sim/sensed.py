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

The mission runs in one compiled loop (core/sim/sensed_loop.py, issue 34): the same kernels the
objects above call (the agents', the coordinator's decision and publisher, the twin's RK4), step
by step, with Python only for the S9 rewiring, the camera's draws (in the generator's order) and
growing buffers; test_sensed_sim.py holds it to the objects' Python interfaces, bit for bit. A
camera run costs about what an ideal one does (docs/sweep.md, "Camera sensing's cost").
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace
import math
import time
from typing import Callable

import numpy as np

from ament_formation.core.control.agent import AgentBatch, AgentParams, frame_k, wheels_k
from ament_formation.core.control.coordinator import Coordinator, new_pub
from ament_formation.core.control.progress import max_time_s
from ament_formation.core.control.switching import MODE_NAMES
from ament_formation.core.errors import ConfigError, excerpt
from ament_formation.core.model.obstacles import obstacle_arrays
from ament_formation.core.sim import sensed_loop as loopk
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
    config/params: ``control_rate_hz`` (formation_controller, 100 Hz), ``state_rate_hz`` (the rate
    it sends its state at, 100 Hz; the coordinator and the robots hear it then; below the control
    rate the robots extrapolate every state by its age, ``parent_timeout_s`` 0), ``camera_gain``
    (its S10 gain, 0.5), ``hear_all`` and ``hear_margin_m`` (its hearing range: parents, the
    assignment's partner and the robots whose camera pose is within kappa R_aa + 0.6 m, 0.3 m
    hysteresis), ``encounter_rate_hz`` and ``republish_s`` (formation_coordinator, 50 Hz, 1 s),
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
    state_rate_hz: float = 100.0
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
            ('state_rate_hz', 0.1, self.control_rate_hz if number(self.control_rate_hz) else 0),
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
    coordinator. The robots at rest before the mission (:meth:`prestart`) go through their
    Python interfaces; the mission runs in the compiled loop (:class:`_Run`).
    """

    def __init__(self, scenario, sensing: SensingParams, dt_s: float):
        self.sc = scenario
        self.twin = PlantTwin(scenario, dt_s)
        self.ids = tuple(sorted(int(r.id) for r in scenario.robots))
        twin_row = {int(rid): q for q, rid in enumerate(self.twin.ids)}
        self.rows = np.array([twin_row[rid] for rid in self.ids], dtype=np.int64)
        self.params = AgentParams(control_rate_hz=sensing.control_rate_hz,
                                  state_rate_hz=sensing.state_rate_hz,
                                  # below the control rate every state is extrapolated (S10.2)
                                  **({'parent_timeout_s': 0.0} if sensing.state_rate_hz
                                     < sensing.control_rate_hz else {}),
                                  camera_gain=sensing.camera_gain, hear_all=sensing.hear_all,
                                  hear_margin_m=sensing.hear_margin_m,
                                  coordinator_timeout_s=sensing.coordinator_timeout_s)
        self.agents = AgentBatch(scenario, self.ids, self.params)
        self.coord = Coordinator(scenario)
        self.camera = _Camera(len(self.ids), sensing, dt_s)
        n = len(self.ids)
        self.sent = np.zeros(n, dtype=np.bool_)  # the previous period's broadcasts
        self.bx, self.ba, self.bmode = np.zeros((n, 5)), np.zeros((n, 2)), np.zeros((n, 3))
        self.b_t = 0.0
        self.mode_events: list[dict] = []
        self.graph_events = [{'t_s': 0.0, 'parents': _parents_json(self.coord.parents)}]

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

    def estimator_counters(self) -> dict:
        total: dict = {}
        for r in range(len(self.ids)):
            for k, v in self.agents.counters(r).items():
                total[k] = total.get(k, 0) + v
        return total


def _parents_json(parents: dict) -> dict:
    return {str(c): (None if p is None else int(p)) for c, p in sorted(parents.items())}


NOISE_FRAMES = 256  # camera frames drawn at once for the compiled loop
BLAS_DOT_N = 16  # numpy's dot of this many values or more is BLAS's blocked sum


class _Run:
    """The mission of a :class:`_Loop` in the compiled loop (core/sim/sensed_loop.py): its
    arrays, and what Python does when the loop returns (noise, rewiring, records, events).
    """

    def __init__(self, loop: _Loop, sensing: SensingParams, dt_s: float, fps: float,
                 every: tuple[int, int, int], k_cap: int, hold_steps: int, n_rec: int):
        ag, tw, coord, sc = loop.agents, loop.twin, loop.coord, loop.sc
        if not (coord.ids == ag.ids == ag.hosted == loop.ids):
            raise RuntimeError('the agents, the coordinator and the camera must share the rows')
        self.loop, self.dt_s = loop, dt_s
        n = len(loop.ids)
        ctrl_every, rec_every, arb_every = every
        step = math.gcd(ctrl_every, rec_every)
        self.reg = np.zeros(loopk.N_REG, dtype=np.int64)
        self.reg[loopk.K_END] = self.reg[loopk.K_CAP] = k_cap
        self.fl = np.zeros(loopk.N_FREG)
        self.fl[loopk.B_T] = loop.b_t
        self.clock = loopk.ClockK(float(dt_s), ctrl_every, rec_every, arb_every,
                                  1.0 / (fps * dt_s), step, hold_steps, loop.params.hear_all,
                                  float(loop.params.hear_hysteresis_m), n >= BLAS_DOT_N,
                                  loop.params.state_every)
        k, dist = tw.k, tw.disturbance
        obstacles = obstacle_arrays(sc.obstacles)
        self.twin = loopk.TwinK(tw.state, tw.wheel_angle_rad, np.array([tw.t_s]), loop.rows,
                                np.argsort(loop.rows), k.m_tilde, k.I_tilde, k.r, k.a, k.d,
                                k.m_c, k.tau_max, dist.amplitude, dist.freq_hz, dist.phase_rad,
                                tuple(obstacles[:6]), tw.obstacles.buffers(), np.zeros((n, 2)),
                                np.zeros((2 * step + 1, n, 2)))
        self.rng = loop.camera.rng  # the prestart's generator goes on
        ring = int(math.ceil((sensing.latency_s + (ctrl_every + 1) * dt_s) * fps)) + 8
        self.camera = self._camera(ring, n, (sensing.noise_m, sensing.noise_rad,
                                             sensing.drop_prob, sensing.latency_s))
        names = coord.obstacle_names
        self.buf = loopk.LoopK(
            np.zeros((n, 2)), np.zeros((n, 2)), loop.bx, loop.ba, loop.bmode, loop.sent,
            np.zeros(n, dtype=np.bool_),
            np.array([rid in coord.avoiding for rid in loop.ids], dtype=np.bool_),
            np.array([names.index(o) if o in names else -1 for o in ag.obstacle_names],
                     dtype=np.int64),
            np.isin(np.arange(n), coord.leaders),
            np.zeros((8 * n * ag.state.ev.shape[1], 7)),
            np.zeros((1024 if self.clock.blas_error else 1, n)))
        m = len(sc.obstacles)
        n_rec = max(16, n_rec)
        self.rec = loopk.RecordK(np.zeros((n_rec, n, 5)), np.zeros((n_rec, n, 2)),
                                 np.zeros((n_rec, n), bool), np.zeros((n_rec, n), bool),
                                 np.zeros((n_rec, m, 2)), np.zeros((n_rec, m)),
                                 np.zeros((n_rec, n)))
        self.pub = new_pub(n, sensing.republish_s)

    @staticmethod
    def _camera(ring: int, n: int, figures: tuple) -> loopk.CameraK:
        """An empty ring of ``ring`` frames, room for the draws of :data:`NOISE_FRAMES`, the
        camera's (noise_m, noise_rad, drop_prob, latency_s).
        """
        return loopk.CameraK(np.zeros(ring), np.zeros(ring), np.zeros((ring, n, 3)),
                             np.zeros((ring, n), dtype=np.bool_), np.zeros((NOISE_FRAMES, n)),
                             np.zeros((NOISE_FRAMES, n, 3)), *(float(v) for v in figures))

    def run(self, progress, duration_s: float) -> None:
        """The compiled loop until the run ends; ``progress`` about every 5 s."""
        reg, dt_s = self.reg, self.dt_s
        chunk = max(1, int(round(5.0 / dt_s)))
        reg[loopk.K_STOP] = chunk
        reg[loopk.NOISE_POS] = NOISE_FRAMES  # nothing drawn yet
        next_progress = 5.0
        while True:
            ag = self.loop.agents
            why = loopk.run_k(reg, self.fl, self.clock, ag.state, ag.static, ag.out,
                              self.loop.coord.k, self.pub, self.twin, self.camera, self.buf,
                              self.rec)
            if why == loopk.DONE:
                break
            if why == loopk.CHUNK_END:
                reg[loopk.K_STOP] += chunk
                t = int(reg[loopk.K]) * dt_s
                if progress is not None and t >= next_progress:
                    progress(t, duration_s)
                    next_progress += 5.0
            elif why == loopk.NOISE:
                self._draw()
            elif why == loopk.REWIRE:
                self._rewire(int(reg[loopk.K]) * dt_s)
            elif why == loopk.RECORD_FULL:
                self.rec = loopk.RecordK(*(np.concatenate([a, np.zeros_like(a)])
                                           for a in self.rec))
            elif why == loopk.FLUSH:
                self.flush()
            elif why == loopk.QUEUE_FULL:
                self._grow_ring()
            else:
                raise RuntimeError(f'the sensed loop stopped for an unknown reason {why}')
        self.flush()
        tw = self.loop.twin
        tw.t_s = float(self.twin.t[0])
        tw.torque_nm = self.twin.tau.copy()

    def _draw(self) -> None:
        """The next frames' drops and noise, drawn as _Camera.capture draws them."""
        cam, rng, n = self.camera, self.rng, self.camera.u.shape[1]
        for f in range(cam.u.shape[0]):
            cam.u[f] = rng.random(n)  # always drawn: a drop rate does not change the noise
            cam.e[f] = rng.standard_normal((n, 3))
        self.reg[loopk.NOISE_POS] = 0

    def _grow_ring(self) -> None:
        cam, reg = self.camera, self.reg
        q = (reg[loopk.CQ_HEAD] + np.arange(reg[loopk.CQ_N])) % cam.arrive.shape[0]
        grown = self._camera(2 * cam.arrive.shape[0], cam.u.shape[1], cam[6:])
        for old, new in zip(cam[:4], grown[:4]):
            new[:len(q)] = old[q]
        grown.u[:], grown.e[:] = cam.u, cam.e
        self.camera = grown
        reg[loopk.CQ_HEAD] = 0

    def _rewire(self, t_s: float) -> None:
        """S9 on the changed set of avoiding robots (_Loop.tick: reported_avoiding)."""
        loop, buf = self.loop, self.buf
        avoiding = frozenset(loop.ids[q] for q in np.flatnonzero(buf.avoid_now))
        parents = loop.coord.set_avoiding(avoiding)
        if parents is not None:
            loop.agents.set_graph(parents, 0.0)
            graph = _parents_json(parents)
            if graph != loop.graph_events[-1]['parents']:  # a change of the graph (as simulate)
                loop.graph_events.append({'t_s': round(t_s, 9), 'parents': graph})
        buf.avoid_set[:] = buf.avoid_now

    def flush(self) -> None:
        """The agents' mode events as dicts; the estimate errors BLAS sums."""
        reg, buf, ag = self.reg, self.buf, self.loop.agents
        for row in buf.events[:reg[loopk.EV_N]]:
            md, tgt = int(row[4]), int(row[5])
            self.loop.mode_events.append({
                't_s': float(row[1]), 'robot': ag.hosted[int(row[0])],
                'event': 'enter' if row[3] > 0.5 else 'exit', 'mode': MODE_NAMES[md],
                'target': ag._target(md, tgt), 'direction': 'ccw' if row[6] > 0 else 'cw'})
        reg[loopk.EV_N] = 0
        fl = self.fl
        for e in buf.err[:reg[loopk.ERR_N]]:
            fl[loopk.ERR_SQ] += float(e @ e)
            fl[loopk.ERR_MAX] = max(float(fl[loopk.ERR_MAX]), float(e.max()))
            reg[loopk.ERR_COUNT] += len(e)
        reg[loopk.ERR_N] = 0

    def record(self) -> loopk.RecordK:
        n = int(self.reg[loopk.REC_N])
        return loopk.RecordK(*(a[:n] for a in self.rec))


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
    The mission runs in one compiled loop (core/sim/sensed_loop.py).
    """
    wall0 = time.perf_counter()
    if not (isinstance(dt_s, (int, float)) and math.isfinite(dt_s) and 0 < dt_s <= 0.01):
        raise ValueError(f'dt_s: must be a finite number in (0, 0.01] s (got {dt_s!r})')
    fps = sensing.frame_rate_hz(scenario)
    ctrl_every = max(1, int(round(1.0 / (sensing.control_rate_hz * dt_s))))
    rec_every = max(1, int(round(record_every_s / dt_s)))
    arb_every = (0 if sensing.encounter_rate_hz <= 0
                 else max(1, int(round(1.0 / (sensing.encounter_rate_hz * dt_s)))))
    loop = _Loop(scenario, sensing, dt_s)
    loop.prestart(fps)
    loop.twin.start()
    k_cap = int(round(max_time_s(scenario.duration_s) / dt_s))
    run = _Run(loop, sensing, dt_s, fps, (ctrl_every, rec_every, arb_every), k_cap,
               int(round(hold_s / dt_s)) + 1, int((scenario.duration_s + 10.0) / record_every_s))
    run.run(progress, scenario.duration_s)
    k = int(run.reg[loopk.K])
    if progress is not None:
        progress(k * dt_s, scenario.duration_s)
    rec = run.record()
    reg, fl = run.reg, run.fl
    n_rec = rec.state.shape[0]
    t_rec = np.arange(n_rec) * rec_every * dt_s
    return SensedResult(
        scenario_name=scenario.name, robot_ids=loop.ids,
        obstacle_names=tuple(o.name for o in scenario.obstacles), t_s=t_rec,
        state=rec.state, torque_nm=rec.torque,
        goal_m=_true_goals(loop, rec), avoiding=rec.avoid,
        saturated=rec.sat, obstacle_center_m=rec.oc,
        obstacle_phi_rad=rec.ophi, mode_events=loop.mode_events,
        graph_events=loop.graph_events, reaching=[], dt_s=dt_s,
        wall_time_s=time.perf_counter() - wall0, mission_end_s=loop.coord.mission_end_s,
        nominal_duration_s=float(scenario.duration_s), progress_s=rec.progress,
        sensing={
            'params': sensing.as_dict(scenario), 'prestart_frames': PRESTART_FRAMES,
            'frames': int(reg[loopk.FRAMES]), 'poses_sent': int(reg[loopk.SENT]),
            'poses_dropped': int(reg[loopk.DROPPED]),
            'estimator': loop.estimator_counters(),
            'estimate_error_m': {'rms': math.sqrt(float(fl[loopk.ERR_SQ])
                                                  / max(1, int(reg[loopk.ERR_COUNT]))),
                                 'max': float(fl[loopk.ERR_MAX])},
        },
    )


def _true_goals(loop: _Loop, rec) -> np.ndarray:
    """(T, N, 2) formation goals of the TRUE states: a leader's r(s) at the coordinator's
    progress, a follower's original parent + delta.
    """
    ids, state = loop.ids, rec.state
    coord = loop.coord
    row = {rid: i for i, rid in enumerate(ids)}
    goal = np.zeros((state.shape[0], len(ids), 2))
    for i, rid in enumerate(ids):
        p0 = coord.graph.original_parent.get(rid)
        if p0 is None:
            loopk.leader_goals_k(coord.refs, i, rec.progress[:, i], goal[:, i])
        else:
            goal[:, i] = state[:, row[p0], :2] + coord.graph.offset(rid, p0)
    return goal
