"""The overhead camera must see where a scenario's robots go (core/scenario/coverage.py).

`formation run config/scenarios/v_formation.yaml` never started before: the scenario spans x from
-0.8 to 5 m and config/camera.yaml sees x from -0.45 to 2.85 m, so the robots outside got no
pose and the coordinator waited for them; the random families' 3 x 2.5 m floor does not fit that
view either. The twin's launcher now fits the simulated camera to such a scenario (same lens and
height, a larger image). Checked here: which scenarios need it, that the fitted camera sees the
whole extent, that markers at its corners are detected, and launch_info.py's output.
"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from ament_formation.core.scenario import coverage
from ament_formation.core.scenario.families import generate
from ament_formation.core.scenario.loader import load_scenario, parse_scenario
from ament_formation.core.vision.camera_model import load_camera_yaml
from ament_formation.core.vision.marker_tracking import make_detector, measure
from ament_formation.core.vision.robot_marker import MarkerLayout
from ament_formation.core.vision.synthetic_camera import RenderOptions, SyntheticCamera

ROOT = Path(__file__).resolve().parents[1]
SETUP = load_camera_yaml(ROOT / 'config' / 'camera.yaml')
PAPER = ROOT / 'config' / 'scenarios' / 'paper.yaml'
V = ROOT / 'config' / 'scenarios' / 'v_formation.yaml'


def test_the_lab_camera_sees_the_paper_scenario_but_not_v_formation():
    assert not coverage.needs_fitting(SETUP, load_scenario(PAPER))
    v = load_scenario(V)
    assert coverage.needs_fitting(SETUP, v)
    x0, x1, y0, y1 = coverage.scenario_extent_m(v, obstacles=False)
    assert x0 < -0.8 and x1 > 4.9  # the V's goals over its mission, with the margin
    # what the view misses lies beyond its x range
    missed = coverage.unseen(SETUP.camera, (x0, x1, y0, y1))
    assert len(missed) and (missed[:, 0].max() > 2.85 or missed[:, 0].min() < -0.45)


def test_a_fitted_camera_sees_everything_with_the_same_lens_and_height():
    v = load_scenario(V)
    extent = coverage.scenario_extent_m(v)
    fit = coverage.fit_camera(SETUP, extent)
    cam, lab = fit.camera, SETUP.camera
    assert len(coverage.unseen(cam, extent)) == 0
    assert (cam.fx_px, cam.fy_px, cam.height_m) == (lab.fx_px, lab.fy_px, lab.height_m)
    assert cam.width_px > lab.width_px and cam.height_px >= lab.height_px
    assert cam.width_px % 16 == 0 and cam.height_px % 16 == 0
    assert not coverage.needs_fitting(fit, v)
    # a scenario the lab camera sees is left as it is: the image is never narrowed
    paper = coverage.fit_camera(SETUP, coverage.scenario_extent_m(load_scenario(PAPER)))
    assert paper.camera.size_px[0] >= lab.width_px and paper.camera.size_px[1] >= lab.height_px


def test_random_scenarios_on_their_declared_floor_get_a_camera_over_that_floor():
    scenario = parse_scenario(generate('two_teams', 7, 0)[0])
    floor = scenario.floor
    assert coverage.scenario_extent_m(scenario) == (*floor.x_m, *floor.y_m)
    gx0, gx1, gy0, gy1 = coverage.scenario_extent_m(scenario, obstacles=False)
    assert floor.x_m[0] <= gx0 < gx1 <= floor.x_m[1] and floor.y_m[0] <= gy0 < gy1 <= floor.y_m[1]
    fit = coverage.fit_camera(SETUP, coverage.scenario_extent_m(scenario))
    assert len(coverage.unseen(fit.camera, (*floor.x_m, *floor.y_m))) == 0


def test_markers_at_the_corners_of_a_fitted_view_are_detected():
    v = load_scenario(V)
    extent = coverage.scenario_extent_m(v)
    fit = coverage.fit_camera(SETUP, extent)
    layout = MarkerLayout()
    x0, x1, y0, y1 = extent
    inset = 0.15  # a robot's marker centre, its body on the extent
    poses = np.array([[x0 + inset, y0 + inset, 0.3], [x1 - inset, y0 + inset, 2.0],
                      [x0 + inset, y1 - inset, -1.2], [x1 - inset, y1 - inset, 3.0],
                      [(x0 + x1) / 2, (y0 + y1) / 2, 0.0]])
    ids = [0, 1, 2, 3, 4]
    image = SyntheticCamera(fit.camera, layout, RenderOptions(noise_std=2.0), fit.floor).render(
        poses, ids)
    found = measure(image, make_detector(layout, fit.camera.size_px, fit.camera), fit.camera,
                    layout)
    assert sorted(int(i) for i in found.ids) == ids
    order = np.argsort(found.ids)
    err = np.linalg.norm(found.poses[order, :2] - poses[:, :2], axis=1)
    assert err.max() < 0.01, err


def _launch_info(*args, env=None):
    return subprocess.run([sys.executable, str(ROOT / 'scripts' / 'launch_info.py'), *args],
                          capture_output=True, text=True, timeout=60, env=env)


def test_launch_info_fits_the_camera_only_where_needed(tmp_path):
    env = {**os.environ, 'PYTHONPATH': str(ROOT)}
    r = _launch_info(str(PAPER), '--camera-fit', str(tmp_path), env=env)
    assert r.returncode == 0, r.stderr
    assert f"camera_file={ROOT / 'config' / 'camera.yaml'}" in r.stdout.splitlines()
    assert not (tmp_path / 'camera.yaml').exists() and r.stderr == ''
    r = _launch_info(str(V), '--camera-fit', str(tmp_path), 'camera.yaml', env=env)
    assert r.returncode == 0, r.stderr
    assert f"camera_file={tmp_path / 'camera.yaml'}" in r.stdout.splitlines()
    assert r.stderr.count('\n') == 1 and 'fitted' in r.stderr, r.stderr
    fitted = load_camera_yaml(tmp_path / 'camera.yaml')
    assert len(coverage.unseen(fitted.camera, coverage.scenario_extent_m(load_scenario(V)))) == 0
    # a camera file that does not exist: one line, status 2
    r = _launch_info(str(PAPER), '--camera-fit', str(tmp_path), 'no_such_camera.yaml', env=env)
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and 'no_such_camera' in r.stderr


@pytest.mark.parametrize('name', ['paper.yaml', 'v_formation.yaml'])
def test_shipped_scenarios_are_seen_by_the_camera_the_twin_gives_them(name):
    scenario = load_scenario(ROOT / 'config' / 'scenarios' / name)
    setup = SETUP
    if coverage.needs_fitting(setup, scenario):
        setup = coverage.fit_camera(setup, coverage.scenario_extent_m(scenario))
    assert not coverage.needs_fitting(setup, scenario)


def test_the_camera_pcs_launcher_warns_when_the_scenario_leaves_the_trackers_view(tmp_path):
    env = {**os.environ, 'PYTHONPATH': str(ROOT)}
    r = _launch_info(str(PAPER), '--camera-check', env=env)
    assert r.returncode == 0 and r.stderr == '', r.stderr
    r = _launch_info(str(V), '--camera-check', env=env)
    assert r.returncode == 0 and 'ids=' in r.stdout
    assert r.stderr.count('\n') == 1 and 'leaves the view of' in r.stderr, r.stderr
    # the lab's tracker reads a camera that sees it (its params file's camera_config): no line
    from ament_formation.core.vision.camera_model import save_camera_yaml

    cam = save_camera_yaml(coverage.fit_camera(SETUP, coverage.scenario_extent_m(
        load_scenario(V))), tmp_path / 'wide.yaml')
    params = tmp_path / 'base.yaml'
    params.write_text(f'formation_tracker:\n  ros__parameters:\n    camera_config: {cam}\n')
    r = _launch_info(str(V), str(params), '--camera-check', env=env)
    assert r.returncode == 0 and r.stderr == '', r.stderr
