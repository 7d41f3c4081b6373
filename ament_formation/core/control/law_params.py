"""Every number the law uses, in one validated set (docs/control-law.md S18).

:class:`LawParams` holds the scenario's gains (S3.3, S3.5, S4: :class:`ControlGains`) and
avoidance geometry and timing (S6.1, S6.5, S7, S8: :class:`AvoidanceParams`), plus the
thresholds this project adds to the specification. Each added threshold is a field made by
:func:`threshold`, which records its unit and its reason; docs/control-law.md S18 lists them
(test/test_law_params.py checks that the table and this class agree). ``LawParams.compiled()``
gives the named tuple of floats the compiled code reads (:data:`LawK`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
import math

from ament_formation.core.errors import ConfigError, excerpt
from ament_formation.core.params import AvoidanceParams, ControlGains


def threshold(default: float, unit: str, reason: str, *, lo: float = 0.0, hi: float = math.inf):
    """A law threshold beyond the specification: its default, ``unit`` and ``reason`` (the table
    of docs/control-law.md S18), valid in (``lo``, ``hi``].
    """
    return field(default=default, metadata={'unit': unit, 'reason': reason, 'range': (lo, hi)})


@dataclass(frozen=True)
class LawParams:
    """The law's parameter set (module docstring). Build with :meth:`for_scenario`."""

    gains: ControlGains = ControlGains()
    avoidance: AvoidanceParams = AvoidanceParams()
    decision_period_s: float = threshold(
        0.01, 's', 'S8 guards run every control period of a robot (S10: 100 Hz)', hi=1.0
    )
    imminent_s: float = threshold(
        1.5, 's', 'inside Q, a ray reaching P this soon is an emergency (S14.2: the margin '
        'grows with the approach speed, not only rho_em)'
    )
    robot_horizon_s: float = threshold(
        12.0, 's', 'a robot is a threat only when contact with its I is this close in time '
        '(two robots drifting together slowly are not, S7.2)'
    )
    teammate_speed_mps: float = threshold(
        0.02, 'm/s', 'robots moving (or resting) together slower than this relative to each '
        'other are no threat but in an emergency (S14.3, S7.2)'
    )
    teammate_release_speed_mps: float = threshold(
        0.04, 'm/s', 'a pair released from an encounter with each other stays exempt up to this '
        '(hysteresis on an estimated speed, S14.3)'
    )
    retarget_margin: float = threshold(
        0.1, '1 (h_L)', 'a robot re-targets to another threat only when its h_L is lower by this '
        '(hysteresis, S8.2)'
    )
    reason_dwell_s: float = threshold(
        2.0, 's', 'a switch between an obstacle and a robot reason waits this long after the '
        'last switch, unless inside the obstacle E (no flipping between reasons, S8.4)'
    )
    mutual_drift_tau_s: float = threshold(
        2.0, 's', "a pair's drift w_c relaxes toward the mean coordination field with this "
        'time constant (S14.1: the drift does not outlive its reason)'
    )
    mutual_drift_cap_mps: float = threshold(
        0.05, 'm/s', "bound of a pair's drift target (S14.1)"
    )
    speed_limit_mps: float = threshold(
        0.25, 'm/s', 'V_d and every velocity feed-forward are clipped to this, below S2.3 v_max '
        '(S15.1: no feed-forward loop runs away)'
    )
    brake_gain_fraction: float = threshold(
        0.4, '1', "the barrier's braking deceleration is this fraction of K: what the S3 loop "
        'realises without feed-forward (S15.2)', hi=1.0
    )
    safety_gap_m: float = threshold(
        0.01, 'm', 'the barrier stops a robot this far outside P, the keep-out circle or the '
        'floor edge (S15.2)'
    )
    safety_range_m: float = threshold(
        0.3, 'm', 'the barrier checks boundaries within this gap (S15.2)'
    )
    safety_lag_s: float = threshold(
        0.3, 's', 'reaction time of the S3 loop before it brakes, in the stopping distance '
        '(S15.2)'
    )
    stall_time_s: float = threshold(
        5.0, 's', 'no progress for this long: the owner of the mode acts (S8.9)'
    )
    stall_distance_m: float = threshold(
        0.05, 'm', 'moving less than this within stall_time_s is no progress (S8.9)'
    )
    at_goal_m: float = threshold(
        0.1, 'm', 'a robot this close to its goal is where it should be: never stalled (S8.9)'
    )
    reform_start_m: float = threshold(
        0.15, 'm', "team error above which a leader's reference slows down (S17)"
    )
    reform_stop_m: float = threshold(
        0.4, 'm', "team error at which a leader's reference waits (S17; below the 0.5 m "
        'of a goal missed)'
    )
    progress_tau_s: float = threshold(
        1.0, 's', "the reference's progress rate follows its target with this time constant: "
        "the reference's acceleration stays bounded (S17)"
    )
    finish_s: float = threshold(
        2.0, 's', 'a reference this close to its end (in path time) waits while any team is not '
        're-formed: the mission ends with every team in formation (S17.3)'
    )
    max_wait_fraction: float = threshold(
        1.0, '1', "a team's reference waits at most this fraction of the free traversal (at least "
        '20 s) in all: then it moves on, so every mission ends (S17.2)'
    )
    make_way_s: float = threshold(
        10.0, 's', 'a robot parked on an obstacle beside a stalled robot stops parking for this '
        'long (it goes round, S8.9)'
    )
    floor_push_m: float = threshold(
        0.05, 'm', "a pair's drift pushes off a floor edge at its cap times the deficit over "
        'this (S16.3)'
    )
    right_of_way_release_m: float = threshold(
        0.9, 'm', 'two teams keep their right of way until no robots of theirs are closer '
        'than this (S7.5)'
    )
    headway_go_m: float = threshold(
        0.8, 'm', 'a team slows down when a moving robot of a team that goes first comes this '
        'close ahead of one of its robots, in its way (S7.5; within right_of_way_release_m, where '
        'the teams are ranked)'
    )
    headway_stop_m: float = threshold(
        0.5, 'm', 'and waits when it is this close: just outside Q of a robot pair (S7.5, '
        'S17.1), so that it follows at a distance instead of yielding and closing up in turn'
    )
    floor_m: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            if 'unit' not in f.metadata:
                continue
            value = getattr(self, f.name)
            lo, hi = f.metadata['range']
            if not (
                isinstance(value, (int, float))
                and not isinstance(value, bool)
                and math.isfinite(value)
                and lo < value <= hi
            ):
                bound = f'<= {hi:g}' if math.isfinite(hi) else 'finite'
                raise ConfigError(
                    f'must be a number > {lo:g} and {bound} [{f.metadata["unit"]}] '
                    f'(got {excerpt(value)})',
                    f.name,
                )
        if self.teammate_release_speed_mps < self.teammate_speed_mps:
            raise ConfigError(
                f'must be >= teammate_speed_mps ({self.teammate_speed_mps:g} m/s) '
                f'(got {self.teammate_release_speed_mps!r})',
                'teammate_release_speed_mps',
            )
        if self.reform_stop_m <= self.reform_start_m:
            raise ConfigError(
                f'must be > reform_start_m ({self.reform_start_m:g} m) '
                f'(got {self.reform_stop_m!r})',
                'reform_stop_m',
            )
        if not self.headway_stop_m < self.headway_go_m <= self.right_of_way_release_m:
            raise ConfigError(
                f'must be > headway_stop_m ({self.headway_stop_m:g} m) and <= '
                f'right_of_way_release_m ({self.right_of_way_release_m:g} m) '
                f'(got {self.headway_go_m!r})',
                'headway_go_m',
            )
        if self.floor_m is not None:
            x0, x1, y0, y1 = (float(v) for v in self.floor_m)
            if not (x0 < x1 and y0 < y1):
                raise ConfigError(f'must be (x_min, x_max, y_min, y_max) (got {self.floor_m})',
                                  'floor_m')

    @classmethod
    def for_scenario(cls, scenario, **overrides) -> 'LawParams':
        """The scenario's gains, avoidance block and floor with these defaults (or
        ``overrides``, fields by name).
        """
        floor = scenario.floor
        bounds = None if floor is None else (*map(float, floor.x_m), *map(float, floor.y_m))
        return cls(gains=scenario.control, avoidance=scenario.avoidance, floor_m=bounds,
                   **overrides)

    def with_(self, **changes) -> 'LawParams':
        """These parameters with ``changes`` (validated again)."""
        return replace(self, **changes)

    @classmethod
    def thresholds(cls) -> dict[str, tuple[float, str, str]]:
        """{name: (default, unit, reason)} of the thresholds beyond the specification."""
        return {
            f.name: (f.default, f.metadata['unit'], f.metadata['reason'])
            for f in fields(cls)
            if 'unit' in f.metadata
        }

    def compiled(self) -> 'LawK':
        """The parameters as the compiled code reads them (:data:`LawK`)."""
        values = {
            **{f.name: getattr(self.gains, f.name) for f in fields(self.gains)},
            **{f.name: getattr(self.avoidance, f.name) for f in fields(self.avoidance)},
            **{name: getattr(self, name) for name in self.thresholds()},
        }
        floor = self.floor_m or (-math.inf, math.inf, -math.inf, math.inf)
        values.update(zip(FLOOR_FIELDS, floor))
        return LawK(**{name: float(values[name]) for name in LawK._fields})


FLOOR_FIELDS = ('floor_x_min_m', 'floor_x_max_m', 'floor_y_min_m', 'floor_y_max_m')


def _law_fields() -> list[str]:
    return (
        [f.name for f in fields(ControlGains)]
        + [f.name for f in fields(AvoidanceParams)]
        + list(LawParams.thresholds())
        + list(FLOOR_FIELDS)
    )


# numba reads a field of a named tuple of floats as fast as a local
from collections import namedtuple  # noqa: E402, I100

LawK = namedtuple('LawK', _law_fields())
LawK.__doc__ = """:class:`LawParams` for the compiled code: a named tuple of floats named as the
fields of ControlGains, AvoidanceParams and LawParams (units there); the floor's four edges are
infinite when the scenario declares none.
"""
