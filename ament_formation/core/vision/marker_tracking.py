"""Marker tracking: ArUco detection → sub-pixel corners → floor plane → robot poses, by marker id.

Pipeline for one frame (:class:`MarkerTracker.step`):

1. **Find** the markers. A tracked marker is first looked for where its track predicts it: the
   predicted corners are refined (step 2) and accepted when the edge fits are clean, land within
   a few pixels of the prediction and the code cells read the marker's id (no detector at all).
   Markers that fail are searched with the ArUco detector (:mod:`aruco_compat`: OpenCV 4.6+) in
   regions of interest around their predictions, packed side by side into one small mosaic image
   (one detector call). Markers still missing trigger a full-frame search (rate-limited while
   they stay lost); without a list of expected markers, a full-frame search also runs every
   ``full_frame_period`` frames to pick up new ones.
2. **Refine** each corner (:mod:`~ament_formation.core.vision.corner_refinement`, compiled):
sub-pixel
   edge points are sampled across the marker's four outer edges (gradient centroid along the
   edge normal), undistorted, and a straight line is fitted to each edge; corners are the
   intersections of adjacent edge lines (ideal image coordinates, so lens distortion is removed
   before fitting).
3. **Map** the corners onto the marker plane (z = ``layout.height_m``) by intersecting viewing
   rays; the marker centre is the mean of the four plane corners, the heading is the mean
   direction of the marker's x axis, and the controlled point is the centre minus the body-frame
   offset (:class:`~ament_formation.core.vision.robot_marker.MarkerLayout`).
4. **Gate**: a pose that moved farther than the robot can in the elapsed time is rejected
   (kept out of the track) unless it persists for ``reacquire_after`` frames.
5. **Uncertainty**: the four plane corners are compared with a perfect square of the known size
   (least-squares fit); the residual, floored at ``pixel_noise_px`` times the local ground
   sample, gives σ of the centre and of the heading, propagated to the controlled point.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

import cv2
import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.vision import aruco_compat, corner_refinement
from ament_formation.core.vision.camera_model import CameraModel, undistort_normalized
from ament_formation.core.vision.robot_marker import aruco_dictionary, MarkerLayout

_FAILED_SIGMA_PX = 0.5  # corner σ when the edge fit failed (detector corners kept)
_MOSAIC_GAP_PX = 6
_MOSAIC_FILL = 128
_MOSAIC_ROW_PX = 4096
_MAX_TRACK_SIGMA_PX = 0.5  # predicted-corner tracking: edge fit must be this clean …
_MAX_TRACK_SHIFT_PX = 4.0  # … land this close to the prediction …
_MIN_CODE_CONTRAST = 30.0  # … and read the right code with white − black >= this [grey levels]


@dataclass(frozen=True)
class TrackerConfig:
    """Tracking parameters (units in names)."""

    max_speed_mps: float = 1.5  # faster apparent motion is a jump (rejected)
    max_turn_rate_radps: float = 12.0
    jump_margin_m: float = 0.03  # slack added to the speed gate
    jump_margin_rad: float = 0.25
    reacquire_after: int = 5  # consecutive rejected detections that reset a track
    track_timeout_s: float = 1.0  # a marker unseen this long is no longer tracked
    use_roi: bool = True
    roi_margin_px: float = 6.0  # ROI border around the last and predicted marker
    full_frame_period: int = 30  # frames between full-frame searches for new markers
    # (only when no expected_ids are given)
    lost_retry_period: int = 5  # frames between full-frame searches for lost markers
    pixel_noise_px: float = 0.03  # floor of the per-corner uncertainty [px]
    refine_edges: bool = True  # sub-pixel edge-line corner refinement (else OpenCV subpix)

    def __post_init__(self) -> None:
        for name in ('max_speed_mps', 'max_turn_rate_radps', 'track_timeout_s', 'pixel_noise_px'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f'must be a finite number > 0 (got {v!r})', name)
        for name in ('jump_margin_m', 'jump_margin_rad', 'roi_margin_px'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError(f'must be a finite number >= 0 (got {v!r})', name)
        for name in ('reacquire_after', 'full_frame_period', 'lost_retry_period'):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ConfigError(f'must be an integer >= 1 (got {v!r})', name)


@dataclass(frozen=True)
class MarkerPoses:
    """Poses measured in one frame. K markers; world frame; SI units."""

    ids: np.ndarray  # (K,) marker ids
    poses: np.ndarray  # (K, 3) rows [x_m, y_m, theta_rad] of the controlled point
    sigma_xy_m: np.ndarray  # (K,) 1-σ position uncertainty (per axis) of the controlled point
    sigma_theta_rad: np.ndarray  # (K,) 1-σ heading uncertainty
    corners_px: np.ndarray  # (K, 4, 2) detected corners TL, TR, BR, BL [px, distorted image]

    @staticmethod
    def empty() -> 'MarkerPoses':
        return MarkerPoses(
            np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros((0, 4, 2))
        )

    def take(self, mask: np.ndarray) -> 'MarkerPoses':
        return MarkerPoses(
            self.ids[mask],
            self.poses[mask],
            self.sigma_xy_m[mask],
            self.sigma_theta_rad[mask],
            self.corners_px[mask],
        )

    def __len__(self) -> int:
        return len(self.ids)


class UndistortLookup:
    """Fast undistortion: ideal normalized coordinates of every pixel, precomputed once and
    interpolated bilinearly (error < 0.001 px: the mapping is smooth at pixel scale).
    """

    def __init__(self, camera: CameraModel):
        w, h = camera.size_px
        uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        xn = undistort_normalized(np.column_stack([uu.ravel(), vv.ravel()]), camera.k, camera.dist)
        self._grid = xn.reshape(h, w, 2)
        self._camera = camera

    def __call__(self, pixels_px: np.ndarray) -> np.ndarray:
        """Distorted pixels (N, 2) → ideal normalized coordinates (N, 2)."""
        px = np.asarray(pixels_px, dtype=np.float64).reshape(-1, 2)
        if len(px) == 0:
            return np.zeros((0, 2))
        w, h = self._camera.size_px
        inside = (px[:, 0] >= 0) & (px[:, 0] <= w - 1) & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)
        # bilinear interpolation with exact weights (cv2.remap quantises them to 1/32 px)
        x = np.clip(px[:, 0].astype(np.float64), 0, w - 1.000001)
        y = np.clip(px[:, 1].astype(np.float64), 0, h - 1.000001)
        x0, y0 = x.astype(np.int64), y.astype(np.int64)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        g = self._grid
        out = (1 - fy) * ((1 - fx) * g[y0, x0] + fx * g[y0, x0 + 1]) + fy * (
            (1 - fx) * g[y0 + 1, x0] + fx * g[y0 + 1, x0 + 1]
        )
        if not inside.all():
            out[~inside] = undistort_normalized(px[~inside], self._camera.k, self._camera.dist)
        return out


def make_detector(
    layout: MarkerLayout,
    image_size_px: tuple[int, int],
    camera: CameraModel | None = None,
    subpix: bool = True,
    single_scale: bool = False,
) -> aruco_compat.MarkerDetector:
    """An ArUco detector tuned for markers of ``layout`` seen by ``camera``.

    The smallest marker perimeter accepted is 60 % of the smallest the camera can see on the floor
    (relative to ``image_size_px``, the size of the image the detector will be given).
    Adaptive thresholding uses windows of 5 and 15 px, or (``single_scale``, for ROIs where the
    marker size is known) one window of about two code cells: half the cost per marker.
    """
    dictionary = aruco_dictionary(layout.dictionary)  # refuses an OpenCV without cv2.aruco
    p = aruco_compat.detector_parameters()
    min_perimeter_px = 40.0
    if camera is not None:
        gsd_max = float(
            camera.ground_sample_m(
                np.array([camera.pixel_to_floor(np.array([[0.0, 0.0]]), layout.height_m)[0]]),
                layout.height_m,
            )[0]
        )
        if math.isfinite(gsd_max):
            min_perimeter_px = 0.6 * 4 * layout.size_m / gsd_max
    p.minMarkerPerimeterRate = max(min_perimeter_px / max(image_size_px), 0.005)
    p.maxMarkerPerimeterRate = 4.0
    p.adaptiveThreshWinSizeMin = 5
    p.adaptiveThreshWinSizeMax = 15
    p.adaptiveThreshWinSizeStep = 10
    if single_scale:
        cell_px = min_perimeter_px / 0.6 / 4 / (layout.bits + 2)
        win = max(3, int(round(2 * cell_px)) | 1)
        p.adaptiveThreshWinSizeMin = p.adaptiveThreshWinSizeMax = win
    p.minDistanceToBorder = 1
    p.perspectiveRemovePixelPerCell = 6
    if subpix:
        p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        p.cornerRefinementWinSize = 2
        p.cornerRefinementMaxIterations = 20
        p.cornerRefinementMinAccuracy = 0.02
    return aruco_compat.MarkerDetector(dictionary, p)


def detect(
    detector: aruco_compat.MarkerDetector, image: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Markers in a mono8 image → corners (K, 4, 2) [px] and ids (K,)."""
    corners, ids = detector.detect(image)
    if ids is None or len(ids) == 0:
        return np.zeros((0, 4, 2)), np.zeros(0, np.int64)
    return np.array(corners, dtype=np.float64).reshape(-1, 4, 2), ids.reshape(-1).astype(np.int64)


