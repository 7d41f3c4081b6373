"""Stop on command loss: how long and how far a robot driving at speed rolls once its commands stop
(docs/safety.md).

    bench/run.sh bench_stop.py [--trials 5] [--speed-mps 0.8] [--json OUT.json] [--no-twin]
    [--no-firmware]

Twin: formation_world's plant and emulated motor board (camera off, one robot of the reference
parameters on an empty floor, the world at ``--speed-factor`` of real time), formation_bridge on
the
board's pty (in this process: a subprocess starves on a loaded machine), and a driver commanding
torques (a speed loop on the true speed) until the robot holds ``--speed-mps``; then the bridge is
killed the way SIGKILL kills it — its port closes, no STOP, no last frame: the board's watchdog
is all that is left. Per trial: time and distance from the board's last command to rest (true
speed below 5 mm/s for good) and to the release of the H-bridge, the peak brake torque.

Firmware: the ATmega328P firmware in simavr (firmware/sim/harness.c: wheel + half the robot's
inertia, the DC-motor model) driven at full torque to the motor's top speed, then the host->board
line is cut. Per trial: time from the last frame the firmware read to the release of the H-bridge,
wheel travel at the wheel radius (emulated time).

Prints a table per part, the worst case, and the analytic bound of docs/safety.md for comparison.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test'))

REST_SPEED_MPS = 0.005

SCENARIO = """\
name: bench_stop
duration_s: 100000.0
robot:
  platform_mass_kg: 2.5
  wheel_mass_kg: 0.10
  wheel_radius_m: 0.035
  axle_length_m: 0.20
  com_offset_m: 0.05
  platform_inertia_kgm2: 0.0167
  torque_limit_nm: 0.15
  body_radius_m: 0.10
robots:
  - id: 0
    leader: true
    path: {type: line, start_m: [0.0, 0.0], heading_rad: 0.0, speed_mps: 0.05}
    slot_m: [0.0, 0.0]
    initial_pose: [0.0, 0.0, 0.0]
    marker_id: 0
