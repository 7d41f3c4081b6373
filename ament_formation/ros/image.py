"""sensor_msgs/Image ↔ numpy without cv_bridge, and sensor_msgs/CameraInfo from the calibration.

Supported encodings: mono8, 8UC1, mono16, 16UC1, bgr8, rgb8, bgra8, rgba8 (row padding through
``step`` and big-endian 16-bit data are handled). :func:`image_to_mono8` gives what the tracker
needs from any of them. :func:`camera_info` describes the frames of a calibrated camera
(core/vision/camera_model.py, ``config/camera.yaml``) the way image_proc, RViz and Foxglove read
it.
"""

from __future__ import annotations

import cv2
import numpy as np
from sensor_msgs.msg import CameraInfo, Image

from ament_formation.core.vision.camera_model import CameraModel

_LAYOUT = {  # encoding -> (dtype, channels)
    'mono8': (np.uint8, 1),
    '8UC1': (np.uint8, 1),
    'mono16': (np.uint16, 1),
    '16UC1': (np.uint16, 1),
    'bgr8': (np.uint8, 3),
    'rgb8': (np.uint8, 3),
    '8UC3': (np.uint8, 3),
    'bgra8': (np.uint8, 4),
    'rgba8': (np.uint8, 4),
    '8UC4': (np.uint8, 4),
}


def image_to_numpy(msg: Image) -> np.ndarray:
    """(H, W) or (H, W, C) array viewing ``msg.data`` (ValueError for unknown encodings/sizes)."""
    if msg.encoding not in _LAYOUT:
        raise ValueError(
            f'encoding: unsupported {msg.encoding!r} (supported: {", ".join(_LAYOUT)})'
        )
    dtype, ch = _LAYOUT[msg.encoding]
    itemsize = np.dtype(dtype).itemsize
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if msg.step < msg.width * ch * itemsize or buf.size < msg.step * msg.height:
        raise ValueError(
            f'data: {buf.size} bytes do not fit {msg.width}x{msg.height} {msg.encoding} '
            f'with step {msg.step}'
        )
    rows = buf[: msg.step * msg.height].reshape(msg.height, msg.step)[
        :, : msg.width * ch * itemsize
    ]
    dt = (
        np.dtype(dtype).newbyteorder('>' if msg.is_bigendian else '<')
        if itemsize > 1
        else np.dtype(dtype)
    )
    arr = np.ascontiguousarray(rows).view(dt) if itemsize > 1 else rows
    arr = arr.reshape(msg.height, msg.width, ch)
    if itemsize > 1:
        arr = arr.astype(np.dtype(dtype).newbyteorder('='), copy=False)
    return arr[:, :, 0] if ch == 1 else arr


def image_to_mono8(msg: Image) -> np.ndarray:
    """(H, W) uint8 grey image from any supported encoding (16-bit scaled by 1/256)."""
    arr = image_to_numpy(msg)
    enc = msg.encoding
    if arr.dtype == np.uint16:
        arr = (arr >> 8).astype(np.uint8)
    if arr.ndim == 2:
        return arr if arr.flags.c_contiguous else np.ascontiguousarray(arr)
    code = {
        'bgr8': cv2.COLOR_BGR2GRAY,
        '8UC3': cv2.COLOR_BGR2GRAY,
        'rgb8': cv2.COLOR_RGB2GRAY,
        'bgra8': cv2.COLOR_BGRA2GRAY,
        '8UC4': cv2.COLOR_BGRA2GRAY,
        'rgba8': cv2.COLOR_RGBA2GRAY,
    }[enc]
    return cv2.cvtColor(np.ascontiguousarray(arr), code)


def numpy_to_image(
    pixels: np.ndarray, encoding: str, stamp=None, frame_id: str = 'camera'
) -> Image:
    """sensor_msgs/Image from an (H, W) or (H, W, C) array in ``encoding`` (no row padding)."""
    if encoding not in _LAYOUT:
        raise ValueError(f'encoding: unsupported {encoding!r}')
    dtype, ch = _LAYOUT[encoding]
    arr = np.asarray(pixels)
    shape_ok = arr.ndim == 2 if ch == 1 else (arr.ndim == 3 and arr.shape[2] == ch)
    if arr.dtype != dtype or not shape_ok:
        raise ValueError(f'pixels: {arr.shape} {arr.dtype} does not match {encoding}')
    msg = Image()
    if stamp is not None:
        msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.height, msg.width = int(arr.shape[0]), int(arr.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = msg.width * ch * arr.dtype.itemsize
    msg.data = np.ascontiguousarray(arr.astype(arr.dtype.newbyteorder('<'), copy=False)).tobytes()
    return msg


def camera_info(camera: CameraModel, stamp=None, frame_id: str = 'camera') -> CameraInfo:
    """sensor_msgs/CameraInfo of ``camera``: size, K, plumb_bob D = [k1, k2, p1, p2, k3], R = I,
    P = [K | 0] (monocular; the tracker undistorts points itself, nothing is rectified).

    Build it once and set ``header.stamp`` to each frame's stamp (the image's, not the send time).
    The mounting (extrinsics) is not part of CameraInfo; it stays in ``config/camera.yaml``.
    """
    msg = CameraInfo()
    if stamp is not None:
        msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.width, msg.height = int(camera.width_px), int(camera.height_px)
    msg.distortion_model = 'plumb_bob'
    msg.d = [float(v) for v in camera.dist]
    k = camera.k
    msg.k = [float(v) for v in k.ravel()]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.p = [
        float(k[0, 0]),
        0.0,
        float(k[0, 2]),
        0.0,
        0.0,
        float(k[1, 1]),
        float(k[1, 2]),
        0.0,
        0.0,
        0.0,
        1.0,
        0.0,
    ]
    return msg