def refine_corners(
    image: np.ndarray,
    corners_px: np.ndarray,
    camera: CameraModel,
    bits: int = 4,
    return_sigma: bool = False,
):
    """Sub-pixel corners by edge-line fitting → ideal normalized coordinates (K, 4, 2)
    (:mod:`~ament_formation.core.vision.corner_refinement`). With ``return_sigma`` also (K,) the
    1-σ
    corner position [px] from the edge fits (``_FAILED_SIGMA_PX`` where a fit failed and the
    detector's corners were kept).
    """
    normalized, sigma = corner_refinement.refine(image, corners_px, camera.k, camera.dist, bits)
    if return_sigma:
        return normalized, np.where(np.isfinite(sigma), sigma, _FAILED_SIGMA_PX)
    return normalized


def poses_from_corners(
    normalized: np.ndarray,
    ids: np.ndarray,
    camera: CameraModel,
    layout: MarkerLayout,
    corners_px: np.ndarray,
    pixel_noise_px: float = 0.03,
    corner_sigma_px: np.ndarray | None = None,
) -> MarkerPoses:
    """Ideal normalized corners (K, 4, 2) → controlled-point poses with uncertainties.

    Per-corner σ (per axis, on the plane) = RMS of: the misfit of the corners to a square of the
    known size, ``corner_sigma_px`` (from the edge fits) and the floor ``pixel_noise_px``, the
    pixel terms scaled by the local ground sample [m/px].
    """
    k_count = len(ids)
    if k_count == 0:
        return MarkerPoses.empty()
    poses = np.empty((k_count, 3))
    sigma_xy = np.empty(k_count)
    sigma_theta = np.empty(k_count)
    fit_px = np.zeros(k_count) if corner_sigma_px is None else np.asarray(corner_sigma_px, float)
    corner_refinement.poses_kernel(
        np.ascontiguousarray(normalized, dtype=np.float64).reshape(-1, 4, 2),
        camera.r_wc,
        camera.center_w,
        float(layout.height_m),
        float(layout.size_m),
        float(layout.offset_m[0]),
        float(layout.offset_m[1]),
        float(camera.fx_px),
        float(camera.fy_px),
        camera.dist,
        float(pixel_noise_px),
        np.ascontiguousarray(fit_px),
        poses,
        sigma_xy,
        sigma_theta,
    )
    return MarkerPoses(
        ids.astype(np.int64),
        poses,
        sigma_xy,
        sigma_theta,
        np.asarray(corners_px, dtype=np.float64).reshape(-1, 4, 2),
    )