graph: {edges: []}
obstacles: []
"""


MOTOR_TOP_SPEED_MPS = (
    12.0 / (0.0175 * 30.0) * 0.035
)  # firmware/src/config.h motor at 12 V: 0.80 m/s


def analytic_bound(
    speed_mps: float,
    m_tilde_kg: float,
    r_m: float,
    tau_limit_nm: float,
    top_speed_mps: float = MOTOR_TOP_SPEED_MPS,
) -> dict:
    """docs/safety.md: the last command (``tau_limit_nm`` forward on both wheels: the worst case;
    0: the robot was holding its speed) stays applied for the 200 ms watchdog (the speed capped
    at the motor's top speed), then the brake at its bound until the wheel speed is in the linear
    range, then the linear tail (time constant J/gain per wheel) to the one-count rest band, then
    the rest window.
    """
    from ament_formation.core.serial import motor_board as mb

    wd = 0.2
    a_drive = 2 * tau_limit_nm / (r_m * m_tilde_kg)
    a_brake = 2 * mb.BRAKE_TORQUE_LIMIT_NM / (r_m * m_tilde_kg)
    v1 = min(speed_mps + a_drive * wd, max(top_speed_mps, speed_mps))
    t_up = (v1 - speed_mps) / a_drive if a_drive > 0 else 0.0
    d1 = speed_mps * t_up + 0.5 * a_drive * t_up**2 + v1 * (wd - t_up)
    w_lin = mb.BRAKE_TORQUE_LIMIT_NM / mb.BRAKE_GAIN_NM_PER_RADPS  # saturation below this [rad/s]
    v_lin = min(v1, w_lin * r_m)
    t2 = (v1 - v_lin) / a_brake
    d2 = (v1**2 - v_lin**2) / (2 * a_brake)
    j_wheel = 0.5 * m_tilde_kg * r_m**2  # robot mass per wheel, reflected
    tc = j_wheel / mb.BRAKE_GAIN_NM_PER_RADPS
    v_rest = 2 * math.pi / 1440 / 0.05 * r_m  # one count per 50 ms
    t3 = tc * math.log(max(v_lin / v_rest, 1.0))
    d3 = v_lin * tc
    return {
        'speed_mps': speed_mps,
        'watchdog_s': wd,
        'speed_at_brake_mps': v1,
        'time_to_rest_s': wd + t2 + t3,
        'time_to_release_s': wd + t2 + t3 + mb.BRAKE_REST_S + 0.01,
        'distance_m': d1 + d2 + d3,
        'brake_decel_mps2': a_brake,
        'drive_accel_mps2': a_drive,
        'linear_time_constant_s': tc,
    }


# ---------------------------------------------------------------------------------------------
def twin_trials(n_trials: int, speed_mps: float, speed_factor: float) -> list[dict]:
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault(
        'FASTRTPS_DEFAULT_PROFILES_FILE', str(ROOT / 'config' / 'fastdds_localhost.xml')
    )
    os.environ.setdefault('ROS_DOMAIN_ID', str(os.getpid() % 200 + 1))
    import numpy as np
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from ament_formation.core.serial import serial_link as sl
    from ament_formation.nodes.bridge import BridgeNode
    from ament_formation.nodes.world import WorldNode, WorldParams
    from ament_formation.ros.executors import spin_until

    tmp = Path(tempfile.mkdtemp(prefix='bench_stop_'))
    scenario = tmp / 'scenario.yaml'
    scenario.write_text(SCENARIO)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(os.environ['ROS_DOMAIN_ID']))
    ex = SingleThreadedExecutor(context=ctx)
    world = WorldNode(
        context=ctx,
        params=WorldParams(
            scenario=str(scenario),
            pty_dir=str(tmp / 'pty'),
            camera_enabled=False,
            exit_at_end=False,
            speed_factor=speed_factor,
        ),
    )
    driver = Node('bench_stop_driver', namespace='robot_0', context=ctx)
    board = world.boards[0].board
    k = world.twin.k
    tau_lim = float(k.tau_max[0])
    state = {'bridge': None}
    samples: list[tuple] = []

    def tick():
        s = world.twin.state[0]
        samples.append(
            (
                world.plant_time_s,
                float(s[0]),
                float(s[1]),
                float(s[3]),
                float(s[4]),
                bool(board.braking),
                tuple(board.applied_e4nm),
            )
        )
        bridge = state['bridge']
        if bridge is not None:
            # the controller's part: a speed loop on the true speed, heading held by the difference
            u = max(-tau_lim, min(tau_lim, 2.0 * (speed_mps - s[3])))
            dw = max(-0.02, min(0.02, -0.05 * s[4]))
            bridge.command((u - dw, u + dw))

    driver.create_timer(0.01, tick)
    ex.add_node(world)
    ex.add_node(driver)
    results = []
    try:
        for trial in range(n_trials):
            # formation_bridge in this process (a subprocess starves on a loaded machine); it is
            # "killed" the way SIGKILL kills a bridge process: no last frame, the OS closes its
            # port
            bridge = BridgeNode(
                context=ctx,
                namespace='/robot_0',
                torque_topic=False,
                parameter_overrides=[
                    Parameter('port', value=str(tmp / 'pty' / 'robot_0')),
                    Parameter('torque_limit_nm', value=tau_lim),
                ],
            )
            ex.add_node(bridge)
            if not spin_until(ex, lambda: bridge.link.state == sl.UP, 30.0):
                raise RuntimeError(f'trial {trial}: link not up ({bridge.link.state})')
            state['bridge'] = bridge
            held = {'since': None}

            def at_speed():
                v = world.twin.state[0, 3]
                if abs(v - speed_mps) < 0.01 and not board.braking:
                    held['since'] = held['since'] or world.plant_time_s
                    return world.plant_time_s - held['since'] > 0.5
                held['since'] = None
                return False

            if not spin_until(ex, at_speed, 60.0 / speed_factor):
                raise RuntimeError(
                    f'trial {trial}: the robot did not reach {speed_mps} m/s '
                    f'(v = {world.twin.state[0, 3]:.3f} m/s)'
                )
            brakes0 = board.brakes
            overruns0 = world.overruns
            state['bridge'] = None
            ex.remove_node(bridge)
            bridge._close_port()  # SIGKILL: the port closes, nothing more is sent
            n0 = len(samples)
            if not spin_until(
                ex,
                lambda: (
                    board.brakes > brakes0
                    and board.brake_released_s is not None
                    and not board.braking
                ),
                10.0 / speed_factor,
            ):
                raise RuntimeError(f'trial {trial}: the board did not brake and release')
            spin_until(ex, lambda: False, 0.3 / speed_factor)  # after the release: drift
            Node.destroy_node(bridge)  # not BridgeNode.destroy_node: that would send STOP
            t_loss = board.last_command_s
            rows = [r for r in samples[max(0, n0 - 50):] if r[0] >= t_loss - 0.011]
            t = np.array([r[0] for r in rows])
            xy = np.array([(r[1], r[2]) for r in rows])
            v = np.array([r[3] for r in rows])
            path = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
            moving = np.flatnonzero(np.abs(v) >= REST_SPEED_MPS)
            i_rest = min(int(moving[-1]) + 1, len(t) - 1) if moving.size else 0
            i_rel = min(int(np.searchsorted(t, board.brake_released_s)), len(t) - 1)
            peak = max((max(abs(a) for a in r[6]) for r in rows if r[5]), default=0) * 1e-4
            results.append(
                {
                    'trial': trial,
                    'speed_at_loss_mps': float(np.interp(t_loss, t, v)),
                    'brake_start_after_loss_s': board.brake_started_s - t_loss,
                    'time_to_rest_s': float(t[i_rest] - t_loss),
                    'distance_to_rest_m': float(path[i_rest]),
                    'time_to_release_s': board.brake_released_s - t_loss,
                    'distance_to_release_m': float(path[i_rel]),
                    'speed_at_release_mps': float(abs(v[i_rel])),
                    'drift_after_release_mps': float(abs(v[-1])),
                    'peak_brake_torque_nm': peak,
                    'released_by': 'rest'
                    if board.brake_released_s - board.brake_started_s < 0.99
                    else 'timeout',
                    'world_overruns': world.overruns - overruns0,
                }
            )
    finally:
        ex.remove_node(world)
        ex.remove_node(driver)
        world.close()
        world.destroy_node()
        driver.destroy_node()
        ex.shutdown(timeout_sec=1.0)
        rclpy.try_shutdown(context=ctx)
        scenario.unlink()
        for p in sorted(tmp.rglob('*'), reverse=True):
            p.unlink() if p.is_file() or p.is_symlink() else p.rmdir()
        tmp.rmdir()
    return results


# ---------------------------------------------------------------------------------------------
def firmware_trials(n_trials: int, build_dir: Path) -> list[dict]:
    from firmware_sim import build_firmware, CodecLink, Harness

    from ament_formation.core.serial import serial_protocol as sp

    build_firmware(build_dir)
    wheel_r_m = 0.035
    results = []
    for trial in range(n_trials):
        work = Path(tempfile.mkdtemp(prefix='bench_stop_fw_'))
        harness = Harness(build_dir, work)
        link = CodecLink(harness.pty)
        try:
            link.handshake()
            last = [0.0]

            def drive():
                now = time.monotonic()
                if now - last[0] >= 0.01:
                    link.send(sp.TorqueCommand(1500, 1500))
                    last[0] = now
                link.pump()

            harness.wait_for(lambda s: min(s['wheel_radps']) > 20.5, 10.0, drive)
            harness.set_mode('cut')
            harness.poll()
            n0 = len(harness.lines)
            released = harness.wait_for(
                lambda s: (
                    s['mode'] == 'cut'
                    and s['duty'] == [0.0, 0.0]
                    and s['t_s'] > s['last_frame_rx_t_s'] + 0.25
                ),
                5.0,
                link.pump,
            )
            t_loss = released['last_frame_rx_t_s']
            lines = [s for s in harness.lines[n0:] if s['t_s'] >= t_loss]
            at_loss = lines[0]
            brake = [s for s in lines if s['telemetry']['flags'] & sp.FLAG_BRAKING]
            rest = next(
                (
                    s
                    for s in lines
                    if max(abs(w) for w in s['wheel_radps']) < REST_SPEED_MPS / wheel_r_m
                ),
                released,
            )
            results.append(
                {
                    'trial': trial,
                    'wheel_speed_at_loss_radps': at_loss['wheel_radps'][0],
                    'speed_at_loss_mps': at_loss['wheel_radps'][0] * wheel_r_m,
                    'brake_seen_after_loss_s': (brake[0]['t_s'] - t_loss) if brake else None,
                    'time_to_rest_s': rest['t_s'] - t_loss,
                    'wheel_travel_to_rest_m': (rest['wheel_rad'][0] - at_loss['wheel_rad'][0])
                    * wheel_r_m,
                    'time_to_release_s': released['pwm_change_t_s'] - t_loss,
                    'wheel_travel_to_release_m': (
                        released['wheel_rad'][0] - at_loss['wheel_rad'][0]
                    )
                    * wheel_r_m,
                    'wheel_speed_at_release_radps': max(abs(w) for w in released['wheel_radps']),
                    # STATUS (every 200 ms) carries the applied torque with its own flags
                    'peak_applied_e4nm': max(
                        (
                            abs(a)
                            for s in lines
                            if s['board']['flags'] & sp.FLAG_BRAKING
                            for a in s['board']['applied_e4nm']
                        ),
                        default=0,
                    ),
                }
            )
        finally:
            link.close()
            harness.close()
            for p in sorted(work.rglob('*'), reverse=True):
                p.unlink() if p.is_file() or p.is_symlink() else p.rmdir()
            work.rmdir()
    return results


def _table(rows: list[dict], keys: list[str]) -> str:
    out = ['  '.join(f'{k:>24s}' for k in keys)]
    for r in rows:
        out.append(
            '  '.join(
                f'{r[k]:24.3f}' if isinstance(r[k], float) else f'{str(r[k]):>24s}' for k in keys
            )
        )
    return '\n'.join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--trials', type=int, default=5)
    ap.add_argument(
        '--speed-mps', type=float, default=0.8, help='twin: speed when the bridge dies'
    )
    ap.add_argument(
        '--speed-factor',
        type=float,
        default=0.5,
        help='twin: world time per wall second (board and plant share it; < 1 lets a busy '
        'machine keep up: world_overruns counts the ticks it could not)',
    )
    ap.add_argument('--json', type=Path, default=None)
    ap.add_argument('--no-twin', action='store_true')
    ap.add_argument('--no-firmware', action='store_true')
    a = ap.parse_args()
    from ament_formation.core.model.dynamics import PlantCoeffs
    from ament_formation.core.scenario.loader import load_scenario

    tmp = Path(tempfile.mkdtemp(prefix='bench_stop_sc_'))
    (tmp / 's.yaml').write_text(SCENARIO)
    k = PlantCoeffs.from_params([load_scenario(str(tmp / 's.yaml')).robots[0].params])
    (tmp / 's.yaml').unlink()
    tmp.rmdir()
    report: dict = {'load_avg_1min': os.getloadavg()[0], 'cpus': os.cpu_count()}
    bound = analytic_bound(a.speed_mps, float(k.m_tilde[0]), float(k.r[0]), float(k.tau_max[0]))
    hold = analytic_bound(a.speed_mps, float(k.m_tilde[0]), float(k.r[0]), 0.0)
    report['analytic_bound'] = bound
    report['analytic_holding_speed'] = hold
    print(
        f'analytic at {a.speed_mps} m/s (m~ = {float(k.m_tilde[0]):.3f} kg, '
        f'brake {bound["brake_decel_mps2"]:.2f} '
        f'm/s^2, motor top speed {MOTOR_TOP_SPEED_MPS:.2f} m/s): '
        'last command holding the speed: rest after '
        f'{hold["time_to_rest_s"]:.3f} s, {hold["distance_m"]:.3f} m; last command full torque: '
        f'{bound["time_to_rest_s"]:.3f} s, {bound["distance_m"]:.3f} m'
    )
    if not a.no_twin:
        rows = twin_trials(a.trials, a.speed_mps, a.speed_factor)
        report['twin'] = rows
        print(
            f'\ntwin: bridge SIGKILLed at {a.speed_mps} m/s, {len(rows)} trials '
            "(times from the board's last command)"
        )
        print(
            _table(
                rows,
                [
                    'trial',
                    'speed_at_loss_mps',
                    'brake_start_after_loss_s',
                    'time_to_rest_s',
                    'distance_to_rest_m',
                    'time_to_release_s',
                    'speed_at_release_mps',
                    'drift_after_release_mps',
                    'peak_brake_torque_nm',
                    'released_by',
                    'world_overruns',
                ],
            )
        )
        print(
            f'worst: time to rest {max(r["time_to_rest_s"] for r in rows):.3f} s, '
            f'distance {max(r["distance_to_rest_m"] for r in rows):.3f} m, '
            f'release {max(r["time_to_release_s"] for r in rows):.3f} s'
        )
    if not a.no_firmware:
        build = Path(tempfile.mkdtemp(prefix='bench_stop_build_'))
        try:
            rows = firmware_trials(a.trials, build)
        finally:
            subprocess.run(['rm', '-rf', str(build)], check=False)
        report['firmware'] = rows
        print(
            "\nfirmware in simavr: line cut at the motor's top speed, "
            f'{len(rows)} trials (emulated time)'
        )
        print(
            _table(
                rows,
                [
                    'trial',
                    'speed_at_loss_mps',
                    'brake_seen_after_loss_s',
                    'time_to_rest_s',
                    'wheel_travel_to_rest_m',
                    'time_to_release_s',
                    'wheel_travel_to_release_m',
                    'wheel_speed_at_release_radps',
                    'peak_applied_e4nm',
                ],
            )
        )
        print(
            f'worst: time to rest {max(r["time_to_rest_s"] for r in rows):.3f} s, '
            f'wheel travel {max(r["wheel_travel_to_rest_m"] for r in rows):.3f} m, '
            f'release {max(r["time_to_release_s"] for r in rows):.3f} s'
        )
    report['load_avg_1min_end'] = os.getloadavg()[0]
    if a.json:
        a.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
