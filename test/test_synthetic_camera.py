"""Synthetic camera and camera model: geometry, determinism, noise, obstacles, motion blur,
YAML.
"""

from __future__ import annotations

import math

import cv2
from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from ament_formation.core.config_files import config_file
from ament_formation.core.errors import ConfigError
from ament_formation.core.vision.camera_model import (
    CameraModel,
    CameraSetup,
    FloorArea,
    load_camera_yaml,
    rotation_vector,
    save_camera_yaml,
)
from ament_formation.core.vision.marker_tracking import detect, make_detector, refine_corners
from ament_formation.core.vision.robot_marker import MarkerLayout
from ament_formation.core.vision.synthetic_camera import Obstacles, RenderOptions, SyntheticCamera

CAM = CameraSetup().camera
POSES = np.array([[0.2, 0.0, 0.3], [1.2, 0.6, -2.0], [2.4, 1.5, 1.0], [2.5, -0.4, 3.0]])
IDS = np.array([3, 7, 11, 42])


@pytest.fixture(scope='module')
def sc() -> SyntheticCamera:
    return SyntheticCamera(CAM, MarkerLayout(), RenderOptions(noise_std=2.0))


def test_default_frame_is_640x480_mono8_at_30_fps(sc):
    frame = sc.render(POSES, IDS)
    assert frame.shape == (480, 640) and frame.dtype == np.uint8
    assert CAM.fps_hz == 30.0 and CAM.height_m == 2.86


def test_the_shipped_camera_yaml_is_the_paper_setup():
    setup = load_camera_yaml(config_file('camera.yaml'))
    assert setup.camera.size_px == (640, 480) and setup.camera.height_m == pytest.approx(2.86)
    assert setup.floor.size_m == (3.0, 2.4)
    x0, x1, y0, y1 = setup.floor.bounds_m  # the whole floor is in view, with margin
    px = setup.camera.floor_to_pixel(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))
    assert (
        (px[:, 0] > 10).all()
        and (px[:, 0] < 630).all()
        and (px[:, 1] > 10).all()
        and (px[:, 1] < 470).all()
    )


def test_frames_are_deterministic_for_a_seed(sc):
    a = sc.render(POSES, IDS, frame_index=5)
    b = sc.render(POSES, IDS, frame_index=5)
    c = sc.render(POSES, IDS, frame_index=6)
    other = SyntheticCamera(CAM, options=RenderOptions(noise_std=2.0, seed=9)).render(
        POSES, IDS, frame_index=5
    )
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c) and not np.array_equal(a, other)
    # only the noise differs between frame indices
    assert np.abs(a.astype(int) - c.astype(int)).mean() < 4.0


def test_markers_land_where_the_camera_model_projects_them():
    """Noise-free frames: refined corners agree with the projected true corners (sub-pixel)."""
    layout = MarkerLayout()
    sc0 = SyntheticCamera(CAM, layout, RenderOptions(noise_std=0.0))
    corners, ids = detect(make_detector(layout, CAM.size_px, CAM), sc0.render(POSES, IDS))
    assert sorted(ids.tolist()) == sorted(IDS.tolist())
    xn = refine_corners(sc0.render(POSES, IDS), corners, CAM)
    measured = CAM.project(
        np.column_stack([xn.reshape(-1, 2) * 2.0, np.full(len(ids) * 4, 2.0)]) @ CAM.r_wc.T
        + CAM.center_w
    ).reshape(-1, 4, 2)  # rays back through K, dist
    truth = CAM.floor_to_pixel(layout.corners_w(POSES).reshape(-1, 2), layout.height_m).reshape(
        -1, 4, 2
    )
    order = [list(IDS).index(i) for i in ids]
    err = np.linalg.norm(measured - truth[order], axis=2)
    assert err.max() < 0.25 and err.mean() < 0.1, err


def test_noise_has_the_requested_standard_deviation():
    flat = SyntheticCamera(CAM, options=RenderOptions(noise_std=3.0)).render(np.zeros((0, 3)), [])
    patch = flat[200:280, 280:360].astype(float)  # uniform floor in the image centre
    assert abs(patch.std() - 3.0) < 0.3
    assert abs(patch.mean() - RenderOptions().floor_level) < 0.5


def test_obstacles_and_floor_area_are_drawn(sc):
    obs = Obstacles(np.array([[1.0, -0.2]]), np.array([[0.4, 0.15]]), np.array([2.0944]))
    clean = SyntheticCamera(CAM, options=RenderOptions(noise_std=0.0))
    frame = clean.render(np.zeros((0, 3)), [], obs)
    o = RenderOptions()
    u, v = CAM.floor_to_pixel(np.array([[1.0, -0.2]]))[0].round().astype(int)
    assert frame[v, u] == o.obstacle_level
    # a point 0.3 m from the centre along the minor axis is outside the obstacle
    minor = np.array([-math.sin(2.0944), math.cos(2.0944)])
    u2, v2 = CAM.floor_to_pixel(np.array([[1.0, -0.2]]) + 0.3 * minor)[0].round().astype(int)
    assert frame[v2, u2] == o.floor_level
    assert frame[2, 2] == o.outside_level  # beyond the 3 x 2.4 m floor
    assert (frame == o.obstacle_level).sum() > 500