def measure(
    image: np.ndarray,
    detector: aruco_compat.MarkerDetector,
    camera: CameraModel,
    layout: MarkerLayout,
    config: TrackerConfig = TrackerConfig(),
) -> MarkerPoses:
    """Full-frame detection → poses (no tracking state)."""
    corners, ids = detect(detector, image)
    return _to_poses(image, corners, ids, camera, layout, config)


def _to_poses(image, corners, ids, camera, layout, config, undistort=None) -> MarkerPoses:
    if len(ids) == 0:
        return MarkerPoses.empty()
    if config.refine_edges:
        normalized, sigma_px = refine_corners(
            image, corners, camera, layout.bits, return_sigma=True
        )
        return poses_from_corners(
            normalized, ids, camera, layout, corners, config.pixel_noise_px, sigma_px
        )
    elif undistort is not None:
        normalized = undistort(corners.reshape(-1, 2)).reshape(-1, 4, 2)
    else:
        normalized = undistort_normalized(corners.reshape(-1, 2), camera.k, camera.dist).reshape(
            -1, 4, 2
        )
    return poses_from_corners(normalized, ids, camera, layout, corners, config.pixel_noise_px)


def _concat(a: MarkerPoses, b: MarkerPoses) -> MarkerPoses:
    if len(a) == 0:
        return b
    if len(b) == 0:
        return a
    return MarkerPoses(
        np.concatenate([a.ids, b.ids]),
        np.concatenate([a.poses, b.poses]),
        np.concatenate([a.sigma_xy_m, b.sigma_xy_m]),
        np.concatenate([a.sigma_theta_rad, b.sigma_theta_rad]),
        np.concatenate([a.corners_px, b.corners_px]),
    )


