"""Overhead camera model: pinhole intrinsics, Brown–Conrady distortion, mounting (extrinsics).

Frames
------
world : x, y on the floor, z up [m].
camera: OpenCV optical frame (x right, y down in the image, z along the optical axis).
pixel : OpenCV convention, pixel centres at integer coordinates, (u, v) = (column, row) [px].

Mounting (extrinsics) is given the way one installs a ceiling camera: the optical centre is
``height_m`` above the floor point ``position_m``; with ``yaw = tilt = roll = 0`` it looks straight
down with image +u along world +x and image +v along world −y. The camera-to-world rotation is

    R_wc = Rz(yaw) · diag(1, −1, −1) · Rx(tilt) · Rz(roll)

(tilt turns the optical axis towards image −v, i.e. world +y for yaw 0; roll turns the image
about the optical axis). Any rotation can be written this way (ZXZ Euler angles), so a floor
calibration (solvePnP) converts back into these fields (:meth:`CameraModel.from_pose`).

Distortion is OpenCV's 5-coefficient model (k1, k2, p1, p2, k3).

The YAML file (``config/camera.yaml``) is read and written by :func:`load_camera_yaml` and
:func:`save_camera_yaml`; ``floor`` gives the tracked floor area (centre and size, world frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from functools import cached_property
import math
from pathlib import Path

import cv2
import numpy as np
import yaml

from ament_formation.core.config_files import read_user_yaml
from ament_formation.core.errors import ConfigError

_R0 = np.diag(
    [1.0, -1.0, -1.0]
)  # camera looking straight down: image +u = world +x, +v = world -y


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _finite(name: str, value: float, positive: bool = False) -> None:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ConfigError(f'must be a finite number (got {value!r})', name)
    if positive and not value > 0:
        raise ConfigError(f'must be > 0 (got {value!r})', name)


def undistort_normalized(pixels_px: np.ndarray, k: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Distorted pixels (N, 2) → ideal normalized image coordinates (N, 2) [x/z, y/z].

    Iterates to 1e-12 (OpenCV's default 5 iterations leave ~0.1 px near the corners of a wide
    lens). Works with OpenCV 4.7+ (``undistortPointsIter``) and 5.x (``criteria`` argument).
    """
    pts = np.ascontiguousarray(pixels_px, dtype=np.float64).reshape(-1, 1, 2)
    if len(pts) == 0:
        return np.zeros((0, 2))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    if hasattr(cv2, 'undistortPointsIter'):  # OpenCV 4.x
        out = cv2.undistortPointsIter(pts, k, dist, None, None, criteria)
    else:  # OpenCV 5.x
        out = cv2.undistortPoints(pts, k, dist, None, None, None, criteria)
    return out.reshape(-1, 2)


def rotation_vector(r: np.ndarray) -> np.ndarray:
    """(3,) axis-angle (Rodrigues) vector of the rotation matrix ``r`` (3, 3).

    Accurate over the whole range, including rotations near pi, where cv2.Rodrigues loses up to
    half the digits; a camera looking straight down is a rotation by pi about a floor axis.
    """
    r = np.asarray(r, dtype=np.float64)
    w = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])  # sin(theta) a
    c = 0.5 * (np.trace(r) - 1.0)  # cos(theta)
    s = float(np.linalg.norm(w))
    theta = math.atan2(s, c)
    if c > 0.0:  # theta < pi/2: the skew part is well conditioned
        return w if s < 1e-15 else w * (theta / s)
    b = (0.5 * (r + r.T) - c * np.eye(3)) / (1.0 - c)  # symmetric part: a a^T
    k = int(np.argmax(np.diag(b)))
    a = b[:, k] / math.sqrt(b[k, k])
    if float(a @ w) < 0.0:
        a = -a
    return a * theta


