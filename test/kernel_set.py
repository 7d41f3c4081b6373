"""The compiled kernels under one name for the tests that compare them with their numpy oracles
(test/oracle_*.py). Each kernel lives in the module named for its equation; this only collects.
"""

from types import SimpleNamespace

from ament_formation.core.control.formation import tracking_field_k
from ament_formation.core.control.limit_cycle import (
    ellipse_field_k,
    gain_schedule_k,
    parking_factor_k,
)
from ament_formation.core.control.smc import smc_torque_k
from ament_formation.core.model.disturbance import (
    disturbance_k,
    disturbance_phasor_advance_k,
    disturbance_phasor_init_k,
)
from ament_formation.core.model.dynamics import (
    commanded_point_accel_k,
    point_velocity_k,
    rk4_step_all,
    rk4_step_k,
    state_derivative_k,
)
from ament_formation.core.model.ellipse import h_value, ray_time, segment_hits

kn = SimpleNamespace(
    commanded_point_accel_k=commanded_point_accel_k,
    disturbance_k=disturbance_k,
    disturbance_phasor_advance_k=disturbance_phasor_advance_k,
    disturbance_phasor_init_k=disturbance_phasor_init_k,
    ellipse_field_k=ellipse_field_k,
    gain_schedule_k=gain_schedule_k,
    h_value=h_value,
    parking_factor_k=parking_factor_k,
    point_velocity_k=point_velocity_k,
    ray_time=ray_time,
    rk4_step_all=rk4_step_all,
    rk4_step_k=rk4_step_k,
    segment_hits=segment_hits,
    smc_torque_k=smc_torque_k,
    state_derivative_k=state_derivative_k,
    tracking_field_k=tracking_field_k,
)
