"""Where each equation of the specification (docs/control-law.md) is implemented: label ->
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
    'S3.2': 'control.law:robot_law_k',  # the law of one robot in its mode (S3 with S4/S6/S7)
    'S7': 'control.arbitration:arbitrate',  # robot-robot encounters: the coordinator's table
    'S7.1': 'control.arbitration:arbitrate',  # one authority for robot encounters
    'S7.2': 'control.arbitration:robot_threats',  # the robot threat test
    'S7.5': 'control.arbitration:right_of_way',  # right of way between teams
    'S8': 'control.switching:robot_transitions',  # a robot's own switching table
    'S8.1': 'control.switching:threat_test',  # the entry test
    'S8.3': 'control.switching:cleared',  # the exit test, items 1-3
    'S8.7': 'control.switching:robot_transitions',  # the robot's table
    'S8.9': 'control.switching:stalled',  # the progress monitor
    'S8.3/goal': 'control.law:goal_k',  # formation goal g_i and coordination field V_c
    'S9': 'control.rewiring:FormationGraph.rewire',  # graph rewiring
    'S13.3': 'model.obstacles:avoided_as_one',  # obstacles too close to pass: avoided as one
    'S15': 'control.safety:safe_field',  # speed limit and braking barrier on V_d
    'S16': 'control.floor:floor_side',  # the floor's edges in the sense choice
    'S17': 'control.progress:leader_reference',  # a leader's reference at its progress
    'S17.1': 'control.progress:rate_targets',  # the progress rate targets of the teams
    'S17.3': 'control.arbitration:coordinate',  # the coordinator's decision and the mission end
    'S10': 'control.estimator:wheel_update_k',  # odometry + latency-compensated camera fusion
    'S10.1': 'control.estimator:wheel_update_k',  # the estimator
    'S10.3': 'control.agent:agent_tick_k',  # the robot agent's control period
}