class _Track:
    """One marker's track: last accepted pose (x_m, y_m, theta_rad) at t_s and its velocity
    estimate (xdot_mps, ydot_mps, thetadot_radps). Plain floats: updated every frame.
    """

    __slots__ = ('pose', 't_s', 'velocity', 'rejected')

    def __init__(self, pose: tuple, t_s: float, velocity: tuple = (0.0, 0.0, 0.0)) -> None:
        self.pose = pose
        self.t_s = t_s
        self.velocity = velocity
        self.rejected = 0

    def predict(self, t_s: float) -> np.ndarray:
        dt = max(t_s - self.t_s, 0.0)
        return np.array([p + v * dt for p, v in zip(self.pose, self.velocity)])


@dataclass(frozen=True)
class FrameResult:
    """The outcome of :meth:`MarkerTracker.step` for one frame."""

    accepted: MarkerPoses
    rejected_ids: tuple[int, ...]
    full_frame: bool  # True when the full-frame detector ran
    roi_pixels: int  # pixels of the ROI mosaic searched by the detector (0: none)
    predicted: int = 0  # markers measured from their predicted corners (no detection)


@dataclass
class MarkerTracker:
    """Tracks markers over frames (ROI search, jump gate). Time is passed in; no clocks inside.

    ``expected_ids``: markers that should be in view (lost ones trigger rate-limited full-frame
    searches); empty means "whatever is seen".
    """

    camera: CameraModel
    layout: MarkerLayout = field(default_factory=MarkerLayout)
    config: TrackerConfig = field(default_factory=TrackerConfig)
    expected_ids: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        self._full = make_detector(
            self.layout, self.camera.size_px, self.camera, subpix=not self.config.refine_edges
        )
        corner_refinement.warm_up()
        self._undistort = UndistortLookup(self.camera)
        self._dictionary = aruco_dictionary(self.layout.dictionary)
        self._codes: dict[int, np.ndarray] = {}
        self._roi_detectors: dict[tuple[int, int], aruco_compat.MarkerDetector] = {}
        self._tracks: dict[int, _Track] = {}
        self._frame = 0
        self._last_full = -(10**9)

    # ------------------------------------------------------------------ ROI mosaic
    def _roi_detector(self, size: tuple[int, int]) -> aruco_compat.MarkerDetector:
        key = (size[0] // 64, size[1] // 64)
        det = self._roi_detectors.get(key)
        if det is None:
            det = make_detector(
                self.layout,
                ((key[0] + 1) * 64, (key[1] + 1) * 64),
                self.camera,
                subpix=not self.config.refine_edges,
                single_scale=True,
            )
            self._roi_detectors[key] = det
        return det

    def _predicted_boxes(
        self, t_s: float, mids: list[int]
    ) -> list[tuple[int, tuple[int, int, int, int]]]:
        """Pixel boxes (x0, y0, x1, y1) around tracks ``mids``' markers, last seen and
        predicted.
        """
        w, h = self.camera.size_px
        last, pred = self._predictions(t_s, mids)
        corners = self.layout.corners_w(np.concatenate([last, pred]))  # (2K, 4, 2)
        px = self.camera.floor_to_pixel(corners.reshape(-1, 2), self.layout.height_m)
        px = px.reshape(2, len(mids), 4, 2).transpose(1, 0, 2, 3).reshape(len(mids), 8, 2)
        lo, hi = px.min(axis=1), px.max(axis=1)  # (K, 2)
        quiet = 1.5 * (hi - lo).max(axis=1) / (self.layout.bits + 2)
        m = self.config.roi_margin_px + quiet
        x0 = np.maximum(np.floor(lo[:, 0] - m), 0).astype(int)
        y0 = np.maximum(np.floor(lo[:, 1] - m), 0).astype(int)
        x1 = np.minimum(np.ceil(hi[:, 0] + m) + 1, w).astype(int)
        y1 = np.minimum(np.ceil(hi[:, 1] + m) + 1, h).astype(int)
        return [
            (mid, (int(a), int(b), int(c), int(d)))
            for mid, a, b, c, d in zip(mids, x0, y0, x1, y1)
            if c - a >= 8 and d - b >= 8
        ]

    def _detect_roi(self, image: np.ndarray, boxes) -> tuple[np.ndarray, np.ndarray, int]:
        """Pack ROIs into one mosaic, detect once, map corners back to the frame."""
        gap = _MOSAIC_GAP_PX
        row_limit = max(
            _MOSAIC_ROW_PX, max(b[2] - b[0] for _, b in boxes) + 2 * gap
        )  # one row: least waste
        places, x, y, row_h, mos_w = [], gap, gap, 0, 0
        for mid, (x0, y0, x1, y1) in boxes:
            bw, bh = x1 - x0, y1 - y0
            if x + bw + gap > row_limit:
                x, y, row_h = gap, y + row_h + gap, 0
            places.append((mid, x0, y0, bw, bh, x, y))
            x += bw + gap
            row_h = max(row_h, bh)
            mos_w = max(mos_w, x)
        mos_h = y + row_h + gap
        mosaic = np.full((mos_h, mos_w), _MOSAIC_FILL, np.uint8)
        for _, x0, y0, bw, bh, mx, my in places:
            mosaic[my: my + bh, mx: mx + bw] = image[y0: y0 + bh, x0: x0 + bw]
        corners, ids = detect(self._roi_detector((mos_w, mos_h)), mosaic)
        out_c, out_i, seen = [], [], set()
        for cc, mid in zip(corners, ids):
            cen = cc.mean(axis=0)
            for pmid, x0, y0, bw, bh, mx, my in places:
                if mx <= cen[0] < mx + bw and my <= cen[1] < my + bh:
                    if int(mid) in seen:
                        break
                    out_c.append(cc + np.array([x0 - mx, y0 - my], dtype=np.float64))
                    out_i.append(int(mid))
                    seen.add(int(mid))
                    break
        if not out_i:
            return np.zeros((0, 4, 2)), np.zeros(0, np.int64), mos_w * mos_h
        return np.array(out_c), np.array(out_i, np.int64), mos_w * mos_h

    # ------------------------------------------------------------------ step
    def step(self, image: np.ndarray, t_s: float) -> FrameResult:
        """Measure the markers in ``image`` (mono8, camera size) captured at ``t_s`` [s]."""
        if image.ndim != 2 or image.dtype != np.uint8:
            raise ValueError(f'image must be mono8 (H, W) uint8, got {image.dtype} {image.shape}')
        if image.shape[::-1] != self.camera.size_px:
            raise ValueError(
                f'image is {image.shape[1]}x{image.shape[0]} px, camera model is '
                f'{self.camera.width_px}x{self.camera.height_px}'
            )
        cfg = self.config
        self._frame += 1
        for mid in [m for m, tr in self._tracks.items() if t_s - tr.t_s > cfg.track_timeout_s]:
            del self._tracks[mid]
        since_full = self._frame - self._last_full
        lost = [m for m in self.expected_ids if m not in self._tracks]
        discover = not self.expected_ids and since_full >= cfg.full_frame_period
        full = (
            not cfg.use_roi
            or not self._tracks
            or discover
            or (lost and since_full >= cfg.lost_retry_period)
        )
        roi_pixels, predicted = 0, 0
        measured = MarkerPoses.empty()
        if not full:
            # 1. refine each track's predicted corners directly, verify the code (no detection)
            measured = self._track_predicted(image, t_s)
            predicted = len(measured)
            remaining = [m for m in self._tracks if m not in set(measured.ids.tolist())]
            # 2. detect in ROIs (one mosaic) around the rest
            if remaining:
                boxes = self._predicted_boxes(t_s, remaining)
                corners, ids, roi_pixels = (
                    self._detect_roi(image, boxes)
                    if boxes
                    else (np.zeros((0, 4, 2)), np.zeros(0, np.int64), 0)
                )
                fresh = np.array([int(m) not in set(measured.ids.tolist()) for m in ids], bool)
                corners, ids = self._resolve_duplicates(corners[fresh], ids[fresh], t_s)
                measured = _concat(
                    measured,
                    _to_poses(image, corners, ids, self.camera, self.layout, cfg, self._undistort),
                )
                # 3. still missing: fall back to the full frame
                if set(remaining) - set(ids.tolist()):
                    full = True
        if full:
            corners, ids = detect(self._full, image)
            self._last_full = self._frame
            corners, ids = self._resolve_duplicates(corners, ids, t_s)
            measured = _to_poses(
                image, corners, ids, self.camera, self.layout, cfg, self._undistort
            )
            predicted = 0
        keep = np.array(
            [self._gate(int(m), p, t_s) for m, p in zip(measured.ids, measured.poses)], dtype=bool
        ).reshape(-1)
        rejected = tuple(int(m) for m in measured.ids[~keep])
        return FrameResult(measured.take(keep), rejected, bool(full), int(roi_pixels), predicted)

    def _predictions(self, t_s: float, mids) -> tuple[np.ndarray, np.ndarray]:
        """(K, 3) last accepted and (K, 3) predicted poses of tracks ``mids`` at ``t_s``."""
        last = np.array([self._tracks[m].pose for m in mids]).reshape(-1, 3)
        dts = np.array([max(t_s - self._tracks[m].t_s, 0.0) for m in mids])
        vel = np.array([self._tracks[m].velocity for m in mids]).reshape(-1, 3)
        return last, last + vel * dts[:, None]

    def _track_predicted(self, image: np.ndarray, t_s: float) -> MarkerPoses:
        """Markers found by refining their predicted corners and checking their code cells."""
        if not self.config.refine_edges:
            return MarkerPoses.empty()
        mids = np.array(list(self._tracks), np.int64)
        _, pred = self._predictions(t_s, mids)
        h = self.layout.height_m
        guess = self.camera.floor_to_pixel(self.layout.corners_w(pred).reshape(-1, 2), h).reshape(
            -1, 4, 2
        )
        normalized, sigma = corner_refinement.refine(
            image, guess, self.camera.k, self.camera.dist, self.layout.bits
        )
        rays = np.concatenate(
            [normalized.reshape(-1, 2), np.ones((normalized.size // 2, 1))], axis=1
        )
        found = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), self.camera.k, self.camera.dist)[
            0
        ].reshape(-1, 4, 2)
        ok = np.isfinite(sigma) & (sigma < _MAX_TRACK_SIGMA_PX)
        ok &= np.linalg.norm(found - guess, axis=2).max(axis=1) < _MAX_TRACK_SHIFT_PX
        ok[ok] = self._verify_codes(image, found[ok], mids[ok])
        if not ok.any():
            return MarkerPoses.empty()
        return poses_from_corners(
            normalized[ok],
            mids[ok],
            self.camera,
            self.layout,
            found[ok],
            self.config.pixel_noise_px,
            sigma[ok],
        )

    def _code_cells(self, mid: int) -> np.ndarray:
        """(n + 2, n + 2) expected cells of marker ``mid`` (1 white): quiet ring, black border,
        code.
        """
        cells = self._codes.get(mid)
        if cells is None:
            cells = np.pad(
                aruco_compat.marker_cells(self._dictionary, int(mid)), 1, constant_values=True
            )
            self._codes[mid] = cells
        return cells

    def _verify_codes(
        self, image: np.ndarray, corners_px: np.ndarray, mids: np.ndarray
    ) -> np.ndarray:
        """(K,) True where the cells inside each quad read marker ``mids[k]`` (<= 1 cell wrong)."""
        if len(mids) == 0:
            return np.zeros(0, bool)
        expected = np.stack([self._code_cells(int(m)).ravel() for m in mids])
        return corner_refinement.verify_codes(
            image, corners_px, expected, self.layout.bits, _MIN_CODE_CONTRAST
        )

    def _resolve_duplicates(self, corners, ids, t_s):
        """Two markers with one id: keep the one nearest the prediction (drop both if
        untracked).
        """
        if len(ids) == len(set(ids.tolist())):
            return corners, ids
        keep = np.ones(len(ids), bool)
        for mid in set(ids.tolist()):
            idx = np.flatnonzero(ids == mid)
            if len(idx) < 2:
                continue
            tr = self._tracks.get(int(mid))
            keep[idx] = False
            if tr is not None:
                pred = tr.predict(t_s)
                pred_px = self.camera.floor_to_pixel(
                    self.layout.marker_centers_w(pred[None]), self.layout.height_m
                )[0]
                dist = np.linalg.norm(corners[idx].mean(axis=1) - pred_px, axis=1)
                keep[idx[int(np.argmin(dist))]] = True
        return corners[keep], ids[keep]

    def _gate(self, mid: int, pose: np.ndarray, t_s: float) -> bool:
        """Accept ``pose`` of marker ``mid`` unless it jumped (implausible speed or turn rate)."""
        cfg = self.config
        x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
        tr = self._tracks.get(mid)
        if tr is None:
            self._tracks[mid] = _Track((x, y, th), t_s)
            return True
        dt = max(t_s - tr.t_s, 1e-6)
        x0, y0, th0 = tr.pose
        dpos = math.hypot(x - x0, y - y0)
        dth = (th - th0 + math.pi) % (2 * math.pi) - math.pi
        if (
            dpos > cfg.max_speed_mps * dt + cfg.jump_margin_m
            or abs(dth) > cfg.max_turn_rate_radps * dt + cfg.jump_margin_rad
        ):
            tr.rejected += 1
            if tr.rejected < cfg.reacquire_after:
                return False
            self._tracks[mid] = _Track((x, y, th), t_s)  # it really moved: start over
            return True
        vx0, vy0, vth0 = tr.velocity
        a = 0.5  # velocity: exponential smoothing
        tr.velocity = (
            a * (x - x0) / dt + (1 - a) * vx0,
            a * (y - y0) / dt + (1 - a) * vy0,
            a * dth / dt + (1 - a) * vth0,
        )
        tr.pose = (x, y, th)
        tr.t_s = t_s
        tr.rejected = 0
        return True

    @property
    def tracked_ids(self) -> tuple[int, ...]:
        return tuple(sorted(self._tracks))