def test_motion_blur_smears_moving_markers_only():
    blur = SyntheticCamera(CAM, options=RenderOptions(noise_std=0.0, exposure_s=0.03))
    still = SyntheticCamera(CAM, options=RenderOptions(noise_std=0.0))
    pose = np.array([[1.2, 0.6, 0.0]])
    rates = np.array([[1.0, 0.0, 0.0]])  # 1 m/s along x: 3 cm (~6 px) in 30 ms
    sharp = still.render(pose, [5]).astype(float)
    smeared = blur.render(pose, [5], pose_rates=rates).astype(float)
    assert np.array_equal(
        blur.render(pose, [5], pose_rates=np.zeros((1, 3))), sharp.astype(np.uint8)
    )
    u, v = CAM.floor_to_pixel(MarkerLayout().marker_centers_w(pose), 0.08)[0].round().astype(int)
    win = np.s_[v - 9: v + 10, u - 9: u + 10]  # inside the marker's white plate
    gx_sharp = np.abs(np.diff(sharp[win], axis=1)).max()
    gx_blur = np.abs(np.diff(smeared[win], axis=1)).max()
    gy_blur = np.abs(np.diff(smeared[win], axis=0)).max()  # across the motion: still sharp
    assert gx_blur < 0.5 * gx_sharp and gy_blur > 0.8 * gx_sharp


def test_bad_render_input_is_refused(sc):
    with pytest.raises(ConfigError, match='marker_ids'):
        sc.render(POSES, IDS[:2])
    with pytest.raises(ConfigError, match='marker_ids'):
        sc.render(POSES[:1], [50])  # DICT_4X4_50 has ids 0..49
    with pytest.raises(ConfigError, match='noise_std'):
        RenderOptions(noise_std=-1.0)


# ------------------------------------------------------------------ camera model
@settings(max_examples=40, deadline=None)
@given(
    st.floats(-3.1, 3.1),
    st.floats(0.0, 0.5),
    st.floats(-0.3, 0.3),
    st.floats(-1.0, 2.0),
    st.floats(-1.0, 2.0),
    st.floats(1.5, 4.0),
)
def test_mounting_round_trips_through_an_opencv_pose(yaw, tilt, roll, x, y, h):
    cam = CameraModel(position_m=(x, y), height_m=h, yaw_rad=yaw, tilt_rad=tilt, roll_rad=roll)
    back = CameraModel.from_pose(cam.rvec, cam.tvec, **cam.intrinsic_fields())
    assert np.allclose(back.r_wc, cam.r_wc, atol=1e-9) and np.allclose(
        back.center_w, cam.center_w, atol=1e-9
    )
    pts = np.array([[x + 0.3, y - 0.2], [x - 0.5, y + 0.4]])
    assert np.allclose(back.pixel_to_floor(cam.floor_to_pixel(pts, 0.05), 0.05), pts, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-1.0, 1.0),
    st.floats(-1.0, 1.0),
    st.floats(-1.0, 1.0),
    st.sampled_from(
        [0.0, 1e-12, 1e-6, 0.5, 1.5, np.pi - 1e-3, np.pi - 1e-7, np.pi - 1e-12, np.pi]
    ),
)
def test_rotation_vector_is_exact_near_zero_and_pi(ax, ay, az, angle):
    """A camera looking straight down is a rotation by pi: rotation_vector must stay exact there
    (cv2.Rodrigues matrix -> vector loses up to half the digits near pi).
    """
    axis = np.array([ax, ay, az])
    if np.linalg.norm(axis) < 1e-3:
        axis = np.array([1.0, 0.0, 0.0])
    r = cv2.Rodrigues((axis / np.linalg.norm(axis) * angle).reshape(3, 1))[0]
    back = cv2.Rodrigues(rotation_vector(r).reshape(3, 1))[0]
    assert np.abs(back - r).max() < 1e-12


def test_pixel_floor_mapping_inverts_projection_across_the_image():
    rng = np.random.default_rng(0)
    xy = rng.uniform([-0.3, -0.6], [2.7, 1.8], (500, 2))
    for z in (0.0, 0.08):
        assert np.abs(CAM.pixel_to_floor(CAM.floor_to_pixel(xy, z), z) - xy).max() < 1e-9


def test_camera_yaml_round_trip_and_field_errors(tmp_path):
    setup = CameraSetup(
        CameraModel(fx_px=600.0, position_m=(1.0, 0.5), tilt_rad=0.1),
        FloorArea((1.0, 0.5), (3.0, 2.4)),
        {'source': 'test'},
    )
    path = save_camera_yaml(setup, tmp_path / 'cam.yaml')
    assert load_camera_yaml(path) == setup
    text = path.read_text()
    (tmp_path / 'bad.yaml').write_text(text.replace('height_m: 2.86', 'height_m: -1.0'))
    with pytest.raises(
        ConfigError,
        match=r'bad.yaml: mounting.height_m: must be a finite number > 0|'
        r'bad.yaml: mounting.height_m: must be > 0',
    ):
        load_camera_yaml(tmp_path / 'bad.yaml')
    (tmp_path / 'typo.yaml').write_text(text + 'lens: wide\n')
    with pytest.raises(ConfigError, match='typo.yaml: lens: unknown key'):
        load_camera_yaml(tmp_path / 'typo.yaml')
    with pytest.raises(ConfigError, match='distortion'):
        CameraModel(distortion=(0.1, 0.0, 0.0))
