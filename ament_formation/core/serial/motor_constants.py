"""The motor board's DC-motor model (firmware/src/motor_model.h) and its constants
(firmware/src/config.h), on the host.

The firmware turns a wheel torque command into H-bridge duty with a steady-state brushed DC motor
behind a gearbox, per wheel::

    d = clamp(tau * R / (G eta k V) + omega * k G / V, -1, 1)

with ``k`` the **motor constant** (``MOTOR_TORQUE_CONSTANT_NM_PER_A``: torque constant k_t in
N·m/A, equal to the back-EMF constant k_e in V·s/rad), R the winding resistance, G the gear
ratio, eta its efficiency, V the supply voltage and omega the wheel speed the firmware measures
from its encoder. The second term cancels the motor's back-EMF so that the wheel gets the
commanded torque at any speed; it cancels it exactly when ``k`` is the motor's own constant. The
real motor gives the wheel ``tau_w = (d V - k' G omega) k' G eta / R`` (:meth:`torque`).

:func:`parse_config_h` reads the constants from config.h (``#define NAME value``), the way the
firmware is built; ``overrides`` stand for ``make CFLAGS_EXTRA=-DNAME=value``.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
import re

from ament_formation.core.errors import ConfigError

# config.h name -> MotorConstants field
CONFIG_NAMES = {
    'MOTOR_SUPPLY_V': 'supply_v',
    'MOTOR_TORQUE_CONSTANT_NM_PER_A': 'torque_constant_nm_per_a',
    'MOTOR_RESISTANCE_OHM': 'resistance_ohm',
    'MOTOR_GEAR_RATIO': 'gear_ratio',
    'MOTOR_GEAR_EFFICIENCY': 'gear_efficiency',
    'ENCODER_TICKS_PER_REV': 'ticks_per_rev',
}
_DEFINE = re.compile(r'^\s*#\s*define\s+(\w+)\s+\(?\s*([-+]?[0-9.]+(?:[eE][-+]?\d+)?)[fFuUlL]*')


@dataclass(frozen=True)
class MotorConstants:
    """One wheel's drive as the firmware models it (defaults: firmware/src/config.h)."""

    supply_v: float = 12.0
    torque_constant_nm_per_a: float = 0.0175  # k = k_t [N·m/A] = k_e [V·s/rad]
    resistance_ohm: float = 2.4
    gear_ratio: float = 30.0  # motor turns per wheel turn
    gear_efficiency: float = 1.0
    ticks_per_rev: int = 1440  # wheel-side encoder counts per revolution (x4)

    def __post_init__(self) -> None:
        for name in ('supply_v', 'torque_constant_nm_per_a', 'resistance_ohm', 'gear_ratio'):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (
                math.isfinite(v) and v > 0
            ):
                raise ConfigError(f'must be a finite number > 0 (got {v!r})', name)
        e = self.gear_efficiency
        if not (isinstance(e, (int, float)) and 0.0 < e <= 1.0):
            raise ConfigError(f'must be in (0, 1] (got {e!r})', 'gear_efficiency')
        t = self.ticks_per_rev
        if isinstance(t, bool) or not isinstance(t, int) or not 1 <= t <= 0xFFFF:
            raise ConfigError(f'must be an integer in [1, 65535] (got {t!r})', 'ticks_per_rev')

    @property
    def duty_per_nm(self) -> float:
        """Duty per wheel torque at rest, R / (G eta k V) [1/(N·m)]."""
        return self.resistance_ohm / (
            self.gear_ratio * self.gear_efficiency * self.torque_constant_nm_per_a * self.supply_v
        )

    @property
    def duty_per_radps(self) -> float:
        """Duty that cancels the back-EMF per wheel speed, k G / V [s/rad]."""
        return self.torque_constant_nm_per_a * self.gear_ratio / self.supply_v

    @property
    def back_emf_damping_nms(self) -> float:
        """Wheel torque per wheel speed of a motor at a fixed voltage, k^2 G^2 eta / R
        [N·m·s/rad].
        """
        kg = self.torque_constant_nm_per_a * self.gear_ratio
        return kg * kg * self.gear_efficiency / self.resistance_ohm

    @property
    def no_load_speed_radps(self) -> float:
        """Wheel speed at full duty without load, V / (k G) [rad/s]."""
        return self.supply_v / (self.torque_constant_nm_per_a * self.gear_ratio)

    def duty(self, torque_nm: float, speed_radps: float) -> float:
        """The firmware's duty in [-1, 1] for wheel torque [N·m] at the measured speed [rad/s]."""
        d = torque_nm * self.duty_per_nm + speed_radps * self.duty_per_radps
        if d != d:  # NaN: never drive on garbage
            return 0.0
        return max(-1.0, min(1.0, d))

    def torque(self, duty: float, speed_radps: float) -> float:
        """Wheel torque [N·m] this motor gives at ``duty`` and wheel speed [rad/s]."""
        d = max(-1.0, min(1.0, duty))
        kg = self.torque_constant_nm_per_a * self.gear_ratio
        return (d * self.supply_v - kg * speed_radps) / self.resistance_ohm * kg * (
            self.gear_efficiency
        )


def parse_config_h(
    text: str, source: str = 'config.h', overrides: dict[str, float] | None = None
) -> MotorConstants:
    """The motor constants defined in firmware/src/config.h text (``overrides``: -D values)."""
    values: dict[str, float] = {}
    for line in text.splitlines():
        m = _DEFINE.match(line)
        if m and m.group(1) in CONFIG_NAMES:
            values[m.group(1)] = float(m.group(2))
    for name, value in (overrides or {}).items():
        if name not in CONFIG_NAMES:
            raise ConfigError(
                f'unknown constant (known: {", ".join(CONFIG_NAMES)})', f'--define {name}'
            )
        values[name] = float(value)
    missing = [n for n in CONFIG_NAMES if n not in values]
    if missing:
        raise ConfigError(f'no #define {missing[0]}', None, source)
    kw = {CONFIG_NAMES[n]: v for n, v in values.items()}
    ticks = kw['ticks_per_rev']
    kw['ticks_per_rev'] = int(ticks) if float(ticks).is_integer() else ticks
    try:
        return MotorConstants(**kw)
    except ConfigError as err:
        raise err.with_file(source) from None


def load_config_h(path: str | Path, overrides: dict[str, float] | None = None) -> MotorConstants:
    """:func:`parse_config_h` of a file; ConfigError naming it when it cannot be read."""
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8', errors='replace')
    except OSError as err:
        raise ConfigError(f'cannot read ({err.strerror})', None, str(path)) from None
    return parse_config_h(text, str(path), overrides)
