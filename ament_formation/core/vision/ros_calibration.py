"""Camera intrinsics from ROS: a ``camera_calibration`` YAML file or the fields of a
sensor_msgs/CameraInfo.

The ROS camera calibrator (``ros2 run camera_calibration cameracalibrator``) and
``camera_info_manager`` store a camera as::

    image_width: 640
    image_height: 480
    camera_name: overhead
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}
    rectification_matrix: {rows: 3, cols: 3, data: [...]}
    projection_matrix: {rows: 3, cols: 4, data: [...]}

and a camera driver publishes the same on ``camera_info`` beside ``image_raw``. The tracker
works on the raw (distorted) image, so it uses the size, K and D; R and P (which describe the
rectified image) are checked for shape and finiteness only. Distortion models: ``plumb_bob``
(OpenCV's k1 k2 p1 p2 k3) and ``rational_polynomial`` when its k4..k6 are zero (the same model);
others are refused. The camera's mounting is not part of a ROS calibration: it stays in the
project's ``camera.yaml`` (:mod:`camera_model`), whose intrinsics these replace
(:func:`apply_intrinsics`).

Every problem is a :class:`ConfigError` naming the file (or ``camera_info``) and the field.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math
from pathlib import Path

import numpy as np

from ament_formation.core.config_files import read_user_yaml
from ament_formation.core.errors import ConfigError, excerpt
from ament_formation.core.vision.camera_model import CameraModel

KEYS = (
    'image_width',
    'image_height',
    'camera_name',
    'camera_matrix',
    'distortion_model',
    'distortion_coefficients',
    'rectification_matrix',
    'projection_matrix',
)
REQUIRED = ('image_width', 'image_height', 'camera_matrix', 'distortion_model',
            'distortion_coefficients')
_SKEW_TOLERANCE = 1e-6  # |K[0, 1]| / fx below this counts as no skew


@dataclass(frozen=True)
class Intrinsics:
    """Image size [px], camera matrix terms [px] and distortion [k1, k2, p1, p2, k3]."""

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    distortion: tuple[float, float, float, float, float]
    camera_name: str = ''

    def close_to(self, other: 'Intrinsics', rel: float = 1e-9) -> bool:
        """True when every term equals ``other``'s within ``rel`` (relative, 1e-12 absolute)."""
        a, b = self._terms(), other._terms()
        return all(abs(x - y) <= max(rel * max(abs(x), abs(y)), 1e-12) for x, y in zip(a, b))

    def _terms(self) -> tuple[float, ...]:
        return (self.width_px, self.height_px, self.fx_px, self.fy_px, self.cx_px, self.cy_px,
                *self.distortion)


def apply_intrinsics(camera: CameraModel, intr: Intrinsics, source: str) -> CameraModel:
    """``camera`` (mounting and frame rate kept) with the intrinsics ``intr`` from ``source``."""
    try:
        return replace(
            camera,
            width_px=intr.width_px,
            height_px=intr.height_px,
            fx_px=intr.fx_px,
            fy_px=intr.fy_px,
            cx_px=intr.cx_px,
            cy_px=intr.cy_px,
            distortion=intr.distortion,
        )
    except ConfigError as err:
        raise ConfigError(err.problem, 'camera_matrix', source) from None


def _matrix(value, field: str, rows: int, cols: int, source: str) -> np.ndarray:
    """A ``{rows, cols, data}`` mapping (YAML) or a flat list (CameraInfo) → (rows, cols)."""
    if isinstance(value, dict):
        extra = sorted(set(value) - {'rows', 'cols', 'data'})
        if extra:
            raise ConfigError('unknown key (allowed: rows, cols, data)', f'{field}.{extra[0]}',
                              source)
        if value.get('rows') != rows or value.get('cols') != cols:
            raise ConfigError(
                f'must be {rows}x{cols} (got rows {excerpt(value.get("rows"))}, cols '
                f'{excerpt(value.get("cols"))})', field, source)
        data = value.get('data')
    else:
        data = value
    if not isinstance(data, (list, tuple, np.ndarray)) or len(data) != rows * cols:
        n = len(data) if isinstance(data, (list, tuple, np.ndarray)) else excerpt(data)
        raise ConfigError(f'needs {rows * cols} numbers (got {n})', field, source)
    out = []
    for i, v in enumerate(data):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
                or not math.isfinite(float(v)):
            raise ConfigError(f'data[{i}]: {excerpt(v)} is not a finite number', field, source)
        out.append(float(v))
    return np.array(out).reshape(rows, cols)


def _size(value, field: str, source: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) \
            or not 16 <= int(value) <= 16384:
        raise ConfigError(f'must be an integer in [16, 16384] px (got {excerpt(value)})', field,
                          source)
    return int(value)


