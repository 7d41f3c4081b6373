"""Does the overhead camera see everywhere a scenario's robots go? (docs/camera.md, "Coverage")

A robot the camera does not see gets no pose: its controller never starts (or stops,
``stopped_pose``) and the coordinator waits for it. On real robots the camera is what it is: the
camera PC's launcher says in one line when a scenario leaves its view (scripts/launch_info.py
``--camera-check``). On the simulated twin the camera is simulated too, so a launcher may *fit*
one to the scenario instead (:func:`fit_camera`): the same lens and height (so a marker is as
many pixels wide as with the lab's camera, and the tracker sees the same sizes), straight down
over the scenario's middle, with an image large enough to take the whole scenario in.

Where robots go (:func:`scenario_extent_m`): every robot's start and its formation goal over the
mission (its team leader's reference plus its slot, every 0.25 s) grown by ``margin_m``: a camera
must see that much (:func:`needs_fitting`). Robots also go around obstacles, on whichever side: a
fitted camera takes in every obstacle's ellipse scaled by the avoidance's ``heading_scale`` (the
limit cycles robots go around it on) at its poses over the mission, plus a body radius, too, or
the whole of a declared ``floor:`` (robots stay on it; it also bounds the goals' extent).
"""

from __future__ import annotations

from dataclasses import replace
import math

import numpy as np

from ament_formation.core.model.obstacles import ObstacleField
from ament_formation.core.vision.camera_model import CameraSetup, FloorArea
from ament_formation.core.vision.robot_marker import MarkerLayout

MARGIN_M = 0.25  # room around where robots go [m]: a body and its marker beyond the goal
BORDER_PX = 12  # a marker nearer the image's edge than this is not counted as seen [px]
STEP_S = 0.25  # sampling of goals and obstacles over the mission [s]


def scenario_extent_m(scenario, margin_m: float = MARGIN_M, *,
                      obstacles: bool = True) -> tuple[float, float, float, float]:
    """(x_min, x_max, y_min, y_max) [m] of where the scenario's robots may go (module
    docstring); ``obstacles=False``: where their goals go only (what a camera must see at least).
    """
    floor = scenario.floor
    if floor is not None and obstacles:
        return (*floor.x_m, *floor.y_m)
    t = np.linspace(0.0, scenario.duration_s, int(scenario.duration_s / STEP_S) + 2)
    points = []
    for r in scenario.robots:
        points.append(np.asarray(r.initial_pose[:2], dtype=float)[None])
        lead = scenario.team_leader(r.id)
        ref = np.asarray(scenario.robot(lead).path.reference(t)[0], dtype=float)
        points.append(ref + scenario.slot(r.id) - scenario.slot(lead))
    pts = np.concatenate(points)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    if obstacles and scenario.obstacles:
        body = max(r.params.body_radius_m for r in scenario.robots)
        field = ObstacleField(scenario.obstacles)
        for ts in t:
            o = field.at(float(ts))
            a, b = (o.semi_axes_m * scenario.avoidance.heading_scale).T
            cos, sin = np.cos(o.phi_rad), np.sin(o.phi_rad)
            half = np.c_[np.hypot(a * cos, b * sin), np.hypot(a * sin, b * cos)] + body
            lo = np.minimum(lo, (o.center_m - half).min(axis=0))
            hi = np.maximum(hi, (o.center_m + half).max(axis=0))
    x0, x1 = float(lo[0] - margin_m), float(hi[0] + margin_m)
    y0, y1 = float(lo[1] - margin_m), float(hi[1] + margin_m)
    if floor is not None:  # robots stay on it
        x0, x1 = max(x0, floor.x_m[0]), min(x1, floor.x_m[1])
        y0, y1 = max(y0, floor.y_m[0]), min(y1, floor.y_m[1])
    return (x0, x1, y0, y1)


def _outline(extent, step_m: float = 0.05) -> np.ndarray:
    """Points every ``step_m`` along the rectangle's edges."""
    x0, x1, y0, y1 = extent
    nx = max(2, int(math.ceil((x1 - x0) / step_m)) + 1)
    ny = max(2, int(math.ceil((y1 - y0) / step_m)) + 1)
    xs, ys = np.linspace(x0, x1, nx), np.linspace(y0, y1, ny)
    return np.concatenate([np.c_[xs, np.full(nx, y0)], np.c_[xs, np.full(nx, y1)],
                           np.c_[np.full(ny, x0), ys], np.c_[np.full(ny, x1), ys]])


def unseen(camera, extent, marker_height_m: float | None = None) -> np.ndarray:
    """The points of the extent's outline (every 5 cm) the camera does not see at the markers'
    height (outside the image less :data:`BORDER_PX`, or behind the camera): (K, 2) [m], empty
    when it sees the whole extent (a rectangle the camera's view contains with its outline).
    """
    z = MarkerLayout().height_m if marker_height_m is None else marker_height_m
    pts = _outline(extent)
    r_cw = camera.r_wc.T
    depth = (r_cw @ (np.c_[pts, np.full(len(pts), z)] - camera.center_w).T)[2]
    px = camera.floor_to_pixel(pts, z)
    w, h = camera.size_px
    seen = ((depth > 0) & np.all(np.isfinite(px), axis=1)
            & (px[:, 0] >= BORDER_PX) & (px[:, 0] <= w - 1 - BORDER_PX)
            & (px[:, 1] >= BORDER_PX) & (px[:, 1] <= h - 1 - BORDER_PX))
    return pts[~seen]


def fit_camera(setup: CameraSetup, extent) -> CameraSetup:
    """A simulated camera seeing the whole ``extent``: ``setup``'s focal lengths and height,
    looking straight down over the extent's middle, without lens distortion, its image widened
    (never narrowed) in steps of 16 px until the extent with :data:`BORDER_PX` fits.
    """
    cam = setup.camera
    x0, x1, y0, y1 = extent
    z = MarkerLayout().height_m
    scale = cam.height_m - z  # metres per normalised image unit at the markers' height

    def size(span_m, f_px, now_px):
        need = span_m / scale * f_px + 2 * BORDER_PX + 4
        return max(now_px, int(math.ceil(need / 16.0)) * 16)

    w, h = size(x1 - x0, cam.fx_px, cam.width_px), size(y1 - y0, cam.fy_px, cam.height_px)
    fitted = replace(cam, width_px=w, height_px=h, cx_px=(w - 1) / 2.0, cy_px=(h - 1) / 2.0,
                     distortion=(0.0, 0.0, 0.0, 0.0, 0.0),
                     position_m=((x0 + x1) / 2.0, (y0 + y1) / 2.0),
                     yaw_rad=0.0, tilt_rad=0.0, roll_rad=0.0)
    floor = FloorArea(center_m=((x0 + x1) / 2.0, (y0 + y1) / 2.0), size_m=(x1 - x0, y1 - y0))
    note = {'source': f"fitted to the scenario by the twin's launcher: {w}x{h} px, "
                      f'straight down, no distortion (core/scenario/coverage.py)'}
    return CameraSetup(fitted, floor, note)


def needs_fitting(setup: CameraSetup, scenario) -> bool:
    """The camera does not see every start and formation goal of the scenario (with margin)."""
    return len(unseen(setup.camera, scenario_extent_m(scenario, obstacles=False))) > 0
