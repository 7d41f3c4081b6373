"""ArUco and ChArUco across OpenCV versions: the one module that knows both APIs.

OpenCV 4.7 moved ArUco from the contrib modules into the main library and replaced its free
functions by objects (``ArucoDetector``, ``CharucoDetector``, ``generateImageMarker``,
``CharucoBoard((sx, sy), ...)``); OpenCV 4.6, which Debian 12 and Ubuntu 24.04 ship as
``python3-opencv`` (with the contrib modules), has only the free functions
(``detectMarkers``, ``DetectorParameters_create``, ``drawMarker``, ``CharucoBoard_create``,
``interpolateCornersCharuco``). Everything else of the project calls the functions here, which
pick the API the installed OpenCV has. Supported: OpenCV >= 4.6 with ``cv2.aruco`` (4.6: the
contrib build; 4.7 and later: any build), 5.x included.

:func:`require_aruco` raises :class:`OpenCVUnsupported` (a ConfigError: one line, exit code 2)
naming what to install when the installed OpenCV cannot be used.
"""

from __future__ import annotations

import re

import cv2
import numpy as np

from ament_formation.core.errors import ConfigError

MIN_OPENCV = (4, 6, 0)
INSTALL_HINT = (
    'install python3-opencv (Debian 12 / Ubuntu 24.04: 4.6 with aruco) or '
    "pip install 'opencv-contrib-python-headless>=4.6' (or 'opencv-python-headless>=4.7')"
)


class OpenCVUnsupported(ConfigError):
    """The installed OpenCV cannot run the marker code (too old, or 4.6 without contrib)."""

    def __init__(self, problem: str) -> None:
        super().__init__(problem, 'OpenCV')


def opencv_version() -> tuple[int, int, int]:
    """(major, minor, patch) of the installed OpenCV."""
    nums = [int(n) for n in re.findall(r'\d+', cv2.__version__)[:3]]
    return tuple(nums + [0] * (3 - len(nums)))  # type: ignore[return-value]


def opencv_problem() -> str | None:
    """Why the installed OpenCV cannot be used (one line naming what to install), or None."""
    version = opencv_version()
    if version < MIN_OPENCV:
        need = '.'.join(map(str, MIN_OPENCV))
        return f'{cv2.__version__} is older than {need}: {INSTALL_HINT}'
    aruco = getattr(cv2, 'aruco', None)
    if aruco is None or not hasattr(aruco, 'getPredefinedDictionary'):
        return f'{cv2.__version__} has no cv2.aruco (a build without contrib): {INSTALL_HINT}'
    return None


def require_aruco() -> None:
    """Raise :class:`OpenCVUnsupported` unless the installed OpenCV has a usable cv2.aruco."""
    problem = opencv_problem()
    if problem is not None:
        raise OpenCVUnsupported(problem)


def has_new_api() -> bool:
    """True with OpenCV >= 4.7 (``cv2.aruco.ArucoDetector``), False with 4.6's free functions."""
    require_aruco()
    return hasattr(cv2.aruco, 'ArucoDetector')


def dictionary_ids() -> dict[str, int]:
    """The predefined dictionaries by their cv2.aruco constant name (empty without aruco)."""
    aruco = getattr(cv2, 'aruco', None)
    if aruco is None:
        return {}
    return {
        name: getattr(aruco, name)
        for name in dir(aruco)
        if name.startswith('DICT_') and isinstance(getattr(aruco, name), int)
    }


def dictionary(dict_id: int):
    """The predefined cv2.aruco.Dictionary with constant ``dict_id``."""
    require_aruco()
    return cv2.aruco.getPredefinedDictionary(int(dict_id))


# ------------------------------------------------------------------------------------ markers
def detector_parameters():
    """A fresh cv2.aruco.DetectorParameters with OpenCV's defaults (set fields on it)."""
    if has_new_api():
        return cv2.aruco.DetectorParameters()
    return cv2.aruco.DetectorParameters_create()


