"""Calibration: a known camera is recovered from rendered ChArUco views and reference markers;
degenerate input is refused with one line; `formation calibrate` writes camera.yaml.

Tolerances (stated): focal lengths within 0.5 %, principal point within 3 px, RMS reprojection
error < 0.3 px, viewing-ray direction (intrinsics + distortion, in pixels of the true camera, image
minus its outer 5 % border) RMS <= 1 px and max <= 2.5 px; floor mapping within 2 mm everywhere on
the 3 x 2.4 m floor, also end to end (intrinsics and mounting both calibrated from rendered
images).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from ament_formation.core.errors import ConfigError
from ament_formation.core.vision.calibration import (
    calibrate_floor,
    calibrate_intrinsics,
    CharucoSpec,
    check_not_collinear,
    load_reference_markers,
    ReferenceMarkers,
)
from ament_formation.core.vision.camera_model import (
    CameraModel,
    CameraSetup,
    load_camera_yaml,
    save_camera_yaml,
)
from ament_formation.core.vision.synthetic_camera import RenderOptions, SyntheticCamera
from ament_formation.tools import cli

# the "unknown" camera to recover: not the default one
TRUE = CameraModel(
    fx_px=548.0,
    fy_px=551.0,
    cx_px=323.0,
    cy_px=236.0,
    distortion=(-0.21, 0.045, 0.0008, -0.0006, 0.0),
    position_m=(1.25, 0.55),
    height_m=2.84,
    yaw_rad=0.03,
    tilt_rad=0.04,
    roll_rad=-0.02,
)
SPEC = CharucoSpec(9, 7, 0.06, 0.045)
REFS = ReferenceMarkers(
    ids=(40, 41, 42, 43, 44),
    poses=((0.0, -0.5, 0.0), (2.4, -0.5, 0.5), (2.4, 1.7, 0.0), (0.0, 1.7, 1.0), (1.2, 0.6, 0.0)),
    size_m=0.15,
)


def _board_views(n: int, seed: int = 3) -> list[tuple[str, np.ndarray]]:
    """Board held 0.9–1.4 m from the camera, tilted up to ~30°, anywhere in the image."""
    sc = SyntheticCamera(TRUE, options=RenderOptions(noise_std=2.0))
    rng = np.random.default_rng(seed)
    tex = SPEC.image(48)
    w, h = SPEC.size_m
    views = []
    for i in range(n):
        rvec = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3)])
        z = rng.uniform(0.9, 1.4)
        u, v = rng.uniform(0.1, 0.9) * 640, rng.uniform(0.1, 0.9) * 480
        center = np.array(
            [(u - TRUE.cx_px) / TRUE.fx_px * z, (v - TRUE.cy_px) / TRUE.fy_px * z, z]
        )
        tvec = center - cv2.Rodrigues(rvec)[0] @ np.array([w / 2, h / 2, 0.0])
        views.append(
            (
                f'view{i}.png',
                sc.render_plane(tex, SPEC.size_m, rvec, tvec, frame_index=i, background=128),
            )
        )
    return views


def _floor_image(camera: CameraModel = TRUE, refs: ReferenceMarkers = REFS) -> np.ndarray:
    sc = SyntheticCamera(camera, refs.layout, RenderOptions(noise_std=2.0, body_radius_m=0.0))
    return sc.render(np.array(refs.poses), np.array(refs.ids))


def _ray_error_px(cam_a: CameraModel, k: np.ndarray, dist: np.ndarray) -> tuple[float, float]:
    """(RMS, max) difference of the viewing rays of two lens models over the image, in pixels of
    ``cam_a``.
    """
    uu, vv = np.meshgrid(np.linspace(32, 607, 33), np.linspace(24, 455, 25))  # 5 % border left out
    px = np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64).reshape(-1, 1, 2)
    a = cv2.undistortPoints(px, cam_a.k, cam_a.dist, P=cam_a.k).reshape(-1, 2)
    b = cv2.undistortPoints(px, k, dist, P=cam_a.k).reshape(-1, 2)
    d = np.linalg.norm(a - b, axis=1)
    return float(np.sqrt((d**2).mean())), float(d.max())


@pytest.fixture(scope='module')
def views():
    return _board_views(16)


def test_intrinsics_are_recovered_from_charuco_views(views):
    r = calibrate_intrinsics(views, SPEC)
    print(
        f'\n[calibration] {r.views_used} views, RMS {r.rms_px:.3f} px, '
        f'fx {r.k[0, 0]:.2f} fy {r.k[1, 1]:.2f} '
        f'cx {r.k[0, 2]:.2f} cy {r.k[1, 2]:.2f}, ray error RMS/max %.3f/%.3f px'
        % _ray_error_px(TRUE, r.k, r.dist)
    )
    assert r.views_used == 16 and r.size_px == (640, 480)
    assert r.rms_px < 0.3
    assert r.k[0, 0] == pytest.approx(TRUE.fx_px, rel=5e-3)
    assert r.k[1, 1] == pytest.approx(TRUE.fy_px, rel=5e-3)
    assert abs(r.k[0, 2] - TRUE.cx_px) < 3.0 and abs(r.k[1, 2] - TRUE.cy_px) < 3.0
    rms, worst = _ray_error_px(TRUE, r.k, r.dist)
    assert rms <= 1.0 and worst <= 2.5
    # the distortion actually matters here: ignoring it would be off by many pixels
    assert _ray_error_px(TRUE, r.k, np.zeros(5))[1] > 10.0
    # end to end: these intrinsics + a floor calibration map the floor within 2 mm
    est = CameraModel(position_m=(1.2, 0.6)).with_intrinsics(r.k, r.dist, r.size_px)
    floor = calibrate_floor(_floor_image(), REFS, est).camera
    grid = np.random.default_rng(1).uniform([-0.3, -0.6], [2.7, 1.8], (400, 2))
    err = np.linalg.norm(floor.pixel_to_floor(TRUE.floor_to_pixel(grid)) - grid, axis=1).max()
    print(f'[calibration] end to end floor mapping error max {err * 1e3:.2f} mm')
    assert err < 2e-3


def test_floor_mapping_is_recovered_from_reference_markers():
    nominal = CameraModel(
        fx_px=TRUE.fx_px,
        fy_px=TRUE.fy_px,
        cx_px=TRUE.cx_px,
        cy_px=TRUE.cy_px,
        distortion=TRUE.distortion,
        position_m=(1.2, 0.6),
    )  # mounting unknown
    r = calibrate_floor(_floor_image(), REFS, nominal)
    grid = np.random.default_rng(0).uniform([-0.3, -0.6], [2.7, 1.8], (400, 2))
    err = np.linalg.norm(r.camera.pixel_to_floor(TRUE.floor_to_pixel(grid)) - grid, axis=1).max()
    print(
        f'\n[calibration] floor: RMS {r.rms_px:.3f} px, floor mapping error max {err * 1e3:.2f} mm'
    )
    assert sorted(r.used_ids) == sorted(REFS.ids)
    assert err < 2e-3 and r.rms_px < 0.3 and r.max_floor_error_m < 3e-3
    assert abs(r.camera.height_m - TRUE.height_m) < 0.01


def test_too_few_views_are_refused(views):
    with pytest.raises(ConfigError, match=r'IMAGES: only 3 usable view\(s\)'):
        calibrate_intrinsics(views[:3], SPEC)
    blank = [(f'blank{i}.png', np.full((480, 640), 128, np.uint8)) for i in range(6)]
    with pytest.raises(ConfigError, match='only 0 usable'):
        calibrate_intrinsics(blank, SPEC)


def test_collinear_or_missing_reference_markers_are_refused():
    with pytest.raises(ConfigError, match='collinear'):
        ReferenceMarkers(
            ids=(1, 2, 3), poses=((0.0, 0.0, 0.0), (1.0, 0.02, 0.0), (2.0, 0.0, 0.0)), size_m=0.15
        )
    with pytest.raises(ConfigError, match='need >= 3'):
        ReferenceMarkers(ids=(1, 2), poses=((0.0, 0.0, 0.0), (1.0, 1.0, 0.0)), size_m=0.15)
    # four on file, but the image shows only the three that lie on one line
    img = _floor_image(
        refs=ReferenceMarkers(
            ids=(40, 41, 42, 43),
            poses=((0.0, 0.0, 0.0), (1.2, 0.01, 0.0), (2.4, 0.0, 0.0), (1.2, 1.5, 0.0)),
            size_m=0.15,
        )
    )
    on_file = ReferenceMarkers(
        ids=(40, 41, 42, 49),
        poses=((0.0, 0.0, 0.0), (1.2, 0.01, 0.0), (2.4, 0.0, 0.0), (1.2, 1.5, 0.0)),
        size_m=0.15,
    )
    with pytest.raises(ConfigError, match='IMAGE \\(markers found\\).*collinear'):
        calibrate_floor(img, on_file, TRUE)
    with pytest.raises(ConfigError, match='found 0 of the 5'):
        calibrate_floor(np.full((480, 640), 128, np.uint8), REFS, TRUE)
    check_not_collinear(np.array([[0, 0], [1, 0], [0, 1]]), 'x')  # a triangle is fine


def test_board_and_marker_files_are_validated(tmp_path):
    assert CharucoSpec.parse('9x7,0.06,0.045') == SPEC
    assert CharucoSpec.parse('5x4,0.05,0.035,DICT_5X5_100').dictionary == 'DICT_5X5_100'
    with pytest.raises(ConfigError, match='--board.marker_m: marker 0.05 m must be smaller'):
        CharucoSpec.parse('7x5,0.04,0.05')
    with pytest.raises(ConfigError, match='--board: expected'):
        CharucoSpec.parse('seven by five')
    f = tmp_path / 'm.yaml'
    f.write_text(
        yaml.safe_dump(
            {
                'size_m': 0.15,
                'markers': [{'id': 1, 'center_m': [0, 0]}, {'id': 2, 'centre_m': [1, 0]}],
            }
        )
    )
    with pytest.raises(ConfigError, match=r'm.yaml: markers\[1\]'):
        load_reference_markers(f)


def test_cli_writes_camera_yaml_and_refuses_degenerate_input(tmp_path, views, capsys):
    paths = []
    for name, img in views[:8]:
        p = tmp_path / name
        cv2.imwrite(str(p), img)
        paths.append(str(p))
    out = tmp_path / 'camera.yaml'
    save_camera_yaml(CameraSetup(), out)  # an existing file: its mounting is kept
    assert (
        cli.main(
            ['calibrate', 'intrinsics', *paths, '--board', '9x7,0.06,0.045', '--out', str(out)]
        )
        == 0
    )
    assert 'reprojection error RMS' in capsys.readouterr().out
    got = load_camera_yaml(out)
    assert got.camera.fx_px == pytest.approx(TRUE.fx_px, rel=5e-3)
    assert got.camera.height_m == CameraSetup().camera.height_m
    assert got.calibration['intrinsics_views'] == 8

    floor_png = tmp_path / 'floor.png'
    cv2.imwrite(str(floor_png), _floor_image())
    markers = tmp_path / 'markers.yaml'
    markers.write_text(
        yaml.safe_dump(
            {
                'size_m': 0.15,
                'markers': [
                    {'id': i, 'center_m': [x, y], 'yaw_rad': yaw}
                    for i, (x, y, yaw) in zip(REFS.ids, REFS.poses)
                ],
            }
        )
    )
    assert (
        cli.main(
            ['calibrate', 'floor', str(floor_png), '--markers', str(markers), '--out', str(out)]
        )
        == 0
    )
    got = load_camera_yaml(out)
    assert abs(got.camera.height_m - TRUE.height_m) < 0.02
    assert got.camera.fx_px == pytest.approx(TRUE.fx_px, rel=5e-3)  # intrinsics kept

    assert (
        cli.main(
            [
                'calibrate',
                'intrinsics',
                *paths[:2],
                '--board',
                '9x7,0.06,0.045',
                '--out',
                str(tmp_path / 'x.yaml'),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'only 2 usable view(s)' in err
    assert not (tmp_path / 'x.yaml').exists()
    collinear = tmp_path / 'line.yaml'
    collinear.write_text(
        yaml.safe_dump(
            {
                'size_m': 0.15,
                'markers': [
                    {'id': 1, 'center_m': [0, 0]},
                    {'id': 2, 'center_m': [1, 0]},
                    {'id': 3, 'center_m': [2, 0]},
                ],
            }
        )
    )
    assert (
        cli.main(
            ['calibrate', 'floor', str(floor_png), '--markers', str(collinear), '--out', str(out)]
        )
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert (
        len(err.splitlines()) == 1
        and 'line.yaml: markers: marker centres are (nearly) collinear' in err
    )
    assert (
        cli.main(['calibrate', 'floor', str(tmp_path / 'nope.png'), '--markers', str(markers)])
        == 2
    )
    assert 'nope.png: cannot read image' in capsys.readouterr().err
