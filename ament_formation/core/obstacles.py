"""Obstacle motion: prohibited ellipses P_j whose centre and orientation move in time (S6.1).

A centre moves with constant velocity plus an optional sinusoidal oscillation; the orientation
turns at a constant rate. States for all M obstacles at time t come back as arrays, so the
vectorised field code never loops over obstacles in Python.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from ament_formation.core.errors import ConfigError


@dataclass(frozen=True)
class ObstacleSpec:
    """One obstacle: the prohibited region P_j of the controlled point (footprint included)."""

    name: str
    center_m: tuple[float, float]
    semi_axes_m: tuple[float, float]  # (r1, r2) of P_j, r1 >= r2 > 0 after normalisation
    orientation_rad: float = 0.0  # phi_j(0)
    velocity_mps: tuple[float, float] = (0.0, 0.0)
    angular_velocity_radps: float = 0.0
    oscillation_amplitude_m: tuple[float, float] = (0.0, 0.0)  # centre += A sin(2 pi t / T)
    oscillation_period_s: float = 0.0  # 0: no oscillation

    def __post_init__(self) -> None:
        if not self.name or not isinstance(self.name, str):
            raise ConfigError('must be a non-empty string', 'name')
        r1, r2 = self.semi_axes_m
        if not (math.isfinite(r1) and math.isfinite(r2) and r1 > 0 and r2 > 0):
            raise ConfigError(
                f'semi-axes must be finite and > 0 m (got {list(self.semi_axes_m)})', 'semi_axes_m'
            )
        if (
            any(a != 0.0 for a in self.oscillation_amplitude_m)
            and not self.oscillation_period_s > 0
        ):
            raise ConfigError(
                'must be > 0 s when an oscillation amplitude is set', 'oscillation_period_s'
            )

    @property
    def moves(self) -> bool:
        return any(v != 0.0 for v in self.velocity_mps) or any(
            a != 0.0 for a in self.oscillation_amplitude_m
        )

    @property
    def rotates(self) -> bool:
        return self.angular_velocity_radps != 0.0


@dataclass(frozen=True)
class ObstacleStates:
    """All M obstacles at one instant. Shapes: (M, 2) or (M,); world frame, SI units."""

    center_m: np.ndarray  # (M, 2) x~_j
    velocity_mps: np.ndarray  # (M, 2) x~dot_j
    accel_mps2: np.ndarray  # (M, 2) x~ddot_j
    phi_rad: np.ndarray  # (M,)   phi_j
    phi_dot_radps: np.ndarray  # (M,)
    phi_ddot_radps2: np.ndarray  # (M,)
    semi_axes_m: np.ndarray  # (M, 2) (r1, r2) of P_j


class ObstacleField:
    """Vectorised motion of a fixed set of obstacles."""

    def __init__(self, specs: tuple[ObstacleSpec, ...] | list[ObstacleSpec]):
        self.specs = tuple(specs)
        self.names = tuple(s.name for s in self.specs)
        m = len(self.specs)
        self._c0 = np.array([s.center_m for s in self.specs], dtype=float).reshape(m, 2)
        self._v = np.array([s.velocity_mps for s in self.specs], dtype=float).reshape(m, 2)
        self._amp = np.array([s.oscillation_amplitude_m for s in self.specs], dtype=float).reshape(
            m, 2
        )
        period = np.array([s.oscillation_period_s for s in self.specs], dtype=float)
        self._w = np.where(period > 0, 2 * np.pi / np.where(period > 0, period, 1.0), 0.0)
        self._phi0 = np.array([s.orientation_rad for s in self.specs], dtype=float)
        self._phidot = np.array([s.angular_velocity_radps for s in self.specs], dtype=float)
        self._axes = np.array([s.semi_axes_m for s in self.specs], dtype=float).reshape(m, 2)

    def __len__(self) -> int:
        return len(self.specs)

    def at(self, t_s: float) -> ObstacleStates:
        """States of every obstacle at time ``t_s`` [s]."""
        wt = self._w * t_s
        sin_wt = np.sin(wt)[:, None]
        cos_wt = np.cos(wt)[:, None]
        w = self._w[:, None]
        center = self._c0 + self._v * t_s + self._amp * sin_wt
        velocity = self._v + self._amp * w * cos_wt
        accel = -self._amp * w**2 * sin_wt
        zeros = np.zeros(len(self.specs))
        return ObstacleStates(
            center_m=center,
            velocity_mps=velocity,
            accel_mps2=accel,
            phi_rad=self._phi0 + self._phidot * t_s,
            phi_dot_radps=self._phidot.copy(),
            phi_ddot_radps2=zeros,
            semi_axes_m=self._axes.copy(),
        )