class MarkerDetector:
    """ArUco marker detection with fixed dictionary and parameters, on either API.

    ``detect(image)`` → (corners, ids) as OpenCV gives them: a list of (1, 4, 2) float32 arrays
    (TL, TR, BR, BL) [px] and an (K, 1) int32 array, or None when nothing was found.
    """

    def __init__(self, dictionary, parameters) -> None:
        self.dictionary = dictionary
        self.parameters = parameters
        self._detector = (
            cv2.aruco.ArucoDetector(dictionary, parameters) if has_new_api() else None
        )

    def detect(self, image: np.ndarray):
        if self._detector is not None:
            corners, ids, _ = self._detector.detectMarkers(image)
        else:
            corners, ids, _ = cv2.aruco.detectMarkers(
                image, self.dictionary, parameters=self.parameters
            )
        return corners, ids


def marker_image(dictionary, marker_id: int, side_px: int, border_bits: int = 1) -> np.ndarray:
    """(side_px, side_px) uint8 image of marker ``marker_id`` (black border ``border_bits``)."""
    if has_new_api():
        make = cv2.aruco.generateImageMarker
    else:
        make = cv2.aruco.drawMarker
    return make(dictionary, int(marker_id), int(side_px), borderBits=border_bits)


def marker_cells(dictionary, marker_id: int) -> np.ndarray:
    """(n + 2, n + 2) bool cells of marker ``marker_id`` with its 1-cell black border (True:
    white), row 0 at the top (the marker's corner 0 → 1 edge).
    """
    n = int(dictionary.markerSize) + 2
    return marker_image(dictionary, marker_id, n, border_bits=1) > 127


def draw_detected_markers(image: np.ndarray, corners, ids) -> None:
    """Outline markers (corners as :meth:`MarkerDetector.detect` gives them) on a BGR image."""
    cv2.aruco.drawDetectedMarkers(image, corners, ids)


# ------------------------------------------------------------------------------------ ChArUco
def charuco_board(squares_xy: tuple[int, int], square_m: float, marker_m: float, dictionary):
    """A ChArUco board of squares_xy = (columns, rows) chessboard squares."""
    sx, sy = int(squares_xy[0]), int(squares_xy[1])
    if has_new_api():
        return cv2.aruco.CharucoBoard((sx, sy), float(square_m), float(marker_m), dictionary)
    return cv2.aruco.CharucoBoard_create(sx, sy, float(square_m), float(marker_m), dictionary)


def board_image(board, size_px: tuple[int, int], margin_px: int = 0, border_bits: int = 1):
    """(H, W) uint8 picture of ``board`` fitted into size_px = (W, H)."""
    size = (int(size_px[0]), int(size_px[1]))
    if has_new_api():
        return board.generateImage(size, marginSize=int(margin_px), borderBits=border_bits)
    return board.draw(size, marginSize=int(margin_px), borderBits=border_bits)


def chessboard_corners(board) -> np.ndarray:
    """(N, 3) inner chessboard corners of a ChArUco board in its own frame [m], by corner id."""
    pts = board.getChessboardCorners() if has_new_api() else board.chessboardCorners
    return np.asarray(pts, dtype=np.float64).reshape(-1, 3)


class CharucoDetector:
    """ChArUco corner detection on either API: ``detect(image)`` → (corners (K, 1, 2) float32
    [px], ids (K, 1) int32), both None when no corner was found.
    """

    def __init__(self, board) -> None:
        self.board = board
        if has_new_api():
            self._detector = cv2.aruco.CharucoDetector(board)
            self._markers = None
        else:
            self._detector = None
            params = detector_parameters()
            self._markers = MarkerDetector(board.dictionary, params)

    def detect(self, image: np.ndarray):
        if self._detector is not None:
            corners, ids, _, _ = self._detector.detectBoard(image)
            return corners, ids
        m_corners, m_ids = self._markers.detect(image)
        if m_ids is None or len(m_ids) == 0:
            return None, None
        n, corners, ids = cv2.aruco.interpolateCornersCharuco(m_corners, m_ids, image, self.board)
        if not n or ids is None:
            return None, None
        return corners, ids


def charuco_collinear(board, ids) -> bool:
    """True when the ChArUco corners ``ids`` lie on one line (a view that cannot calibrate)."""
    ids = np.asarray(ids, dtype=np.int32).reshape(-1, 1)
    if has_new_api():
        return bool(board.checkCharucoCornersCollinear(ids))
    return bool(cv2.aruco.testCharucoCornersCollinear(board, ids))


def charuco_object_points(board, ids) -> np.ndarray:
    """(K, 3) board-frame points [m] of the ChArUco corners ``ids``."""
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    return chessboard_corners(board)[ids]