@dataclass(frozen=True)
class CameraModel:
    """One calibrated camera: image size, intrinsics, distortion, mounting. SI units, world
    frame.
    """

    width_px: int = 640
    height_px: int = 480
    fps_hz: float = 30.0
    fx_px: float = 540.0
    fy_px: float = 540.0
    cx_px: float = 319.5
    cy_px: float = 239.5
    distortion: tuple[float, float, float, float, float] = (-0.18, 0.03, 0.0005, -0.0003, 0.0)
    position_m: tuple[float, float] = (0.0, 0.0)  # floor point below the optical centre
    height_m: float = 2.86  # optical centre above the floor
    yaw_rad: float = 0.0
    tilt_rad: float = 0.0
    roll_rad: float = 0.0

    def __post_init__(self) -> None:
        for name in ('width_px', 'height_px'):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or not 16 <= v <= 16384:
                raise ConfigError(f'must be an integer in [16, 16384] px (got {v!r})', name)
        for name in ('fps_hz', 'fx_px', 'fy_px', 'height_m'):
            _finite(name, getattr(self, name), positive=True)
        for name in ('cx_px', 'cy_px', 'yaw_rad', 'tilt_rad', 'roll_rad'):
            _finite(name, getattr(self, name))
        if not (0.0 <= self.cx_px <= self.width_px and 0.0 <= self.cy_px <= self.height_px):
            raise ConfigError(
                f'principal point ({self.cx_px}, {self.cy_px}) px lies outside the '
                f'{self.width_px}x{self.height_px} image',
                'cx_px',
            )
        if len(self.distortion) != 5:
            raise ConfigError(
                f'needs 5 coefficients k1 k2 p1 p2 k3 (got {len(self.distortion)})', 'distortion'
            )
        for i, v in enumerate(self.distortion):
            _finite(f'distortion[{i}]', v)
        if len(self.position_m) != 2:
            raise ConfigError('needs [x, y] in m', 'position_m')
        for i, v in enumerate(self.position_m):
            _finite(f'position_m[{i}]', v)
        if abs(self.tilt_rad) >= math.radians(80):
            raise ConfigError(
                f'must be within ±80° of straight down (got {self.tilt_rad} rad)', 'tilt_rad'
            )

    # ---------------------------------------------------------------- matrices
    @cached_property
    def k(self) -> np.ndarray:
        """(3, 3) camera matrix K."""
        return np.array(
            [[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]]
        )

    @cached_property
    def dist(self) -> np.ndarray:
        """(5,) distortion coefficients [k1, k2, p1, p2, k3]."""
        return np.array(self.distortion, dtype=np.float64)

    @cached_property
    def r_wc(self) -> np.ndarray:
        """(3, 3) rotation camera → world (columns: camera axes in world)."""
        return _rz(self.yaw_rad) @ _R0 @ _rx(self.tilt_rad) @ _rz(self.roll_rad)

    @cached_property
    def center_w(self) -> np.ndarray:
        """(3,) optical centre in world [m]."""
        return np.array([self.position_m[0], self.position_m[1], self.height_m])

    @cached_property
    def rvec(self) -> np.ndarray:
        """(3,) Rodrigues vector world → camera (OpenCV solvePnP convention)."""
        return rotation_vector(self.r_wc.T)

    @cached_property
    def tvec(self) -> np.ndarray:
        """(3,) translation world → camera [m]: X_c = R_cw X_w + t."""
        return -self.r_wc.T @ self.center_w

    @property
    def size_px(self) -> tuple[int, int]:
        """(width, height) [px]."""
        return (self.width_px, self.height_px)

    # ---------------------------------------------------------------- mappings
    def project(self, points_w: np.ndarray, distort: bool = True) -> np.ndarray:
        """World points (N, 3) [m] → pixels (N, 2) [px] (with lens distortion unless told not
        to).
        """
        pts = np.ascontiguousarray(points_w, dtype=np.float64).reshape(-1, 3)
        if len(pts) == 0:
            return np.zeros((0, 2))
        dist = self.dist if distort else np.zeros(5)
        return cv2.projectPoints(pts, self.rvec, self.tvec, self.k, dist)[0].reshape(-1, 2)

    def floor_to_pixel(self, xy_m: np.ndarray, z_m: float = 0.0) -> np.ndarray:
        """Points (N, 2) on the plane z = ``z_m`` [m] (world) → distorted pixels (N, 2) [px]."""
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        return self.project(np.column_stack([xy, np.full(len(xy), float(z_m))]))

    def rays_w(self, pixels_px: np.ndarray) -> np.ndarray:
        """Distorted pixels (N, 2) → unnormalised viewing-ray directions (N, 3) in world."""
        xn = undistort_normalized(pixels_px, self.k, self.dist)
        rays_c = np.column_stack([xn, np.ones(len(xn))])
        return rays_c @ self.r_wc.T

    def pixel_to_floor(self, pixels_px: np.ndarray, z_m: float = 0.0) -> np.ndarray:
        """Distorted pixels (N, 2) [px] → points (N, 2) [m] on the plane z = ``z_m`` (world).

        Rays that do not hit the plane in front of the camera give NaN.
        """
        d = self.rays_w(pixels_px)
        with np.errstate(divide='ignore', invalid='ignore'):
            t = (float(z_m) - self.center_w[2]) / d[:, 2]
        t = np.where(t > 0, t, np.nan)
        return self.center_w[:2] + t[:, None] * d[:, :2]

    def ground_sample_m(self, xy_m: np.ndarray, z_m: float = 0.0) -> np.ndarray:
        """Approximate size of one pixel on the plane z = ``z_m``
        at points (N, 2) → (N,) [m/px].
        """
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        px = self.floor_to_pixel(xy, z_m)
        step = 1e-3
        du = self.floor_to_pixel(xy + [step, 0.0], z_m) - px
        dv = self.floor_to_pixel(xy + [0.0, step], z_m) - px
        area_px_per_m2 = np.abs(du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0]) / step**2
        return 1.0 / np.sqrt(area_px_per_m2)

    # ---------------------------------------------------------------- constructors
    @classmethod
    def from_pose(cls, rvec: np.ndarray, tvec: np.ndarray, **intrinsics) -> 'CameraModel':
        """Camera from an OpenCV world → camera pose (rvec, tvec) plus intrinsic fields."""
        r_cw = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
        r_wc = r_cw.T
        center = -r_wc @ np.asarray(tvec, dtype=np.float64).reshape(3)
        m = _R0.T @ r_wc  # = Rz(-yaw) Rx(tilt) Rz(roll)  (ZXZ Euler)
        # atan2, not acos(m22): acos loses half the digits near straight down (tilt ~ 0)
        tilt = math.atan2(math.hypot(m[0, 2], m[1, 2]), m[2, 2])
        if math.sin(tilt) < 1e-9:
            roll = 0.0
            yaw = -math.atan2(m[1, 0], m[0, 0])
        else:
            yaw = -math.atan2(m[0, 2], -m[1, 2])
            roll = math.atan2(m[2, 0], m[2, 1])
        return cls(
            position_m=(float(center[0]), float(center[1])),
            height_m=float(center[2]),
            yaw_rad=yaw,
            tilt_rad=tilt,
            roll_rad=roll,
            **intrinsics,
        )

    def intrinsic_fields(self) -> dict:
        """The fields that do not describe the mounting (to rebuild with another pose)."""
        keep = (
            'width_px',
            'height_px',
            'fps_hz',
            'fx_px',
            'fy_px',
            'cx_px',
            'cy_px',
            'distortion',
        )
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name in keep}

    def with_intrinsics(
        self, k: np.ndarray, dist: np.ndarray, size_px: tuple[int, int]
    ) -> 'CameraModel':
        """The same mounting with a new camera matrix (3, 3), distortion (5,) and image size."""
        d = np.asarray(dist, dtype=float).reshape(-1)[:5]
        d = np.concatenate([d, np.zeros(5 - len(d))])
        return replace(
            self,
            width_px=int(size_px[0]),
            height_px=int(size_px[1]),
            fx_px=float(k[0, 0]),
            fy_px=float(k[1, 1]),
            cx_px=float(k[0, 2]),
            cy_px=float(k[1, 2]),
            distortion=tuple(float(v) for v in d),
        )


