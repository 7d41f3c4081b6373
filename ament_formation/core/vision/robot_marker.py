"""The ArUco marker on top of each robot: dictionary, size, where it sits on the robot.

Geometry (shared by the synthetic camera and the tracker)
--------------------------------------------------------
The marker's centre is at ``offset_m`` in the robot body frame of the *controlled point*
(x forward along the heading θ, y to the left), on the plane ``height_m`` above the floor.
The marker's image +x (its top edge, corner 0 → corner 1) points along the heading; its image
"up" points to the robot's left. ArUco corner order (TL, TR, BR, BL) is therefore, in the
marker frame centred on the marker with half side s: (−s, +s), (+s, +s), (+s, −s), (−s, −s).

Default size 0.12 m: from 2.86 m with the default 640×480 lens (f = 540 px) one pixel covers
5.3 mm at the image centre and 6.2 mm at the floor's corners, so the marker spans 19–23 px,
≥ 3.2 px per code cell (6 cells with the border) everywhere on the 3 × 2.4 m floor: enough to
decode through lens blur and noise, and long edges for sub-pixel heading. A 0.10 m marker drops
to 2.7 px per cell at the corners and misses 0.17 % of the markers there (0.12 m: none); the
measured numbers are in docs/camera.md. With a 1-cell quiet zone the white plate is 0.16 m, which
fits a 0.2 m robot.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.vision import aruco_compat

#: ArUco dictionaries by name (the cv2.aruco constant names; empty without cv2.aruco).
DICTIONARIES = aruco_compat.dictionary_ids()


def aruco_dictionary(name: str):
    """The cv2.aruco.Dictionary called ``name`` (e.g. "DICT_4X4_50"); ConfigError if unknown,
    :class:`~ament_formation.core.vision.aruco_compat.OpenCVUnsupported` without a usable
    cv2.aruco.
    """
    aruco_compat.require_aruco()
    if name not in DICTIONARIES:
        raise ConfigError(f'unknown ArUco dictionary {name!r} (e.g. DICT_4X4_50)', 'dictionary')
    return aruco_compat.dictionary(DICTIONARIES[name])


def dictionary_size(name: str) -> int:
    """Number of markers in dictionary ``name`` (the last number of its name)."""
    return int(aruco_dictionary(name).bytesList.shape[0])


@dataclass(frozen=True)
class MarkerLayout:
    """The marker every robot carries (all robots carry the same kind, with their own id)."""

    dictionary: str = 'DICT_4X4_50'
    size_m: float = 0.12  # side of the black square (outer border)
    offset_m: tuple[float, float] = (
        -0.05,
        0.0,
    )  # marker centre in the controlled point's body frame
    height_m: float = 0.08  # marker plane above the floor

    def __post_init__(self) -> None:
        aruco_dictionary(self.dictionary)
        if not (
            isinstance(self.size_m, (int, float))
            and math.isfinite(self.size_m)
            and 0.01 <= self.size_m <= 1.0
        ):
            raise ConfigError(f'must be in [0.01, 1.0] m (got {self.size_m!r})', 'size_m')
        if len(self.offset_m) != 2 or not all(math.isfinite(v) for v in self.offset_m):
            raise ConfigError(
                f'needs two finite values [x, y] m (got {self.offset_m!r})', 'offset_m'
            )
        if not (math.isfinite(self.height_m) and 0.0 <= self.height_m <= 2.0):
            raise ConfigError(f'must be in [0, 2] m (got {self.height_m!r})', 'height_m')

    @property
    def bits(self) -> int:
        """Code bits per side (4 for DICT_4X4_*)."""
        return int(aruco_dictionary(self.dictionary).markerSize)

    def corners_marker_m(self) -> np.ndarray:
        """(4, 2) corners TL, TR, BR, BL in the marker frame [m]."""
        s = self.size_m / 2.0
        return np.array([[-s, s], [s, s], [s, -s], [-s, -s]])

    def marker_centers_w(self, poses: np.ndarray) -> np.ndarray:
        """Controlled-point poses (N, 3) [x_m, y_m, theta_rad] → marker centres (N, 2) [m]."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        ox, oy = self.offset_m
        return poses[:, :2] + np.column_stack([c * ox - s * oy, s * ox + c * oy])

    def corners_w(self, poses: np.ndarray) -> np.ndarray:
        """Controlled-point poses (N, 3) → marker corners (N, 4, 2) on the marker plane [m]."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        centers = self.marker_centers_w(poses)
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (N, 2, 2)
        return centers[:, None, :] + np.einsum('nij,kj->nki', rot, self.corners_marker_m())

    def controlled_point(self, marker_centers_w: np.ndarray, theta_rad: np.ndarray) -> np.ndarray:
        """Marker centres (N, 2) and headings (N,) → controlled points (N, 2) [m]."""
        centers = np.asarray(marker_centers_w, dtype=float).reshape(-1, 2)
        th = np.asarray(theta_rad, dtype=float).reshape(-1)
        c, s = np.cos(th), np.sin(th)
        ox, oy = self.offset_m
        return centers - np.column_stack([c * ox - s * oy, s * ox + c * oy])
