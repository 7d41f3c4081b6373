"""Frozen, self-validating parameter sets shared by the core, the nodes and the tests.

Every ``__post_init__`` raises :class:`ConfigError` naming the field, the value and the unit.
Defaults are the spec's (S2.3 robot, S3.3/S3.5 sliding-mode gains, S4 formation feedback,
S6.1/S6.5/S7/S8 avoidance and switching).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
import math
from typing import Any

from ament_formation.core.errors import ConfigError, excerpt


def param(
    default: Any,
    description: str,
    *,
    range: tuple[float, float] | None = None,  # noqa: A002
    live: bool = False,
    dynamic_typing: bool = False,
) -> Any:
    """A dataclass field that is also a ROS parameter (ros/params.py ``declare_dataclass``).

    ``description``: what it is, with its unit (shown by ``ros2 param describe``);
    ``range``: inclusive [lo, hi] bounds (a FloatingPointRange/IntegerRange on the parameter; the
    dataclass still checks open ends and cross-field rules); ``live``: the node applies a change at
    run time (otherwise the parameter is read-only); ``dynamic_typing``: the parameter takes more
    than one type (e.g. a camera source given as a device index or a path). Metadata only: the
    dataclass stays plain and ROS-free.
    """
    return field(
        default=default,
        metadata={
            'description': description,
            'range': range,
            'live': live,
            'dynamic_typing': dynamic_typing,
        },
    )


def _require(cond: bool, field: str, value, problem: str) -> None:
    if not cond:
        raise ConfigError(f'{problem} (got {excerpt(value)})', field)


def _finite_positive(obj, names: tuple[str, ...]) -> None:
    for name in names:
        value = getattr(obj, name)
        _require(
            isinstance(value, (int, float)) and math.isfinite(value) and value > 0,
            name,
            value,
            'must be a finite number > 0',
        )


@dataclass(frozen=True)
class RobotParams:
    """Physical parameters of one differential-drive robot (spec S2.2, S2.3)."""

    platform_mass_kg: float = 2.5  # m_c: platform without wheels
    wheel_mass_kg: float = 0.10  # m_w: one wheel with its rotor
    wheel_radius_m: float = 0.035  # r
    axle_length_m: float = 0.20  # a (wheel separation); L = a/2
    com_offset_m: float = 0.05  # d: controlled point (CoM) ahead of the axle midpoint
    platform_inertia_kgm2: float = 0.0167  # I_c: platform yaw inertia about its CoM
    torque_limit_nm: float = 0.15  # tau_max per wheel
    body_radius_m: float = 0.10  # R_body: footprint radius about p
    wheel_spin_inertia_kgm2: float | None = None  # I_w; None: solid disc 1/2 m_w r^2
    wheel_diameter_inertia_kgm2: float | None = None  # I_m; None: solid disc 1/4 m_w r^2

    def __post_init__(self) -> None:
        _finite_positive(
            self,
            (
                'platform_mass_kg',
                'wheel_mass_kg',
                'wheel_radius_m',
                'axle_length_m',
                'com_offset_m',
                'platform_inertia_kgm2',
                'torque_limit_nm',
                'body_radius_m',
            ),
        )
        for name in ('wheel_spin_inertia_kgm2', 'wheel_diameter_inertia_kgm2'):
            value = getattr(self, name)
            if value is not None:
                _require(
                    isinstance(value, (int, float)) and math.isfinite(value) and value >= 0,
                    name,
                    value,
                    'must be a finite number >= 0 [kg m^2]',
                )
        # r appears squared in divisors (S2.2): a wheel of 1e-300 m made them zero
        _require(
            1e-3 <= self.wheel_radius_m <= 10.0,
            'wheel_radius_m',
            self.wheel_radius_m,
            'must be in [0.001, 10] m',
        )

    @property
    def wheel_spin_inertia(self) -> float:
        """I_w [kg m^2]."""
        if self.wheel_spin_inertia_kgm2 is not None:
            return float(self.wheel_spin_inertia_kgm2)
        return 0.5 * self.wheel_mass_kg * self.wheel_radius_m**2

    @property
    def wheel_diameter_inertia(self) -> float:
        """I_m [kg m^2]."""
        if self.wheel_diameter_inertia_kgm2 is not None:
            return float(self.wheel_diameter_inertia_kgm2)
        return 0.25 * self.wheel_mass_kg * self.wheel_radius_m**2

    @property
    def mass_tilde_kg(self) -> float:
        """m~ = m_c + 2 m_w + 2 I_w / r^2 (S2.2)."""
        r = self.wheel_radius_m
        return self.platform_mass_kg + 2 * self.wheel_mass_kg + 2 * self.wheel_spin_inertia / r**2

    @property
    def accel_limit_mps2(self) -> float:
        """Largest point acceleration the torque limit allows, 2 tau_max / (m~ r) [m/s^2] (S2.2;
        the compiled law's own copy is ``core.control.safety.accel_limit``).
        """
        return 2.0 * self.torque_limit_nm / (self.mass_tilde_kg * self.wheel_radius_m)

    @property
    def inertia_tilde_kgm2(self) -> float:
        """I~ = I_c + m_c d^2 + 2 m_w L^2 + 2 I_m + 2 L^2 I_w / r^2 (S2.2)."""
        half_axle = 0.5 * self.axle_length_m
        r = self.wheel_radius_m
        return (
            self.platform_inertia_kgm2
            + self.platform_mass_kg * self.com_offset_m**2
            + 2 * self.wheel_mass_kg * half_axle**2
            + 2 * self.wheel_diameter_inertia
            + 2 * half_axle**2 * self.wheel_spin_inertia / r**2
        )

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


@dataclass(frozen=True)
class ControlGains:
    """Sliding-mode and formation-feedback gains (S3.3, S3.5, S4)."""

    reaching_rate_mps2: float = 0.15  # lambda: guaranteed reaching rate
    switching_gain_mps2: float = 0.27  # K = lambda + sup|S1 g| + sup|Delta a| (S3.3)
    boundary_layer_mps: float = 0.01  # epsilon (S3.5); must exceed K * T_s
    formation_gain_per_s: float = 0.5  # alpha (S4)
    formation_speed_cap_mps: float = 0.10  # v_cap (S4)
    control_period_s: float = 0.001  # T_s of the sliding-mode loop (ZOH torques)

    def __post_init__(self) -> None:
        _finite_positive(self, tuple(f.name for f in fields(self)))
        _require(
            self.switching_gain_mps2 >= self.reaching_rate_mps2,
            'switching_gain_mps2',
            self.switching_gain_mps2,
            'must be >= reaching_rate_mps2 (S3.3: K = lambda + bounds)',
        )
        _require(
            self.boundary_layer_mps >= self.switching_gain_mps2 * self.control_period_s,
            'boundary_layer_mps',
            self.boundary_layer_mps,
            'must be >= switching_gain_mps2 * control_period_s (S3.5 sampling rule)',
        )


@dataclass(frozen=True)
class AvoidanceParams:
    """Nested-ellipse scales, limit-cycle gain design and switching timing (S6.1, S6.5, S7, S8)."""

    emergency_scale: float = 1.05  # rho_em: E_j
    limit_cycle_scale: float = 1.10  # rho_L: L_j (the limit cycle)
    heading_scale: float = 1.15  # rho_in: I_j (ray test)
    clearance_scale: float = 1.00  # rho_clr: C_j (segment test)
    protected_scale: float = 1.80  # kappa: Q_j
    tangential_speed_mps: float = 0.08  # v_tan for obstacles (S6.5)
    agent_tangential_speed_mps: float = 0.12  # v_tan for agent-agent encounters
    radial_speed_mps: float = 0.04  # v_rad (S6.5); keep <= v_tan / 2
    gain_start_fraction: float = 0.3  # beta0 in (0, 1]
    gain_time_constant_s: float = 1.5  # tau_g
    parking_anomaly_rad: float = 0.5  # psi_slow (parking factor mu)
    dwell_s: float = 0.3  # T_dwell (S8.3 item 4)
    min_avoid_s: float = 1.0  # T_min
    cooldown_s: float = 1.0  # T_cool (S8.4)
    agent_keepout_margin_m: float = 0.05  # R_aa = 2 R_body + margin (S7)

    def __post_init__(self) -> None:
        _finite_positive(self, tuple(f.name for f in fields(self)))
        _require(
            self.clearance_scale >= 1.0,
            'clearance_scale',
            self.clearance_scale,
            'must be >= 1 (C_j contains P_j)',
        )
        _require(
            1.0 < self.emergency_scale < self.limit_cycle_scale,
            'emergency_scale',
            self.emergency_scale,
            'must satisfy 1 < emergency_scale < limit_cycle_scale (S8.4)',
        )
        _require(
            self.limit_cycle_scale < self.heading_scale < self.protected_scale,
            'heading_scale',
            self.heading_scale,
            'must satisfy limit_cycle_scale < heading_scale < protected_scale',
        )
        _require(
            self.gain_start_fraction <= 1.0,
            'gain_start_fraction',
            self.gain_start_fraction,
            'must be in (0, 1]',
        )
        _require(
            self.radial_speed_mps <= 0.5 * self.tangential_speed_mps + 1e-12,
            'radial_speed_mps',
            self.radial_speed_mps,
            'must be <= tangential_speed_mps / 2 (S6.5)',
        )