@dataclass(frozen=True)
class FloorArea:
    """The rectangle of floor the camera must cover (world frame, axis-aligned)."""

    center_m: tuple[float, float] = (1.2, 0.6)
    size_m: tuple[float, float] = (3.0, 2.4)

    def __post_init__(self) -> None:
        for name in ('center_m', 'size_m'):
            v = getattr(self, name)
            if len(v) != 2:
                raise ConfigError('needs two values [x, y] in m', name)
            for i, x in enumerate(v):
                _finite(f'{name}[{i}]', x, positive=(name == 'size_m'))

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) [m]."""
        (cx, cy), (sx, sy) = self.center_m, self.size_m
        return (cx - sx / 2, cx + sx / 2, cy - sy / 2, cy + sy / 2)


@dataclass(frozen=True)
class CameraSetup:
    """What ``config/camera.yaml`` holds: the camera, the floor it covers, calibration notes."""

    camera: CameraModel = field(default_factory=lambda: CameraModel(position_m=(1.2, 0.6)))
    floor: FloorArea = field(default_factory=FloorArea)
    calibration: dict = field(default_factory=dict)  # free-form record (rms, source, date)


# ------------------------------------------------------------------------ YAML
_TOP_KEYS = {
    'width_px',
    'height_px',
    'fps_hz',
    'intrinsics',
    'distortion',
    'mounting',
    'floor',
    'calibration',
}


def _expect_keys(d: dict, allowed: set[str], where: str, file: str) -> None:
    if not isinstance(d, dict):
        raise ConfigError('must be a mapping', where or None, file)
    unknown = sorted(set(d) - allowed)
    if unknown:
        key = f'{where}.{unknown[0]}' if where else unknown[0]
        raise ConfigError(f'unknown key (allowed: {", ".join(sorted(allowed))})', key, file)


def camera_setup_from_dict(data: dict, file: str = 'camera.yaml') -> CameraSetup:
    """Build a validated CameraSetup from the YAML mapping; errors name file and field."""
    _expect_keys(data, _TOP_KEYS, '', file)
    kw: dict = {}
    try:
        for key in ('width_px', 'height_px', 'fps_hz'):
            if key in data:
                kw[key] = data[key]
        intr = data.get('intrinsics', {})
        _expect_keys(intr, {'fx_px', 'fy_px', 'cx_px', 'cy_px'}, 'intrinsics', file)
        kw.update(intr)
        dist = data.get('distortion', {})
        _expect_keys(dist, {'k1', 'k2', 'p1', 'p2', 'k3'}, 'distortion', file)
        if dist:
            kw['distortion'] = tuple(
                float(dist.get(n, 0.0)) for n in ('k1', 'k2', 'p1', 'p2', 'k3')
            )
        mount = data.get('mounting', {})
        _expect_keys(
            mount, {'position_m', 'height_m', 'yaw_rad', 'tilt_rad', 'roll_rad'}, 'mounting', file
        )
        for key, value in mount.items():
            kw[key] = tuple(value) if key == 'position_m' else value
        camera = CameraModel(**kw)
    except ConfigError as err:
        prefix = (
            'intrinsics'
            if err.field in {'fx_px', 'fy_px', 'cx_px', 'cy_px'}
            else 'mounting'
            if err.field
            and err.field.split('[')[0]
            in {'position_m', 'height_m', 'yaw_rad', 'tilt_rad', 'roll_rad'}
            else None
        )
        err = err.under(prefix) if prefix else err
        raise err.with_file(file) from None
    except TypeError as err:
        raise ConfigError(str(err), None, file) from None
    floor_d = data.get('floor', {})
    _expect_keys(floor_d, {'center_m', 'size_m'}, 'floor', file)
    try:
        floor = FloorArea(**{k: tuple(v) for k, v in floor_d.items()})
    except ConfigError as err:
        raise err.under('floor').with_file(file) from None
    calibration = data.get('calibration', {}) or {}
    if not isinstance(calibration, dict):
        raise ConfigError('must be a mapping', 'calibration', file)
    return CameraSetup(camera, floor, dict(calibration))


def camera_setup_to_dict(setup: CameraSetup) -> dict:
    """The YAML mapping of a CameraSetup (inverse of :func:`camera_setup_from_dict`)."""
    c = setup.camera
    k1, k2, p1, p2, k3 = (float(v) for v in c.distortion)
    out = {
        'width_px': c.width_px,
        'height_px': c.height_px,
        'fps_hz': float(c.fps_hz),
        'intrinsics': {
            'fx_px': float(c.fx_px),
            'fy_px': float(c.fy_px),
            'cx_px': float(c.cx_px),
            'cy_px': float(c.cy_px),
        },
        'distortion': {'k1': k1, 'k2': k2, 'p1': p1, 'p2': p2, 'k3': k3},
        'mounting': {
            'position_m': [float(v) for v in c.position_m],
            'height_m': float(c.height_m),
            'yaw_rad': float(c.yaw_rad),
            'tilt_rad': float(c.tilt_rad),
            'roll_rad': float(c.roll_rad),
        },
        'floor': {
            'center_m': [float(v) for v in setup.floor.center_m],
            'size_m': [float(v) for v in setup.floor.size_m],
        },
    }
    if setup.calibration:
        out['calibration'] = dict(setup.calibration)
    return out


def load_camera_yaml(path: str | Path) -> CameraSetup:
    """Read and validate a camera.yaml; raises ConfigError naming the file and field."""
    data = read_user_yaml(path, 'camera file') or {}
    return camera_setup_from_dict(data, str(path))


_HEADER = """\
# Overhead camera (read by the tracker, the synthetic camera and `formation calibrate`).
# Pixels: OpenCV convention (pixel centres at integers). Distortion: OpenCV k1 k2 p1 p2 k3.
# Mounting: optical centre height_m above floor point position_m (world frame); yaw = tilt = roll
# = 0 looks straight down with image +u along world +x and image +v along world -y.
"""


def save_camera_yaml(setup: CameraSetup, path: str | Path) -> Path:
    """Write ``setup`` to ``path`` (parent folders created); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(
        camera_setup_to_dict(setup), sort_keys=False, default_flow_style=None, width=100
    )
    path.write_text(_HEADER + text)
    return path