def _distortion(model, coeffs, source: str) -> tuple[float, float, float, float, float]:
    if model not in ('plumb_bob', 'rational_polynomial'):
        raise ConfigError(
            f'{excerpt(model)} is not supported (plumb_bob: k1 k2 p1 p2 k3; recalibrate with '
            'that model)', 'distortion_model', source)
    n = len(coeffs)
    if model == 'plumb_bob' and n not in (4, 5):
        raise ConfigError(f'plumb_bob needs 5 coefficients k1 k2 p1 p2 k3 (got {n})',
                          'distortion_coefficients', source)
    if model == 'rational_polynomial':
        if n != 8:
            raise ConfigError(f'rational_polynomial needs 8 coefficients (got {n})',
                              'distortion_coefficients', source)
        if any(abs(c) > 0.0 for c in coeffs[5:]):
            raise ConfigError(
                'rational_polynomial with k4, k5, k6 not all zero is not supported (recalibrate '
                'with plumb_bob)', 'distortion_coefficients', source)
    d = [float(c) for c in coeffs[:5]] + [0.0] * (5 - min(n, 5))
    return tuple(d)  # type: ignore[return-value]


def intrinsics_from_fields(
    width, height, model, d, k, r=None, p=None, name: str = '', source: str = 'camera_info'
) -> Intrinsics:
    """Validated intrinsics from CameraInfo-like fields (K, R, P flat lists or YAML matrices)."""
    w = _size(width, 'image_width', source)
    h = _size(height, 'image_height', source)
    data = d.get('data') if isinstance(d, dict) else d
    n = len(data) if isinstance(data, (list, tuple, np.ndarray)) and len(data) else 5
    coeffs = _matrix(d, 'distortion_coefficients', 1, n, source).ravel()
    dist = _distortion(model, list(coeffs), source)
    km = _matrix(k, 'camera_matrix', 3, 3, source)
    if km[1, 0] != 0.0 or km[2, 0] != 0.0 or km[2, 1] != 0.0 or km[2, 2] != 1.0:
        raise ConfigError('must be [fx, 0, cx, 0, fy, cy, 0, 0, 1]', 'camera_matrix', source)
    if abs(km[0, 1]) > _SKEW_TOLERANCE * abs(km[0, 0]):
        raise ConfigError(f'skew {km[0, 1]:g} is not supported (must be 0)', 'camera_matrix',
                          source)
    if r is not None and not (isinstance(r, (list, tuple, np.ndarray)) and len(r) == 0):
        _matrix(r, 'rectification_matrix', 3, 3, source)
    if p is not None and not (isinstance(p, (list, tuple, np.ndarray)) and len(p) == 0):
        _matrix(p, 'projection_matrix', 3, 4, source)
    intr = Intrinsics(w, h, float(km[0, 0]), float(km[1, 1]), float(km[0, 2]), float(km[1, 2]),
                      dist, str(name or ''))
    apply_intrinsics(CameraModel(), intr, source)  # validates focal lengths, principal point
    return intr


def load_ros_calibration(path: str | Path) -> Intrinsics:
    """Read a ROS ``camera_calibration`` YAML file; ConfigError naming the file and field."""
    path = Path(path)
    source = str(path)
    data = read_user_yaml(path, 'camera_calibration file')  # the safe reader (config_files)
    if not isinstance(data, dict):
        raise ConfigError('must be a mapping (a ROS camera_calibration file)', None, source)
    unknown = sorted(str(k) for k in set(data) - set(KEYS))
    if unknown:
        raise ConfigError(f'unknown key (allowed: {", ".join(KEYS)})', unknown[0], source)
    for key in REQUIRED:
        if key not in data:
            raise ConfigError('missing', key, source)
    return intrinsics_from_fields(
        data['image_width'],
        data['image_height'],
        data['distortion_model'],
        data['distortion_coefficients'],
        data['camera_matrix'],
        data.get('rectification_matrix'),
        data.get('projection_matrix'),
        name=data.get('camera_name', ''),
        source=source,
    )


def ros_calibration_dict(camera: CameraModel, camera_name: str = 'camera') -> dict:
    """The ROS ``camera_calibration`` mapping of ``camera``'s intrinsics (R = I, P = [K | 0])."""
    k = [float(v) for v in camera.k.ravel()]
    return {
        'image_width': camera.width_px,
        'image_height': camera.height_px,
        'camera_name': camera_name,
        'camera_matrix': {'rows': 3, 'cols': 3, 'data': k},
        'distortion_model': 'plumb_bob',
        'distortion_coefficients': {'rows': 1, 'cols': 5,
                                    'data': [float(v) for v in camera.distortion]},
        'rectification_matrix': {'rows': 3, 'cols': 3,
                                 'data': [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]},
        'projection_matrix': {'rows': 3, 'cols': 4,
                              'data': k[0:3] + [0.0] + k[3:6] + [0.0] + k[6:9] + [0.0]},
    }
