"""The camera-loss stop's lead and travel for the reference robot (docs/safety.md §7's table).

    .venv/bin/python bench/stop_lead_table.py [--scenario S.yaml] [--robot ID] [--delay-periods N]

Per starting speed (v0, omega0): the closed-form time to rest (``StopLead.time_to_rest``), the
lead, the camera age at which the stop begins and by which the robot is at rest (+ one control
period), and, from the stop law sampled at 100 Hz on the plant with the disturbance at its bound
along the motion and each command computed from the state ``--delay-periods`` periods old, the
simulated time to rest and the travel while braking and from the last pose (the speed held until
the stop begins, one period included). Also the lead with the formation law's K_p on v
(``stop_decel_mps2`` 0, the hold_parent stop).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
import sys

import numpy as np

from ament_formation.core.control.stop import REST_SPEED_MPS, stop_torque, StopLead
from ament_formation.core.model.dynamics import PlantCoeffs, rk4_step_all
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.nodes.controller import ControllerParams

HERE = Path(__file__).resolve().parent
SPEEDS = [(0.0, 0.0), (0.05, 0.0), (0.08, 0.3), (0.10, 0.0), (0.15, 0.0), (0.0, 1.4), (0.0, 2.5)]


def simulate(sc, rid, prm, decel, v0, w0, delay_periods):
    """(time to rest [s], travel [m] and heading change [rad] until then) of the sampled,
    delayed stop law.
    """
    robot = sc.robot(rid).params
    k = PlantCoeffs.from_params([robot])
    g = np.array([[math.copysign(b, s) for b, s in zip(sc.disturbance.accel_bound, (v0, w0))]])
    x = np.array([[0.0, 0.0, 0.0, v0, w0]])
    period = 1.0 / prm.control_rate_hz
    dt, t, last_moving, travel = 0.001, 0.0, 0.0, 0.0
    at_rest = (0.0, 0.0)  # travel and heading change when last moving
    seen = [x.copy()] * (delay_periods + 1)
    while t < 3.0:
        if round(t / dt) % round(period / dt) == 0:
            seen = seen[1:] + [x.copy()]
            u = stop_torque(seen[0], k, prm.stop_time_s, sc.control, decel, period)
        x_prev = x
        x = rk4_step_all(
            x, u, g, g, g, dt, k.m_tilde, k.I_tilde, k.r, k.a, k.d, k.m_c, np.empty_like(x)
        )
        t += dt
        travel += abs(x[0, 3] + x_prev[0, 3]) * 0.5 * dt
        if abs(x[0, 3]) + 0.5 * robot.axle_length_m * abs(x[0, 4]) >= REST_SPEED_MPS:
            last_moving, at_rest = t, (travel, abs(float(x[0, 2])))
    return last_moving, *at_rest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scenario', type=Path, default=HERE.parent / 'config/scenarios/paper.yaml')
    ap.add_argument('--robot', type=int, default=1)
    ap.add_argument('--delay-periods', type=int, default=3)
    args = ap.parse_args(argv)
    sc = load_scenario(args.scenario)
    prm = ControllerParams(scenario=str(args.scenario), robot_id=args.robot)
    period = 1.0 / prm.control_rate_hz

    def lead_for(decel):
        return StopLead(
            sc.robot(args.robot).params,
            prm.stop_time_s,
            sc.control,
            sc.disturbance.accel_bound,
            margin_s=prm.stop_margin_s,
            speed_max_mps=prm.stop_speed_max_mps,
            turn_rate_max_radps=prm.stop_turn_rate_max_radps,
            decel_mps2=decel,
            period_s=period,
        )

    lead, gentle = lead_for(prm.stop_decel_mps2), lead_for(0.0)
    timeout = prm.pose_timeout_s
    print(
        f'lead_max {lead.max_s:.3f} s (time to rest {lead.time_to_rest_max_s:.3f} s + margin '
        f'{lead.margin_s:g} s); with K_p on v {gentle.max_s:.3f} s; decel {lead.decel_mps2:g} '
        f'm/s^2; peak torque {lead.peak_torque_nm:.3f} N m; loop {args.delay_periods} periods late'
    )
    print(
        '| v0 [m/s] | omega0 [rad/s] | time to rest (closed form) | simulated | lead | '
        'stop begins at age | at rest by age (+ one period) | travel while braking | '
        'travel from the last pose to rest | with K_p on v: stop begins at age |'
    )
    print('|---|---|---|---|---|---|---|---|---|---|')
    worst = 0.0
    for v0, w0 in SPEEDS:
        ttr, lead_s = lead.time_to_rest(v0, w0), lead.lead_s(v0, w0)
        begins = timeout - lead_s
        sim_t, sim_d, sim_h = simulate(
            sc, args.robot, prm, lead.decel_mps2, v0, w0, args.delay_periods
        )
        worst = max(worst, begins + period + sim_t)
        held = (begins + period) * abs(v0), (begins + period) * abs(w0)
        print(
            f'| {v0:g} | {w0:g} | {ttr:.3f} s | {sim_t:.3f} s | {lead_s:.3f} s | {begins:.3f} s | '
            f'{begins + ttr:.3f} s | {sim_d * 1e3:.0f} mm, {sim_h:.2f} rad | '
            f'{(held[0] + sim_d) * 1e3:.0f} mm, {held[1] + sim_h:.2f} rad | '
            f'{timeout - gentle.lead_s(v0, w0):.3f} s |'
        )
    bound = timeout + period
    print(f'simulated at rest by age {worst:.3f} s (target {bound:.3f} s)')
    return 0 if worst <= bound + 1e-9 else 1


if __name__ == '__main__':
    sys.exit(main())
