"""Where each equation of the specification (spec/control-law.md) is implemented: label ->
``'module:function'`` (module relative to ``ament_formation.core``). Exactly one function per
label; that function carries the marker comment ``# implements: <label>[, <label> ...]`` on the
line above its ``def`` (or decorator), and no other function in the package carries the label
(test/test_spec_map.py checks both). The simulator, the robot's controller, the arbiter and the
nodes all call these.
"""

SPEC_MAP = {
    'S2': 'model.dynamics:state_derivative_k',  # robot model (16)-(20); RK4: rk4_step_k calls it
    'S2.3': 'model.disturbance:disturbance_k',  # bounded smooth disturbance g(t)
    'S3': 'control.smc:smc_torque_k',  # generic sliding-mode law S3.1, S3.2, S3.5, S3.6
    'S4': 'control.formation:tracking_field_k',  # leader and follower formation field
    'S5': 'control.smc:smc_torque_k',  # sign conventions (sigma = p_dot - V_d)
    'S6': 'control.limit_cycle:ellipse_field_k',  # limit-cycle field S6.3 and derivative S6.4
    'S6.1': 'model.obstacles:obstacle_states',  # obstacle motion (moving, rotating)
    'S6.2': 'model.ellipse:h_value',  # ellipse function h
    'S6.5': 'control.limit_cycle:design_gains',  # gain design psi_dot_max, c_max
    'S6.6': 'control.limit_cycle:choose_direction',  # rotation direction
    'S7': 'control.encounters:decide',  # agent-agent encounters (yield / mutual)
    'S8': 'control.encounters:decide',  # the switching automaton, every decision period
    'S8.3': 'control.law:goals_and_fields',  # formation goal g_i and coordination field V_c
    'S9': 'control.rewiring:FormationGraph.rewire',  # graph rewiring
    'S13.3': 'model.obstacles:avoided_as_one',  # obstacles too close to pass: avoided as one
    'S14': 'control.safety:safe_field',  # speed limit and braking barrier on V_d (issue 13)
    'S10': 'control.estimator:PoseEstimator',  # odometry + latency-compensated camera fusion
    'S10/neighbours': 'control.neighbours:extrapolate_neighbour',  # heard states, to now
}
