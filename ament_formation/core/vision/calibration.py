"""Camera calibration: intrinsics from ChArUco board views, floor mapping from reference markers.

- :func:`calibrate_intrinsics`: several images of a ChArUco board held at different poses →
  camera matrix and distortion (k1 k2 p1 p2 k3) with ``cv2.calibrateCamera``; the RMS
  reprojection error is reported. Fewer than ``min_views`` usable views is refused.
- :func:`calibrate_floor`: one image of ArUco markers lying flat at known floor positions →
  the camera's mounting (extrinsics) by a planar PnP on all their corners (distortion removed
  first, corners refined to sub-pixel); fewer than 3 markers or markers on one line are refused.

Bad input raises :class:`~ament_formation.core.errors.ConfigError` with one line naming it.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path

import cv2
import numpy as np

from ament_formation.core.config_files import read_user_yaml
from ament_formation.core.errors import ConfigError
from ament_formation.core.vision import aruco_compat
from ament_formation.core.vision.camera_model import CameraModel
from ament_formation.core.vision.marker_tracking import detect, make_detector, refine_corners
from ament_formation.core.vision.robot_marker import (
    aruco_dictionary,
    dictionary_size,
    MarkerLayout,
)

MIN_VIEWS = 5
MIN_CORNERS_PER_VIEW = 8
MIN_FLOOR_MARKERS = 3
COLLINEAR_RATIO = 0.1  # smallest / largest spread of the marker centres


# --------------------------------------------------------------------------- ChArUco board
@dataclass(frozen=True)
class CharucoSpec:
    """A ChArUco board: squares_x × squares_y chessboard squares with markers in the white ones."""

    squares_x: int = 7
    squares_y: int = 5
    square_m: float = 0.04
    marker_m: float = 0.03
    dictionary: str = 'DICT_4X4_50'

    def __post_init__(self) -> None:
        for name in ('squares_x', 'squares_y'):
            v = getattr(self, name)
            if not isinstance(v, int) or not 3 <= v <= 100:
                raise ConfigError(f'must be an integer in [3, 100] (got {v!r})', name)
        for name in ('square_m', 'marker_m'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f'must be > 0 m (got {v!r})', name)
        if self.marker_m >= self.square_m:
            raise ConfigError(
                f'marker {self.marker_m} m must be smaller than the square {self.square_m} m',
                'marker_m',
            )
        need = self.squares_x * self.squares_y // 2
        if dictionary_size(self.dictionary) < need:
            raise ConfigError(
                f'{self.dictionary} has fewer than the {need} markers the board needs',
                'dictionary',
            )

    @staticmethod
    def parse(text: str) -> 'CharucoSpec':
        """``"7x5,0.04,0.03[,DICT_4X4_50]"`` (squares, square and marker side in m) or a YAML file
        with the field names of this class.
        """
        path = Path(text)
        if path.suffix in ('.yaml', '.yml') or path.is_file():
            data = read_user_yaml(path, 'board file') or {}
            if not isinstance(data, dict):
                raise ConfigError('board file must be a mapping', '--board', str(path))
            try:
                return CharucoSpec(**data)
            except TypeError as err:
                raise ConfigError(str(err), '--board', str(path)) from None
            except ConfigError as err:
                raise err.with_file(str(path)) from None
        parts = [p.strip() for p in text.split(',')]
        try:
            sx, sy = (int(v) for v in parts[0].lower().split('x'))
            square, marker = float(parts[1]), float(parts[2])
        except (ValueError, IndexError):
            raise ConfigError(
                f'expected SQUARESxSQUARES,SQUARE_M,MARKER_M[,DICT] or a YAML file (got {text!r})',
                '--board',
            ) from None
        try:
            return CharucoSpec(sx, sy, square, marker, *(parts[3:4]))
        except ConfigError as err:
            raise err.under('--board') from None

    def board(self):
        """The ChArUco board object of the installed OpenCV (4.6 and later, aruco_compat)."""
        return aruco_compat.charuco_board(
            (self.squares_x, self.squares_y),
            self.square_m,
            self.marker_m,
            aruco_dictionary(self.dictionary),
        )

    @property
    def size_m(self) -> tuple[float, float]:
        return (self.squares_x * self.square_m, self.squares_y * self.square_m)

    def image(self, px_per_square: int = 40) -> np.ndarray:
        """(H, W) uint8 picture of the board, exactly covering it (no margin)."""
        size = (self.squares_x * px_per_square, self.squares_y * px_per_square)
        return aruco_compat.board_image(self.board(), size, margin_px=0, border_bits=1)


@dataclass(frozen=True)
class IntrinsicsResult:
    """Camera matrix (3, 3), distortion (5,) [k1 k2 p1 p2 k3], image size, RMS error [px]."""

    k: np.ndarray
    dist: np.ndarray
    size_px: tuple[int, int]
    rms_px: float
    views_used: int
    views_skipped: tuple[str, ...]


def calibrate_intrinsics(
    images: list[tuple[str, np.ndarray]], spec: CharucoSpec, min_views: int = MIN_VIEWS
) -> IntrinsicsResult:
    """Intrinsics from ChArUco views ``images`` = [(name, mono8 (H, W))]."""
    if min_views < 3:
        raise ConfigError(f'must be >= 3 (got {min_views})', '--min-views')
    if not images:
        raise ConfigError('no images given', 'IMAGES')
    board = spec.board()
    detector = aruco_compat.CharucoDetector(board)
    size = images[0][1].shape[1], images[0][1].shape[0]
    obj_pts, img_pts, skipped = [], [], []
    for name, img in images:
        if (img.shape[1], img.shape[0]) != size:
            raise ConfigError(
                f'is {img.shape[1]}x{img.shape[0]} px, the first image is {size[0]}x{size[1]}',
                name,
            )
        ch_corners, ch_ids = detector.detect(img)
        if ch_ids is None or len(ch_ids) < MIN_CORNERS_PER_VIEW:
            skipped.append(name)
            continue
        if aruco_compat.charuco_collinear(board, ch_ids):
            skipped.append(name)
            continue
        obj = aruco_compat.charuco_object_points(board, ch_ids)
        obj_pts.append(obj.reshape(-1, 1, 3).astype(np.float32))
        img_pts.append(np.asarray(ch_corners).reshape(-1, 1, 2).astype(np.float32))
    if len(obj_pts) < min_views:
        raise ConfigError(
            f'only {len(obj_pts)} usable view(s) of the {spec.squares_x}x{spec.squares_y} '
            f'board (need >= {min_views} with >= {MIN_CORNERS_PER_VIEW} non-collinear '
            f'corners each)',
            'IMAGES',
        )
    k0 = np.array(
        [[max(size), 0, (size[0] - 1) / 2], [0, max(size), (size[1] - 1) / 2], [0, 0, 1.0]]
    )
    rms, k, dist, _, _ = cv2.calibrateCamera(
        obj_pts, img_pts, size, k0, np.zeros(5), flags=cv2.CALIB_USE_INTRINSIC_GUESS
    )
    return IntrinsicsResult(
        k, np.asarray(dist, float).reshape(-1)[:5], size, float(rms), len(obj_pts), tuple(skipped)
    )


# --------------------------------------------------------------------------- floor
@dataclass(frozen=True)
class ReferenceMarkers:
    """ArUco markers lying flat on the floor at known poses (world frame).

    ``poses``: (N, 3) rows [x_m, y_m, yaw_rad] of each marker's centre; yaw is the direction of
    the marker's top edge (corner 0 → 1), as for robot markers.
    """

    ids: tuple[int, ...]
    poses: tuple[tuple[float, float, float], ...]
    size_m: float
    dictionary: str = 'DICT_4X4_50'

    def __post_init__(self) -> None:
        MarkerLayout(self.dictionary, self.size_m, (0.0, 0.0), 0.0)  # validates size, dictionary
        if len(self.ids) != len(set(self.ids)):
            raise ConfigError('marker ids must be unique', 'markers')
        if len(self.ids) < MIN_FLOOR_MARKERS:
            raise ConfigError(
                f'{len(self.ids)} reference marker(s); need >= {MIN_FLOOR_MARKERS} '
                'not on one line',
                'markers',
            )
        check_not_collinear(np.array(self.poses)[:, :2], 'markers')

    @property
    def layout(self) -> MarkerLayout:
        return MarkerLayout(self.dictionary, self.size_m, (0.0, 0.0), 0.0)


def check_not_collinear(points_m: np.ndarray, field: str) -> None:
    """Raise ConfigError when points (N, 2) are fewer than 3 or lie (nearly) on one line."""
    pts = np.asarray(points_m, dtype=float).reshape(-1, 2)
    if len(pts) < MIN_FLOOR_MARKERS:
        raise ConfigError(
            f'{len(pts)} marker(s); need >= {MIN_FLOOR_MARKERS} not on one line', field
        )
    s = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    if s[0] <= 0 or s[1] / s[0] < COLLINEAR_RATIO:
        raise ConfigError(
            f'marker centres are (nearly) collinear (spread ratio {s[1] / max(s[0], 1e-12):.3f}'
            f' < {COLLINEAR_RATIO}); the floor plane is not determined',
            field,
        )


def load_reference_markers(path: str | Path) -> ReferenceMarkers:
    """YAML: ``{size_m: 0.15, dictionary: DICT_4X4_50, markers: [{id: 10, center_m: [x, y],
    yaw_rad: 0.0}, ...]}``.
    """
    path = Path(path)
    data = read_user_yaml(path, 'reference marker file') or {}
    if not isinstance(data, dict):
        raise ConfigError('must be a mapping', None, str(path))
    unknown = sorted(set(data) - {'size_m', 'dictionary', 'markers'})
    if unknown:
        raise ConfigError(
            'unknown key (allowed: size_m, dictionary, markers)', unknown[0], str(path)
        )
    if 'size_m' not in data:
        raise ConfigError('missing (marker side in m)', 'size_m', str(path))
    ids, poses = [], []
    for i, m in enumerate(data.get('markers') or []):
        if not isinstance(m, dict) or 'id' not in m or 'center_m' not in m:
            raise ConfigError('needs id and center_m', f'markers[{i}]', str(path))
        extra = sorted(set(m) - {'id', 'center_m', 'yaw_rad'})
        if extra:
            raise ConfigError(
                'unknown key (allowed: id, center_m, yaw_rad)',
                f'markers[{i}].{extra[0]}',
                str(path),
            )
        try:
            x, y = (float(v) for v in m['center_m'])
            ids.append(int(m['id']))
            poses.append((x, y, float(m.get('yaw_rad', 0.0))))
        except (TypeError, ValueError):
            raise ConfigError('center_m must be [x, y] in m', f'markers[{i}]', str(path)) from None
    try:
        return ReferenceMarkers(
            tuple(ids),
            tuple(poses),
            float(data['size_m']),
            str(data.get('dictionary', 'DICT_4X4_50')),
        )
    except ConfigError as err:
        raise err.with_file(str(path)) from None


@dataclass(frozen=True)
class FloorResult:
    """The camera with its mounting from the floor calibration, and how well it fits."""

    camera: CameraModel
    rms_px: float  # reprojection RMS of the reference corners
    max_floor_error_m: (
        float  # largest distance between a known corner and its image mapped to the floor
    )
    used_ids: tuple[int, ...]


def calibrate_floor(image: np.ndarray, refs: ReferenceMarkers, camera: CameraModel) -> FloorResult:
    """Mounting of ``camera`` (its intrinsics are kept) from an image of reference markers."""
    if image.shape[::-1] != camera.size_px:
        raise ConfigError(
            f'is {image.shape[1]}x{image.shape[0]} px, the camera is '
            f'{camera.width_px}x{camera.height_px}',
            'IMAGE',
        )
    layout = refs.layout
    corners, ids = detect(make_detector(layout, camera.size_px, None, subpix=True), image)
    known = {m: i for i, m in enumerate(refs.ids)}
    sel = [j for j, m in enumerate(ids) if int(m) in known and list(ids).count(m) == 1]
    if len(sel) < MIN_FLOOR_MARKERS:
        raise ConfigError(
            f'found {len(sel)} of the {len(refs.ids)} reference markers in the image '
            f'(need >= {MIN_FLOOR_MARKERS})',
            'IMAGE',
        )
    used = tuple(int(ids[j]) for j in sel)
    poses = np.array([refs.poses[known[m]] for m in used])
    check_not_collinear(poses[:, :2], 'IMAGE (markers found)')
    normalized = refine_corners(image, corners[sel], camera, layout.bits)  # (K, 4, 2)
    world = layout.corners_w(poses)  # (K, 4, 2)
    obj = np.column_stack([world.reshape(-1, 2), np.zeros(4 * len(used))])
    img = normalized.reshape(-1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, img, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise ConfigError('the marker corners do not determine a camera pose', 'IMAGE')
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, np.eye(3), None, rvec, tvec)
    new = CameraModel.from_pose(rvec.reshape(3), tvec.reshape(3), **camera.intrinsic_fields())
    detected_px = cv2.projectPoints(
        np.column_stack([img, np.ones(len(img))]), np.zeros(3), np.zeros(3), new.k, new.dist
    )[0].reshape(-1, 2)
    reproj = new.project(obj)
    rms = float(np.sqrt(((reproj - detected_px) ** 2).sum(axis=1).mean()))
    on_floor = new.pixel_to_floor(detected_px, 0.0)
    err = float(np.linalg.norm(on_floor - obj[:, :2], axis=1).max())
    return FloorResult(new, rms, err, used)
