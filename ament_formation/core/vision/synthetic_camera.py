"""Synthetic overhead camera: mono8 frames of the floor, the robots' ArUco markers and obstacles.

Rendering is by inverse mapping, in two stages, so a frame costs a few milliseconds:

1. an *ideal* pinhole canvas (same focal length, large enough to hold everything the real lens
   sees) is drawn: a static floor background, obstacles and robot plates as anti-aliased
   polygons projected by the floor-plane homography, and each marker as a texture warped by its
   plane homography only inside its bounding box, 4×4 supersampled (box filter) so that edges
   land with sub-pixel accuracy;
2. one ``cv2.remap`` through grids precomputed at construction (for every output pixel, where
   its undistorted ray meets the canvas) applies the radial/tangential lens distortion;

then optional sensor noise (i.i.d. Gaussian per pixel, grey levels) is added. Motion blur
(optional) averages
each marker over sub-poses spread across the exposure time. Frames are a pure function of the
inputs and ``(seed, frame_index)``.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import cv2
import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.vision import aruco_compat
from ament_formation.core.vision.camera_model import CameraModel, FloorArea, undistort_normalized
from ament_formation.core.vision.robot_marker import aruco_dictionary, MarkerLayout

_TEXEL_PER_CELL = 8
_ELLIPSE_POINTS = 72
_SHIFT = 4  # sub-pixel bits for cv2.fillPoly
_SHIFT_SCALE = float(1 << _SHIFT)


@dataclass(frozen=True)
class RenderOptions:
    """How frames look. Grey levels are 0–255."""

    noise_std: float = 2.0  # sensor noise, grey levels (Gaussian)
    exposure_s: float = 0.0  # > 0 with pose rates given: motion blur over this exposure
    blur_samples: int = 5  # sub-poses averaged for motion blur
    supersample: int = 4  # marker anti-aliasing (samples per pixel per axis)
    quiet_zone_cells: int = 1  # white margin around each marker, in code cells
    body_radius_m: float = 0.10  # dark robot plate under the marker (0: none)
    floor_level: int = 150
    outside_level: int = 100  # beyond the floor area
    obstacle_level: int = 85
    body_level: int = 45
    black_level: int = 25
    white_level: int = 225
    seed: int = 0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.noise_std) and 0.0 <= self.noise_std <= 50.0):
            raise ConfigError(
                f'must be in [0, 50] grey levels (got {self.noise_std!r})', 'noise_std'
            )
        if not (math.isfinite(self.exposure_s) and 0.0 <= self.exposure_s <= 1.0):
            raise ConfigError(f'must be in [0, 1] s (got {self.exposure_s!r})', 'exposure_s')
        for name, lo, hi in (
            ('blur_samples', 1, 64),
            ('supersample', 1, 8),
            ('quiet_zone_cells', 0, 4),
        ):
            v = getattr(self, name)
            if not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(f'must be an integer in [{lo}, {hi}] (got {v!r})', name)
        if not (math.isfinite(self.body_radius_m) and 0.0 <= self.body_radius_m <= 1.0):
            raise ConfigError(f'must be in [0, 1] m (got {self.body_radius_m!r})', 'body_radius_m')
        for name in (
            'floor_level',
            'outside_level',
            'obstacle_level',
            'body_level',
            'black_level',
            'white_level',
        ):
            v = getattr(self, name)
            if not isinstance(v, int) or not 0 <= v <= 255:
                raise ConfigError(f'must be an integer grey level in [0, 255] (got {v!r})', name)


@dataclass(frozen=True)
class Obstacles:
    """Elliptical obstacles drawn on the floor. Shapes (M, 2), (M, 2), (M,); world frame."""

    center_m: np.ndarray
    semi_axes_m: np.ndarray
    phi_rad: np.ndarray

    @staticmethod
    def none() -> 'Obstacles':
        return Obstacles(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))


def _plane_homography(k: np.ndarray, r_cw: np.ndarray, t: np.ndarray, z_m: float) -> np.ndarray:
    """(3, 3) homography: world point (X, Y, 1) on plane z = z_m → pinhole pixel (homogeneous)."""
    return k @ np.column_stack([r_cw[:, 0], r_cw[:, 1], r_cw[:, 2] * z_m + t])


class SyntheticCamera:
    """Renders frames of ``camera`` (intrinsics, distortion, mounting) looking at the floor.

    Parameters
    ----------
    camera : CameraModel
    layout : MarkerLayout
        The marker each robot carries (size, offset from the controlled point, height).
    options : RenderOptions
    floor : FloorArea
        Drawn at ``floor_level``; everything else at ``outside_level``.
    """

    def __init__(
        self,
        camera: CameraModel,
        layout: MarkerLayout | None = None,
        options: RenderOptions | None = None,
        floor: FloorArea | None = None,
    ):
        self.camera = camera
        self.layout = layout or MarkerLayout()
        self.options = options or RenderOptions()
        self.floor = floor or FloorArea()
        self._dictionary = aruco_dictionary(self.layout.dictionary)
        self._n_ids = int(self._dictionary.bytesList.shape[0])
        self._textures: dict[int, np.ndarray] = {}
        self._build_canvas()

    # ---------------------------------------------------------------- set-up
    def _build_canvas(self) -> None:
        cam = self.camera
        w, h = cam.width_px, cam.height_px
        uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        xn = undistort_normalized(np.column_stack([uu.ravel(), vv.ravel()]), cam.k, cam.dist)
        ideal_u = cam.fx_px * xn[:, 0]
        ideal_v = cam.fy_px * xn[:, 1]
        pad = 3.0
        u0, v0 = math.floor(ideal_u.min() - pad), math.floor(ideal_v.min() - pad)
        cw = int(math.ceil(ideal_u.max() + pad)) - u0
        ch = int(math.ceil(ideal_v.max() + pad)) - v0
        self._canvas_size = (cw, ch)
        self._kc = np.array([[cam.fx_px, 0.0, -u0], [0.0, cam.fy_px, -v0], [0.0, 0.0, 1.0]])
        map_x = (ideal_u - u0).reshape(h, w).astype(np.float32)
        map_y = (ideal_v - v0).reshape(h, w).astype(np.float32)
        self._map1, self._map2 = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
        self._r_cw = cam.r_wc.T
        self._t = cam.tvec
        self._h_floor = _plane_homography(self._kc, self._r_cw, self._t, 0.0)
        self._h_marker = _plane_homography(self._kc, self._r_cw, self._t, self.layout.height_m)
        # static background: floor area vs outside, by mapping canvas pixels back to the floor
        cu, cv_ = np.meshgrid(np.arange(cw, dtype=np.float64), np.arange(ch, dtype=np.float64))
        pix = np.stack([cu.ravel(), cv_.ravel(), np.ones(cu.size)])
        xyw = np.linalg.solve(self._h_floor, pix)
        with np.errstate(divide='ignore', invalid='ignore'):
            x, y = xyw[0] / xyw[2], xyw[1] / xyw[2]
        x0, x1, y0, y1 = self.floor.bounds_m
        inside = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1) & (xyw[2] > 0)
        o = self.options
        bg = np.where(inside, o.floor_level, o.outside_level).reshape(ch, cw).astype(np.uint8)
        self._background = cv2.GaussianBlur(bg, (3, 3), 0.7)  # soft floor edge, like a lens would
        # sensor noise: each frame adds a window, at a random offset drawn from (seed, frame
        # index), of one long i.i.d. Gaussian sequence (fast: no per-frame normal draws)
        self._noise_bank = None
        if o.noise_std > 0:
            bank_rng = np.random.default_rng((o.seed, 0x5E75))
            self._noise_bank = np.round(bank_rng.standard_normal(4 * w * h) * o.noise_std).astype(
                np.int16
            )
        q = o.quiet_zone_cells
        cells = self.layout.bits + 2 + 2 * q
        self._plate_m = self.layout.size_m * cells / (self.layout.bits + 2)
        self._texture_px = cells * _TEXEL_PER_CELL
        tp, plate = float(self._texture_px), self._plate_m
        # texture pixel (tx, ty) -> marker frame (mx, my) [m]; texel centres at integers
        self._a_tex = np.array(
            [
                [plate / tp, 0.0, 0.5 * plate / tp - plate / 2],
                [0.0, -plate / tp, plate / 2 - 0.5 * plate / tp],
                [0.0, 0.0, 1.0],
            ]
        )

    def texture(self, marker_id: int) -> np.ndarray:
        """(T, T) uint8 texture of marker ``marker_id`` with its white quiet zone."""
        tex = self._textures.get(marker_id)
        if tex is None:
            if not 0 <= marker_id < self._n_ids:
                raise ConfigError(
                    f'marker id {marker_id} not in {self.layout.dictionary} '
                    f'(0..{self._n_ids - 1})',
                    'marker_ids',
                )
            o = self.options
            inner = (self.layout.bits + 2) * _TEXEL_PER_CELL
            img = aruco_compat.marker_image(self._dictionary, int(marker_id), inner, border_bits=1)
            pad = o.quiet_zone_cells * _TEXEL_PER_CELL
            img = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
            tex = np.where(img > 127, o.white_level, o.black_level).astype(np.uint8)
            self._textures[marker_id] = tex
        return tex

    @property
    def canvas_size(self) -> tuple[int, int]:
        """(width, height) [px] of the ideal pinhole canvas."""
        return self._canvas_size

    # ---------------------------------------------------------------- drawing
    def _to_canvas(self, h: np.ndarray, xy: np.ndarray) -> np.ndarray:
        p = np.column_stack([xy, np.ones(len(xy))]) @ h.T
        return p[:, :2] / p[:, 2:3]

    def _draw_ellipses(
        self,
        canvas: np.ndarray,
        h: np.ndarray,
        centers: np.ndarray,
        axes: np.ndarray,
        phis: np.ndarray,
        level: int,
    ) -> None:
        """Anti-aliased filled ellipses (M,) on the plane of homography ``h``
        (one fillPoly call).
        """
        if len(centers) == 0:
            return
        t = np.linspace(0.0, 2 * np.pi, _ELLIPSE_POINTS, endpoint=False)
        ct, st = np.cos(t)[None, :], np.sin(t)[None, :]
        c, s = np.cos(phis)[:, None], np.sin(phis)[:, None]
        a, b = axes[:, 0:1], axes[:, 1:2]
        x = centers[:, 0:1] + a * ct * c - b * st * s  # (M, P)
        y = centers[:, 1:2] + a * ct * s + b * st * c
        p = np.stack([x, y, np.ones_like(x)], axis=-1) @ h.T  # (M, P, 3)
        px = np.round(p[..., :2] / p[..., 2:3] * _SHIFT_SCALE).astype(np.int32)
        cv2.fillPoly(
            canvas, list(px.reshape(len(centers), -1, 1, 2)), int(level), cv2.LINE_AA, _SHIFT
        )

    def _warp_patch(self, canvas: np.ndarray, texture: np.ndarray, hs: list[np.ndarray]) -> None:
        """Warp ``texture`` by each canvas homography in ``hs`` (averaged: motion blur) into the
        canvas, supersampled inside the bounding box of the warped texture only.
        """
        tw, th = texture.shape[1] - 0.5, texture.shape[0] - 0.5
        quad = np.array([[-0.5, -0.5], [tw, -0.5], [tw, th], [-0.5, th]])
        pts = np.concatenate([self._to_canvas(h, quad) for h in hs])
        cw, ch = self._canvas_size
        x0 = max(int(math.floor(pts[:, 0].min())) - 1, 0)
        y0 = max(int(math.floor(pts[:, 1].min())) - 1, 0)
        x1 = min(int(math.ceil(pts[:, 0].max())) + 2, cw)
        y1 = min(int(math.ceil(pts[:, 1].max())) + 2, ch)
        if x1 <= x0 or y1 <= y0:
            return
        ss = self.options.supersample
        bw, bh = x1 - x0, y1 - y0
        # canvas px (x, y) -> buffer px: b = ss * (x - x0 + 0.5) - 0.5
        s = np.array(
            [[ss, 0.0, ss * (0.5 - x0) - 0.5], [0.0, ss, ss * (0.5 - y0) - 0.5], [0, 0, 1.0]]
        )
        base = cv2.resize(
            canvas[y0:y1, x0:x1], (bw * ss, bh * ss), interpolation=cv2.INTER_NEAREST
        )
        if len(hs) == 1:
            buf = base
            cv2.warpPerspective(
                texture,
                s @ hs[0],
                (bw * ss, bh * ss),
                dst=buf,
                flags=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_TRANSPARENT,
            )
        else:
            acc = np.zeros(base.shape, np.float32)
            for h in hs:
                buf = base.copy()
                cv2.warpPerspective(
                    texture,
                    s @ h,
                    (bw * ss, bh * ss),
                    dst=buf,
                    flags=cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_TRANSPARENT,
                )
                acc += buf
            buf = np.clip(acc / len(hs) + 0.5, 0, 255).astype(np.uint8)
        canvas[y0:y1, x0:x1] = cv2.resize(buf, (bw, bh), interpolation=cv2.INTER_AREA)

    def _marker_homography(self, pose: np.ndarray) -> np.ndarray:
        """Texture px → canvas px for a robot whose controlled point is at ``pose`` (3,)."""
        center = self.layout.marker_centers_w(pose[None])[0]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        w = np.array([[c, -s, center[0]], [s, c, center[1]], [0.0, 0.0, 1.0]])
        return self._h_marker @ w @ self._a_tex

    def _finish(self, canvas: np.ndarray, frame_index: int) -> np.ndarray:
        frame = cv2.remap(
            canvas, self._map1, self._map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )
        if self._noise_bank is not None:
            n = frame.size
            rng = np.random.default_rng((self.options.seed, int(frame_index)))
            start = int(rng.integers(0, self._noise_bank.size - n))
            noise = self._noise_bank[start: start + n].reshape(frame.shape)
            frame = cv2.add(frame, noise, dtype=cv2.CV_8U)  # saturating
        return frame

    # ---------------------------------------------------------------- public
    def render(
        self,
        poses: np.ndarray,
        marker_ids,
        obstacles: Obstacles | None = None,
        pose_rates: np.ndarray | None = None,
        frame_index: int = 0,
    ) -> np.ndarray:
        """One mono8 frame.

        Parameters
        ----------
        poses : (N, 3) rows [x_m, y_m, theta_rad] of each robot's controlled point (world frame).
        marker_ids : (N,) marker id each robot carries.
        obstacles : elliptical obstacles on the floor (drawn at ``obstacle_level``).
        pose_rates : (N, 3) rows [xdot_mps, ydot_mps, thetadot_radps]; with ``exposure_s`` > 0 the
            markers are blurred over the exposure centred on the frame time.
        frame_index : selects the noise realisation (with ``options.seed``).

        Returns
        -------
        (height_px, width_px) uint8 image.
        """
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        ids = np.asarray(marker_ids, dtype=np.int64).reshape(-1)
        if len(ids) != len(poses):
            raise ConfigError(f'{len(ids)} marker ids for {len(poses)} poses', 'marker_ids')
        canvas = self._background.copy()
        o = self.options
        if obstacles is not None and len(obstacles.center_m):
            self._draw_ellipses(
                canvas,
                self._h_floor,
                np.asarray(obstacles.center_m).reshape(-1, 2),
                np.asarray(obstacles.semi_axes_m).reshape(-1, 2),
                np.asarray(obstacles.phi_rad).reshape(-1),
                o.obstacle_level,
            )
        if len(poses) and o.body_radius_m > 0:
            centers = self.layout.marker_centers_w(poses)
            r = o.body_radius_m
            self._draw_ellipses(
                canvas,
                self._h_marker,
                centers,
                np.full((len(poses), 2), r),
                np.zeros(len(poses)),
                o.body_level,
            )
        blur = o.exposure_s > 0 and pose_rates is not None and o.blur_samples > 1
        if blur:
            rates = np.asarray(pose_rates, dtype=np.float64).reshape(-1, 3)
            offsets_s = (np.linspace(0.0, 1.0, o.blur_samples) - 0.5) * o.exposure_s
        for i, (pose, mid) in enumerate(zip(poses, ids)):
            tex = self.texture(int(mid))
            if blur:
                hs = [self._marker_homography(pose + rates[i] * dt) for dt in offsets_s]
            else:
                hs = [self._marker_homography(pose)]
            self._warp_patch(canvas, tex, hs)
        return self._finish(canvas, frame_index)

    def render_plane(
        self,
        texture: np.ndarray,
        size_m: tuple[float, float],
        rvec: np.ndarray,
        tvec: np.ndarray,
        frame_index: int = 0,
        background: int | None = None,
    ) -> np.ndarray:
        """A frame of a flat textured board (e.g. a ChArUco calibration target) held in view.

        Parameters
        ----------
        texture : (H, W) uint8 image of the board; it covers ``size_m`` = (width, height) [m].
        rvec, tvec : (3,) board → camera pose (OpenCV convention); board frame origin at the
            texture's top-left corner, x along texture columns, y along rows, z into the board.
        background : grey level behind the board (default ``outside_level``).
        """
        r = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
        t = np.asarray(tvec, dtype=np.float64).reshape(3)
        hgt, wid = texture.shape[:2]
        a = np.array(
            [
                [size_m[0] / wid, 0.0, 0.5 * size_m[0] / wid],
                [0.0, size_m[1] / hgt, 0.5 * size_m[1] / hgt],
                [0.0, 0.0, 1.0],
            ]
        )
        h = self._kc @ np.column_stack([r[:, 0], r[:, 1], t]) @ a
        level = self.options.outside_level if background is None else int(background)
        canvas = np.full(self._canvas_size[::-1], level, np.uint8)
        self._warp_patch(canvas, texture, [h])
        return self._finish(canvas, frame_index)
