"""Board check of a new robot (`formation board-check`): each wheel spun in turn with a small
constant torque, its encoder read through the serial protocol, and per wheel: which way the
encoder counts for a positive command, the wheel's direction and the encoder's sign (with an
observation of the wheel), and the motor constant, identified against the firmware's.

What the host can see
---------------------
Only the encoder. Counting up for a positive command means "motor and encoder agree": both
right, or both reversed. Which one is reversed when they disagree, and whether the wheel turns
forward at all, only an observation tells (``seen``: the operator watching the wheel, or the
camera), so the check asks for one and reports the encoder's sign relative to it.

Motor constant
--------------
The firmware drives each motor with duty ``d = tau R / (G eta k V) + omega_enc k G / V``
(core/serial/motor_constants.py): the second term cancels the motor's back-EMF. A motor of
constant k' then gives the free wheel (robot on blocks) of inertia J, viscous friction b and
Coulomb friction f (command-torque equivalent)::

    J domega/dt = (k'/k) (tau - f) - D_w omega,   D_w = b + (k' G^2 eta / R)(k' -/+ k)

``-`` when motor and encoder agree (the compensation cancels the back-EMF), ``+`` when they
disagree (it doubles it). Each wheel is spun from rest at two torques tau1 < tau2 and each
run's encoder angle fitted with a first-order step response sharing one decay rate ``s``:
``theta = theta0 + a (u - (1 - exp(-s u)) / s) / s``, ``u = t - delay``. The apparent damping
``D = s (tau2 - tau1) / (a2 - a1) = (k / k') D_w`` (friction f cancels) gives

    k' = k + D R / (k G^2 eta)     (agree)        k' = D R / (k G^2 eta) - k     (disagree)

neglecting b: its share, ``b R / (k'^2 G^2 eta)``, is 1.7 % of k for the reference wheel and
gear motor (b = 2e-3 N·m·s/rad) and makes the estimate that much high. G, eta and R are taken
as configured: the estimate is the k that makes the firmware's model fit the wheel. When motor
and encoder disagree the wheel only creeps (a few encoder counts per 10 ms period: the doubled
back-EMF damping) and the estimate is rough (±15 % in the simavr firmware); it is reported
(``~``) but not judged: the wiring comes first.

The times of the samples are the board's: the STATUS frames' uptime (every 200 ms), interpolated
in the order of the TELEMETRY frames between them (tools/board_check_cmd.py), so a busy host or
an emulator slower than real time does not distort the fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.serial.motor_constants import MotorConstants

WHEELS = ('left', 'right')
SEEN_VALUES = ('forward', 'backward')
_DELAYS_S = np.arange(0.0, 0.0301, 0.0025)  # command -> wheel response delays tried [s]


@dataclass(frozen=True)
class CheckParams:
    """How the wheels are spun (units in names)."""

    torque_nm: float = 0.04  # the larger of the two test torques; the smaller is half of it
    spin_s: float = 1.0  # longest spin per torque
    speed_fraction: float = 0.6  # a spin ends at this fraction of the no-load speed
    tolerance: float = 0.15  # |k_estimate / k_firmware - 1| allowed
    min_counts: int = 20  # fewer counts for the larger torque: the wheel did not move
    rest_timeout_s: float = 5.0  # longest wait for a wheel to come to rest

    def __post_init__(self) -> None:
        checks = (
            ('torque_nm', 0.001, 3.0, '--torque-nm', 'N·m'),
            ('spin_s', 0.1, 5.0, '--spin-s', 's'),
            ('speed_fraction', 0.05, 0.95, '--speed-fraction', ''),
            ('tolerance', 0.005, 1.0, '--tolerance', ''),
            ('rest_timeout_s', 0.5, 60.0, '--rest-timeout-s', 's'),
        )
        for name, lo, hi, flag, unit in checks:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
                raise ConfigError(f'must be in [{lo:g}, {hi:g}] {unit} (got {v!r})'.strip(), flag)
        if not isinstance(self.min_counts, int) or self.min_counts < 2:
            raise ConfigError(f'must be an integer >= 2 (got {self.min_counts!r})', '--min-counts')

    @property
    def torques_nm(self) -> tuple[float, float]:
        return (0.5 * self.torque_nm, self.torque_nm)


def parse_seen(text: str) -> dict[str, str]:
    """``"left=forward,right=backward"`` → {'left': 'forward', 'right': 'backward'}."""
    out: dict[str, str] = {}
    for part in [p for p in str(text).replace(' ', '').split(',') if p]:
        wheel, _, value = part.partition('=')
        if wheel not in WHEELS or value not in SEEN_VALUES:
            raise ConfigError(
                f'expected left=forward|backward,right=forward|backward (got {text!r})', '--seen'
            )
        out[wheel] = value
    return out


@dataclass(frozen=True)
class Spin:
    """One run: ``torque_nm`` commanded to wheel ``wheel`` (0 left, 1 right) from ``t_s`` = 0
    (the first command's send time); samples (N,) of time [s] and the wheel's encoder angle [rad]
    as the board reports it (unwrapped), relative to the angle at rest before the run.
    """

    wheel: int
    torque_nm: float
    t_s: np.ndarray
    angle_rad: np.ndarray
    ended_by: str  # 'time' | 'speed'


@dataclass(frozen=True)
class StepFit:
    """theta = theta0 + a (u - (1 - e^(-s u)) / s) / s, u = max(t - delay, 0), per spin."""

    decay_per_s: float  # s, shared by the spins
    accel_radps2: tuple[float, ...]  # a of each spin
    offset_rad: tuple[float, ...]
    delay_s: tuple[float, ...]
    rms_rad: float

    @property
    def steady_speed_radps(self) -> tuple[float, ...]:
        """Steady speed a / s of each spin (inf when s <= 0: no steady state)."""
        s = self.decay_per_s
        return tuple(a / s if s > 0 else math.copysign(math.inf, a) for a in self.accel_radps2)


def _basis(t: np.ndarray, s: float, delay: float) -> np.ndarray:
    u = np.maximum(t - delay, 0.0)
    if abs(s * u.max(initial=0.0)) < 1e-6:
        return 0.5 * u * u
    return (u - (-np.expm1(-s * u)) / s) / s


def _fit_one(t: np.ndarray, y: np.ndarray, s: float) -> tuple[float, float, float, float]:
    """Best (sse, a, theta0, delay) of one spin for decay rate s."""
    best = (math.inf, 0.0, 0.0, 0.0)
    for delay in _DELAYS_S:
        g = _basis(t, s, delay)
        m = np.column_stack([g, np.ones_like(g)])
        coef, *_ = np.linalg.lstsq(m, y, rcond=None)
        sse = float(((m @ coef - y) ** 2).sum())
        if sse < best[0]:
            best = (sse, float(coef[0]), float(coef[1]), float(delay))
    return best


def fit_spins(spins: list[Spin]) -> StepFit:
    """Joint least-squares fit of the spins of one wheel: a grid over s (both signs: a runaway
    wheel has s < 0), refined by golden-section search, each spin's a, theta0 (linear) and delay
    (grid of 2.5 ms) at each s.
    """
    data = [(np.asarray(sp.t_s, float), np.asarray(sp.angle_rad, float)) for sp in spins]

    def total(s: float) -> float:
        return sum(_fit_one(t, y, s)[0] for t, y in data)

    grid = np.concatenate(
        [-np.geomspace(30.0, 0.05, 16), [0.0], np.geomspace(0.05, 2000.0, 48)]
    )
    costs = [total(s) for s in grid]
    i = int(np.argmin(costs))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    golden = (math.sqrt(5) - 1) / 2
    a, b = lo, hi
    c, d = b - golden * (b - a), a + golden * (b - a)
    fc, fd = total(c), total(d)
    for _ in range(40):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - golden * (b - a)
            fc = total(c)
        else:
            a, c, fc = c, d, fd
            d = a + golden * (b - a)
            fd = total(d)
    s = c if fc < fd else d
    if costs[i] < min(fc, fd):
        s = float(grid[i])
    fits = [_fit_one(t, y, s) for t, y in data]
    n = sum(len(t) for t, _ in data)
    return StepFit(
        float(s),
        tuple(f[1] for f in fits),
        tuple(f[2] for f in fits),
        tuple(f[3] for f in fits),
        math.sqrt(sum(f[0] for f in fits) / max(n, 1)),
    )


@dataclass(frozen=True)
class WheelReport:
    """The check's findings for one wheel."""

    wheel: str
    counts: int  # encoder counts moved by the larger torque's spin (signed)
    agree: bool | None  # encoder counts up for a positive command (None: did not move)
    direction: str  # 'forward' | 'backward' | 'unknown' (for a positive command)
    encoder_sign: int | None  # +1 counts up while the wheel turns forward, -1 down, None unknown
    fit: StepFit | None
    apparent_damping_nms: float  # D [N·m·s/rad]
    kt_estimate: float  # [N·m/A] (nan: not identified)
    kt_firmware: float
    friction_nm: float  # Coulomb friction, command-torque equivalent [N·m] (nan: unknown)
    reasons: tuple[str, ...] = field(default=())

    @property
    def ok(self) -> bool:
        return not self.reasons

    @property
    def kt_error(self) -> float:
        """k_estimate / k_firmware - 1."""
        return self.kt_estimate / self.kt_firmware - 1.0

    def line(self) -> str:
        """One line: ``left: OK: ...`` or ``left: FAIL: reason; reason (...)``."""
        if self.agree is None:
            facts = f'encoder moved {self.counts:+d} counts'
        else:
            facts = (
                f'turns {self.direction}, encoder counts {"up" if self.counts > 0 else "down"}'
                f' ({self.counts:+d} counts'
                + (f', sign {self.encoder_sign:+d})' if self.encoder_sign else ')')
            )
        if math.isfinite(self.kt_estimate):
            facts += (
                f', motor constant {"~" if not self.agree else ""}{self.kt_estimate:.4f} N·m/A '
                f'(firmware {self.kt_firmware:.4f}, {self.kt_error:+.1%})'
            )
        if math.isfinite(self.friction_nm):
            facts += f', friction {self.friction_nm:.4f} N·m'
        if self.ok:
            return f'{self.wheel}: OK: {facts}'
        return f'{self.wheel}: FAIL: {"; ".join(self.reasons)} ({facts})'


def assess(
    wheel: int,
    spins: list[Spin],
    motor: MotorConstants,
    params: CheckParams,
    seen: str | None = None,
) -> WheelReport:
    """The report of wheel ``wheel`` from its two spins (smaller torque first)."""
    name = WHEELS[wheel]
    tpr = motor.ticks_per_rev
    big = max(spins, key=lambda sp: sp.torque_nm)
    counts = int(round(float(big.angle_rad[-1]) * tpr / (2 * math.pi))) if len(big.t_s) else 0
    k = motor.torque_constant_nm_per_a
    nan = math.nan
    if abs(counts) < params.min_counts:
        return WheelReport(
            name, counts, None, 'unknown', None, None, nan, nan, k, nan,
            (f'did not turn ({counts:+d} encoder counts for {big.torque_nm:g} N·m): motor, '
             'H-bridge or encoder not connected, no motor supply, or the wheel is blocked',),
        )
    agree = counts > 0
    reasons: list[str] = []
    if seen is None:
        direction, enc = 'unknown', None
        if not agree:
            reasons.append(
                'encoder counts down for a positive command: the motor or the encoder is '
                f'reversed (watch the wheel, --seen {name}=forward|backward, to tell which)'
            )
    else:
        direction = seen
        enc = (1 if agree else -1) * (1 if seen == 'forward' else -1)
        if seen == 'backward':
            reasons.append("turns backward for a positive command: swap the motor's two leads")
        if enc < 0:
            reasons.append(
                'encoder counts down while the wheel turns forward: swap its A and B lines'
            )
    fit = fit_spins(spins)
    (t1, t2), (a1, a2) = (sp.torque_nm for sp in spins), fit.accel_radps2
    kt, friction, damping = nan, nan, nan
    if a2 != a1 and (a2 - a1) * (1 if agree else -1) > 0:
        damping = fit.decay_per_s * (t2 - t1) / (a2 - a1) * (1 if agree else -1)
        scale = motor.resistance_ohm / (k * motor.gear_ratio ** 2 * motor.gear_efficiency)
        kt = k + damping * scale if agree else damping * scale - k
        friction = t1 - a1 * (t2 - t1) / (a2 - a1)
    if not (math.isfinite(kt) and kt > 0):
        kt = nan
        reasons.append(
            "motor constant not identified (the two spins do not fit the firmware's motor "
            'model: check the motor supply voltage and gear ratio it was built with)'
        )
    elif agree and abs(kt / k - 1.0) > params.tolerance:  # (disagreeing: a rough estimate,
        # the wiring comes first: the firmware's compensation then doubles the back-EMF and the
        # wheel creeps at a few counts per period)
        reasons.append(
            f"motor constant {kt:.4f} N·m/A is {kt / k - 1.0:+.0%} off the firmware's {k:.4f} "
            f'(tolerance {params.tolerance:.0%}): set MOTOR_TORQUE_CONSTANT_NM_PER_A (or the '
            "gear ratio, resistance, supply) in firmware/src/config.h to the motor's"
        )
    return WheelReport(
        name, counts, agree, direction, enc, fit, damping, kt, k, friction, tuple(reasons)
    )
