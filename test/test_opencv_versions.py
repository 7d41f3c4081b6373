"""OpenCV versions: the installed one (4.7+ API), OpenCV 4.6 with contrib (python3-opencv of
Debian 12 / Ubuntu 24.04: the free-function ArUco API) and 4.6 without contrib (no cv2.aruco:
refused at start in one line naming what to install).

4.6 runs in a subprocess with ``pip install --target`` folders in front (test/opencv_overlay.py,
cached in ~/.cache/ament_formation); the 4.6 tests skip when pip cannot install them (offline
without a cached copy). Stated: under 4.6 the tracker measures 6 robots on 40 rendered frames
with 100 % detection, position p95 < 1 mm and heading p95 < 0.5° (as under 4.7+), a marker sheet
and ChArUco board are detected, and its marker images equal the installed OpenCV's.
bench/bench_opencv46.py runs the vision and tracker test files under 4.6.
"""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
from opencv_overlay import env, overlay
import pytest

from ament_formation.core.vision import aruco_compat
from ament_formation.core.vision.robot_marker import aruco_dictionary

SCRIPT = r"""
import json, cv2, numpy as np
from ament_formation.core.vision import aruco_compat, marker_sheet as ms
from ament_formation.core.vision.calibration import CharucoSpec
from ament_formation.core.vision.camera_model import CameraSetup
from ament_formation.core.vision.marker_tracking import MarkerTracker
from ament_formation.core.vision.robot_marker import aruco_dictionary
from ament_formation.core.vision.synthetic_camera import RenderOptions, SyntheticCamera
out = {'version': cv2.__version__, 'numpy': np.__version__,
       'new_api': aruco_compat.has_new_api()}
setup = CameraSetup()
ids = (0, 1, 2, 3, 4, 5)
sc = SyntheticCamera(setup.camera, options=RenderOptions(noise_std=2.0), floor=setup.floor)
tr = MarkerTracker(setup.camera, expected_ids=ids)
rng = np.random.default_rng(1)
start = np.column_stack([rng.uniform(0, 2.4, 6), rng.uniform(-0.3, 1.5, 6),
                         rng.uniform(-3, 3, 6)])
found, pos, yaw = 0, [], []
for k in range(40):
    truth = start + k / 30 * np.array([0.1, 0.05, 0.3])
    r = tr.step(sc.render(truth, ids, frame_index=k), k / 30).accepted
    found += len(r)
    for m, p in zip(r.ids, r.poses):
        t = truth[ids.index(int(m))]
        pos.append(float(np.hypot(*(p[:2] - t[:2]))))
        yaw.append(float(abs((p[2] - t[2] + np.pi) % (2 * np.pi) - np.pi)))
out['detection'] = found / 240
out['pos_p95_m'] = float(np.percentile(pos, 95))
out['yaw_p95_deg'] = float(np.degrees(np.percentile(yaw, 95)))
sheet = ms.layout(ms.SheetSpec(marker_ids=(0, 1, 2), marker_size_m=0.05,
                               board=CharucoSpec(5, 4, 0.04, 0.03)))
p = aruco_compat.detector_parameters()
det = aruco_compat.MarkerDetector(aruco_dictionary('DICT_4X4_50'), p)
c, i = det.detect(ms.rasterize(sheet.pages[0], 150))
out['sheet_ids'] = sorted(int(v) for v in i.ravel())
c, i = aruco_compat.CharucoDetector(CharucoSpec(5, 4, 0.04, 0.03).board()).detect(
    ms.rasterize(sheet.pages[1], 150))
out['charuco_corners'] = 0 if i is None else len(i)
out['marker_7'] = aruco_compat.marker_image(aruco_dictionary('DICT_4X4_50'), 7, 60).tolist()
print(json.dumps(out))
"""


def test_the_installed_opencv_is_supported():
    assert aruco_compat.opencv_problem() is None
    assert aruco_compat.has_new_api() == (aruco_compat.opencv_version() >= (4, 7, 0))
    cells = aruco_compat.marker_cells(aruco_dictionary('DICT_4X4_50'), 0)
    assert cells.shape == (6, 6) and not cells[0].any() and not cells[:, 0].any()


def test_opencv_46_with_contrib_tracks_markers_as_well():
    folder = overlay(contrib=True)
    if folder is None:
        pytest.skip('OpenCV 4.6 (opencv-contrib-python-headless 4.6.0.66) cannot be installed')
    res = subprocess.run([sys.executable, '-c', SCRIPT], env=env(folder), capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    print(f'\n[opencv {out["version"]}, numpy {out["numpy"]}] detection {out["detection"]:.1%}, '
          f'position p95 {out["pos_p95_m"] * 1e3:.2f} mm, heading p95 {out["yaw_p95_deg"]:.2f}°, '
          f'sheet {out["sheet_ids"]}, ChArUco corners {out["charuco_corners"]}')
    assert out['version'] == '4.6.0' and out['new_api'] is False
    assert out['detection'] == 1.0
    assert out['pos_p95_m'] < 1e-3 and out['yaw_p95_deg'] < 0.5
    assert out['sheet_ids'] == [0, 1, 2] and out['charuco_corners'] == 12
    here = aruco_compat.marker_image(aruco_dictionary('DICT_4X4_50'), 7, 60)
    assert np.array_equal(np.array(out['marker_7'], np.uint8), here)


def test_opencv_46_without_contrib_is_refused_in_one_line(tmp_path):
    folder = overlay(contrib=False)
    if folder is None:
        pytest.skip('OpenCV 4.6 (opencv-python-headless 4.6.0.66) cannot be installed')
    for args in (
        ['-m', 'ament_formation.tools.cli', 'markers', '--out', str(tmp_path / 'm.pdf'),
         '--ids', '1'],
        ['-m', 'ament_formation.nodes.tracker'],
    ):
        res = subprocess.run([sys.executable, *args], env=env(folder), capture_output=True,
                             text=True, timeout=300)
        err = res.stderr.strip()
        assert res.returncode == 2 and '\n' not in err, err
        assert 'OpenCV: 4.6.0 has no cv2.aruco' in err and 'opencv-contrib-python-headless' in err
        assert 'python3-opencv' in err
    assert cv2.__version__ != '4.6.0'  # this process kept its own OpenCV
