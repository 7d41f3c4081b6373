"""The sensing options of `formation sim` (and of any command that runs the fast simulator):
``--sensing ideal|camera|camera-stress|camera-perfect`` and overrides of the preset's figures
(core/sim/sensed.py :class:`~ament_formation.core.sim.sensed.SensingParams`).
"""

from __future__ import annotations

import argparse

from ament_formation.core.errors import ConfigError, excerpt

SENSING_CHOICES = ('ideal', 'camera', 'camera-stress', 'camera-perfect')

# option -> SensingParams field
_OVERRIDES = (
    ('--camera-fps', 'fps', float, 'HZ', "camera frame rate [Hz] (default: the scenario's)"),
    ('--camera-latency-s', 'latency_s', float, 'S', 'capture to controller delay [s]'),
    ('--camera-noise-m', 'noise_m', float, 'M', 'position noise, std per axis [m]'),
    ('--camera-noise-rad', 'noise_rad', float, 'RAD', 'heading noise, std [rad]'),
    ('--camera-drop', 'drop_prob', float, 'P', 'probability a robot is missing from a frame'),
    ('--sensing-seed', 'seed', int, 'N', 'seed of the camera noise and drops (default 0)'),
    ('--control-rate-hz', 'control_rate_hz', float, 'HZ', 'controller rate [Hz] (default 100)'),
    ('--state-rate-hz', 'state_rate_hz', float, 'HZ',
     'rate the robots send their state at [Hz] (default 100; lower: each one extrapolated by '
     'its age)'),
)


def add_sensing_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--sensing`` and its overrides to ``parser``."""
    group = parser.add_argument_group(
        'sensing',
        'ideal: the law on the true state at every step (default). camera: what the robots '
        'have (docs/scenarios.md "Sensing"): camera poses with the tracker\'s measured '
        'figures (0.18 mm / 0.15 deg std, 12 ms, no drops), wheel odometry and the S10 '
        'estimator, the controller at 100 Hz with the coordinator; camera-stress: 30 fps, '
        '50 ms, 3 mm, 5 %% drops; camera-perfect: no noise, delay or drops.',
    )
    group.add_argument(
        '--sensing',
        default='ideal',
        metavar='|'.join(SENSING_CHOICES),
        help='sensing model (default ideal)',
    )
    for option, _field, _kind, metavar, text in _OVERRIDES:  # checked by sensing_from_args
        group.add_argument(option, default=None, metavar=metavar, help=text)


def sensing_from_args(args: argparse.Namespace):
    """The :class:`SensingParams` of the parsed options, None for ``--sensing ideal``; a bad
    value or an override without a camera model raises ConfigError naming the option.
    """
    from ament_formation.core.sim.sensed import SensingParams

    given = {}
    for option, field, kind, *_ in _OVERRIDES:
        text = getattr(args, field_attr(option))
        if text is None:
            continue
        try:
            given[(option, field)] = kind(text)
        except ValueError:
            what = 'an integer' if kind is int else 'a number'
            raise ConfigError(f'must be {what} (got {excerpt(text)})', option) from None
    if args.sensing not in SENSING_CHOICES:
        raise ConfigError(
            f'must be one of {", ".join(SENSING_CHOICES)} (got {excerpt(args.sensing)})',
            '--sensing',
        )
    if args.sensing == 'ideal':
        if given:
            option = next(iter(given))[0]
            raise ConfigError('needs --sensing camera, camera-stress or camera-perfect', option)
        return None
    try:
        return SensingParams.preset(args.sensing, **{f: v for (_o, f), v in given.items()})
    except ConfigError as err:
        option = next((o for (o, f) in given if f == err.field), err.field)
        raise ConfigError(err.problem, option) from None


def field_attr(option: str) -> str:
    """The attribute name argparse gives ``option``."""
    return option.lstrip('-').replace('-', '_')
