"""`formation calibrate intrinsics|floor|from-ros|to-ros`: the camera's calibration in camera.yaml.

    formation calibrate intrinsics IMAGES... --board 7x5,0.04,0.03[,DICT_4X4_50] [--out FILE]
    formation calibrate floor IMAGE --markers FILE [--camera FILE] [--out FILE]
    formation calibrate from-ros ROS.yaml [--out FILE]      # intrinsics of a ROS calibration
    formation calibrate to-ros [--camera FILE] --out ROS.yaml [--name NAME]

``intrinsics`` (and ``from-ros``, which takes them from a ROS ``camera_calibration`` YAML) keeps
the mounting already in ``--out`` (if the file exists) and replaces the image size, camera matrix
and distortion; ``to-ros`` writes the intrinsics as a ROS ``camera_calibration`` YAML (for a
camera driver's ``camera_info_url``). ``floor`` takes the intrinsics from ``--camera``
(default: the ``--out`` file, else the built-in default) and replaces the mounting. Degenerate
input (too few usable views, fewer than 3 reference markers or markers on one line, unreadable
images, a malformed ROS file) is refused with one line naming it (exit code 2).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import cv2
import yaml

from ament_formation.core.config_files import config_dir
from ament_formation.core.errors import ConfigError
from ament_formation.core.vision.calibration import (
    calibrate_floor,
    calibrate_intrinsics,
    CharucoSpec,
    load_reference_markers,
)
from ament_formation.core.vision.camera_model import (
    CameraSetup,
    load_camera_yaml,
    save_camera_yaml,
)
from ament_formation.core.vision.ros_calibration import (
    apply_intrinsics,
    load_ros_calibration,
    ros_calibration_dict,
)


def _default_out() -> Path:
    try:
        return config_dir() / 'camera.yaml'
    except FileNotFoundError:
        return Path('config') / 'camera.yaml'


def _read_mono(path: str):
    if not Path(path).is_file():
        raise ConfigError('cannot read image (no such file)', None, path)
    img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ConfigError('cannot read image (missing file or unknown format)', None, path)
    return img


def _existing_setup(path: Path | None) -> CameraSetup:
    if path is not None and path.exists():
        return load_camera_yaml(path)
    return CameraSetup()


def _intrinsics(args: argparse.Namespace) -> int:
    spec = CharucoSpec.parse(args.board)
    images = [(p, _read_mono(p)) for p in args.images]
    result = calibrate_intrinsics(images, spec, min_views=args.min_views)
    out = Path(args.out)
    setup = _existing_setup(out)
    camera = setup.camera.with_intrinsics(result.k, result.dist, result.size_px)
    calib = dict(setup.calibration)
    calib.update(
        {
            'intrinsics_rms_px': round(result.rms_px, 4),
            'intrinsics_views': result.views_used,
            'board': args.board,
        }
    )
    save_camera_yaml(replace(setup, camera=camera, calibration=calib), out)
    k1, k2, p1, p2, k3 = camera.distortion
    print(
        f'intrinsics from {result.views_used} view(s) ({len(result.views_skipped)} skipped): '
        f'fx {camera.fx_px:.2f} fy {camera.fy_px:.2f} '
        f'cx {camera.cx_px:.2f} cy {camera.cy_px:.2f} px, '
        f'k1 {k1:.4f} k2 {k2:.4f} p1 {p1:.5f} p2 {p2:.5f} k3 {k3:.4f}'
    )
    print(f'reprojection error RMS {result.rms_px:.3f} px -> {out}')
    return 0


def _floor(args: argparse.Namespace) -> int:
    refs = load_reference_markers(args.markers)
    out = Path(args.out)
    source = Path(args.camera) if args.camera else out
    if args.camera and not source.exists():
        raise ConfigError('no such camera file', '--camera', args.camera)
    setup = _existing_setup(source)
    image = _read_mono(args.image)
    try:
        result = calibrate_floor(image, refs, setup.camera)
    except ConfigError as err:
        raise (err.with_file(args.image) if err.field == 'IMAGE' else err) from None
    calib = dict(setup.calibration)
    calib.update(
        {
            'floor_rms_px': round(result.rms_px, 4),
            'floor_max_error_m': round(result.max_floor_error_m, 5),
            'floor_markers': list(result.used_ids),
        }
    )
    save_camera_yaml(replace(setup, camera=result.camera, calibration=calib), out)
    c = result.camera
    print(
        f'floor from {len(result.used_ids)} reference marker(s) {list(result.used_ids)}: '
        f'camera above ({c.position_m[0]:.3f}, {c.position_m[1]:.3f}) m '
        f'at {c.height_m:.3f} m, yaw {c.yaw_rad:.4f} '
        f'tilt {c.tilt_rad:.4f} roll {c.roll_rad:.4f} rad'
    )
    print(
        f'reprojection error RMS {result.rms_px:.3f} px, largest floor error '
        f'{result.max_floor_error_m * 1e3:.2f} mm -> {out}'
    )
    return 0


def _from_ros(args: argparse.Namespace) -> int:
    intr = load_ros_calibration(args.file)
    out = Path(args.out)
    setup = _existing_setup(out)
    camera = apply_intrinsics(setup.camera, intr, args.file)
    calib = dict(setup.calibration)
    calib.update({'intrinsics_from': str(args.file)})
    save_camera_yaml(replace(setup, camera=camera, calibration=calib), out)
    print(
        f'intrinsics of {args.file} ({intr.camera_name or "unnamed"}): {intr.width_px}x'
        f'{intr.height_px} px, fx {intr.fx_px:.2f} fy {intr.fy_px:.2f} cx {intr.cx_px:.2f} '
        f'cy {intr.cy_px:.2f} -> {out} (mounting kept)'
    )
    return 0


def _to_ros(args: argparse.Namespace) -> int:
    source = Path(args.camera) if args.camera else Path(_default_out())
    if not source.exists():
        raise ConfigError('no such camera file', '--camera', str(source))
    camera = load_camera_yaml(source).camera
    out = Path(args.out)
    if not out.parent.is_dir():
        raise ConfigError('no such folder', '--out', str(out.parent))
    out.write_text(
        yaml.safe_dump(ros_calibration_dict(camera, args.name), sort_keys=False,
                       default_flow_style=None, width=100)
    )
    print(f'intrinsics of {source} -> {out} (ROS camera_calibration, camera_name {args.name})')
    return 0


def register(subparsers) -> None:
    """Add ``calibrate intrinsics`` and ``calibrate floor``."""
    cal = subparsers.add_parser(
        'calibrate', help='calibrate the overhead camera (writes camera.yaml)'
    )
    sub = cal.add_subparsers(dest='calibrate_command', metavar='WHAT')
    sub.required = True
    default_out = str(_default_out())

    p = sub.add_parser('intrinsics', help='camera matrix + distortion from ChArUco board images')
    p.add_argument(
        'images', nargs='+', metavar='IMAGES', help='images of the board at different poses'
    )
    p.add_argument(
        '--board',
        required=True,
        help='SQUARES_XxSQUARES_Y,SQUARE_M,MARKER_M[,DICT] (e.g. 7x5,0.04,0.03) or a YAML file',
    )
    p.add_argument('--min-views', type=int, default=5, help='usable views required (default 5)')
    p.add_argument(
        '--out', default=default_out, help=f'camera.yaml to write (default {default_out})'
    )
    p.set_defaults(func=_intrinsics)

    p = sub.add_parser(
        'floor', help='camera mounting from an image of reference markers on the floor'
    )
    p.add_argument('image', metavar='IMAGE')
    p.add_argument(
        '--markers',
        required=True,
        help='YAML: size_m, dictionary, markers: [{id, center_m: [x, y], yaw_rad}]',
    )
    p.add_argument(
        '--camera', default=None, help='camera.yaml with the intrinsics (default: --out)'
    )
    p.add_argument(
        '--out', default=default_out, help=f'camera.yaml to write (default {default_out})'
    )
    p.set_defaults(func=_floor)

    p = sub.add_parser(
        'from-ros', help='intrinsics from a ROS camera_calibration YAML (mounting kept)'
    )
    p.add_argument('file', metavar='ROS.yaml', help='file of ros2 run camera_calibration ...')
    p.add_argument(
        '--out', default=default_out, help=f'camera.yaml to write (default {default_out})'
    )
    p.set_defaults(func=_from_ros)

    p = sub.add_parser('to-ros', help='write the intrinsics as a ROS camera_calibration YAML')
    p.add_argument('--camera', default=None, help=f'camera.yaml to read (default {default_out})')
    p.add_argument('--out', required=True, metavar='ROS.yaml')
    p.add_argument('--name', default='camera', help='camera_name (default camera)')
    p.set_defaults(func=_to_ros)
