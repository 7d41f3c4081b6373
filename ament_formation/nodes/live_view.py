"""formation_live_view: the run, live, in Foxglove (docs/live_view.md).

Serves the formation to the Foxglove app over the Foxglove WebSocket protocol (``foxglove-sdk``;
open ``ws://HOST:PORT`` as a "Foxglove WebSocket" connection, layout
config/foxglove/formation_layout.json). What it shows comes from core/sim/scene.py (ROS-free):

  /formation/scene             foxglove.SceneUpdate: per robot its body disc, heading arrow and a
                               label (id, mode, target, direction); its formation goal g_i (sphere
                               and a thin line to it); while it avoids, an arrow of its sense of
                               circulation (ccw green, cw orange) and a line to what it goes round;
                               per obstacle P (filled), L and Q (outlines) placed at the obstacle's
                               pose at scenario time, so they move and turn with it; the active
                               graph edges parent -> child                         scene_rate_hz
  /camera/image/compressed     foxglove.CompressedImage (JPEG of the overhead camera)
  image_rate_hz
  /formation/series/robot_<id> JSON {t_s, formation_error_m, clearance_m, nearest_obstacle,
                               robot_distance_m, torque_left_nm, torque_right_nm, avoiding, mode}
                               for the Plot panel                                   series_rate_hz
  /formation/status            JSON {t_s, start_s, revision, parents, avoiding, modes}: on every
                               graph change and every second

Everything is computed and sent only while a Foxglove client subscribes to it, and the ROS
subscriptions behind it (states, modes, wheel torques, camera) exist only then too: with no
client the live view costs next to nothing. Scenario time is ROS time minus ``start_s`` of
/formation/graph; obstacles come from the scenario at that time. The server also publishes the
ROS time (Foxglove's "time" capability), so the app's clock follows a simulated /clock.

Topics (QoS from ros/qos.py)
  sub  /formation/graph       std_msgs/String JSON (parents, avoiding, start_s)      QOS_GRAPH
  sub  robot_<id>/state       nav_msgs/Odometry (fused pose; taken serialized)       QOS_CONTROL
  sub  robot_<id>/mode        std_msgs/String JSON {mode, target, direction, avoiding} QOS_CONTROL
  sub  robot_<id>/wheel_torque sensor_msgs/JointState effort [left, right] (serialized) QOS_CONTROL
  sub  image_topic            sensor_msgs/Image (mono8, bgr8, rgb8, ...; serialized)  QOS_IMAGE

Parameters
  scenario        str    scenario YAML (required)
  host            str    address the WebSocket server binds to                 default 127.0.0.1
                         (loopback: this machine only; the camera PC's lab address or 0.0.0.0
                         to let the lab network connect, see docs/live_view.md)
  port            int    TCP port (0: any free port, logged at start)          default 8765
  scene_rate_hz   float  3D scene updates [Hz]                                 default 10
  series_rate_hz  float  time-series samples per robot [Hz]                    default 10
  image_rate_hz   float  camera frames sent [Hz] (0: no image)                 default 5
  jpeg_quality    int    JPEG quality, 1..100                                  default 75
  image_topic     str    the camera topic                         default /camera/image_raw

Diagnostics (/diagnostics, docs/diagnostics.md)
  "formation_live_view: server"  OK: its URL, what some client shows, messages sent per channel
  "formation_live_view: inputs"  WARN for 10 s after a rejected input (graph/mode payload, non-
                                 finite state or torque, unusable image), with the counts
"""

from __future__ import annotations

from dataclasses import dataclass
import ipaddress
import json
import math
import re
import sys
import time

import numpy as np
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import String

from ament_formation.core.errors import ConfigError
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.core.sim.scene import (
    finite_or_none,
    LiveScene,
    robot_rgb,
    scenario_time_s,
    Scene,
)
from ament_formation.ros import diagnostics as diag
from ament_formation.ros import messages as msgs
from ament_formation.ros.executors import run_node
from ament_formation.ros.params import declare_dataclass
from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH, QOS_IMAGE

SCENE_TOPIC = '/formation/scene'
IMAGE_TOPIC = '/camera/image/compressed'
STATUS_TOPIC = '/formation/status'
SERIES_TOPIC = '/formation/series/robot_{id}'
WORLD_FRAME = msgs.WORLD_FRAME

_HOSTNAME_RE = re.compile(r'^[A-Za-z0-9]([A-Za-z0-9.\-]{0,252})$')


@dataclass(frozen=True)
class LiveViewParams:
    scenario: str = ''
    host: str = '127.0.0.1'
    port: int = 8765
    scene_rate_hz: float = 10.0
    series_rate_hz: float = 10.0
    image_rate_hz: float = 5.0
    jpeg_quality: int = 75
    image_topic: str = '/camera/image_raw'

    def __post_init__(self) -> None:
        if not self.scenario:
            raise ConfigError('is required (path of a scenario YAML)', 'scenario')
        if not (
            isinstance(self.host, str) and (_is_ip(self.host) or _HOSTNAME_RE.match(self.host))
        ):
            raise ConfigError(f'must be an IP address or host name (got {self.host!r})', 'host')
        if not (isinstance(self.port, int) and 0 <= self.port <= 65535):
            raise ConfigError(
                f'must be a TCP port in [0, 65535] (0: any free port; got {self.port!r})', 'port'
            )
        for name, lo, hi, zero_ok in (
            ('scene_rate_hz', 0.5, 60.0, False),
            ('series_rate_hz', 0.5, 200.0, False),
            ('image_rate_hz', 0.1, 30.0, True),
        ):
            v = getattr(self, name)
            ok = (
                isinstance(v, (int, float))
                and math.isfinite(v)
                and (lo <= v <= hi or (zero_ok and v == 0))
            )
            if not ok:
                raise ConfigError(
                    f'must be in [{lo:g}, {hi:g}] Hz{" or 0" if zero_ok else ""} (got {v!r})', name
                )
        if not (isinstance(self.jpeg_quality, int) and 1 <= self.jpeg_quality <= 100):
            raise ConfigError(
                f'must be an integer in [1, 100] (got {self.jpeg_quality!r})', 'jpeg_quality'
            )
        if not (isinstance(self.image_topic, str) and self.image_topic.strip()):
            raise ConfigError('must be a topic name', 'image_topic')


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def is_loopback(host: str) -> bool:
    """True when ``host`` only accepts connections from this machine."""
    if host == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


# ------------------------------------------------------------------------------ foxglove messages
SERIES_SCHEMA = {
    'title': 'ament_formation.RobotSeries',
    'description': "One robot's live time series (formation_live_view)",
    'type': 'object',
    'properties': {
        't_s': {
            'type': ['number', 'null'],
            'description': 'scenario time [s] (null before the start)',
        },
        'formation_error_m': {'type': ['number', 'null'], 'description': '|p_i - g_i| [m]'},
        'clearance_m': {
            'type': ['number', 'null'],
            'description': (
                'signed distance of p_i to the nearest prohibited ellipse P_j [m], < 0 inside'
            ),
        },
        'nearest_obstacle': {'type': ['string', 'null']},
        'robot_distance_m': {
            'type': ['number', 'null'],
            'description': 'distance to the nearest other robot [m]',
        },
        'torque_left_nm': {
            'type': ['number', 'null'],
            'description': 'commanded left wheel torque [N m]',
        },
        'torque_right_nm': {
            'type': ['number', 'null'],
            'description': 'commanded right wheel torque [N m]',
        },
        'avoiding': {'type': 'integer', 'description': '1 in an avoidance mode, else 0'},
        'mode': {'type': ['string', 'null']},
    },
}

STATUS_SCHEMA = {
    'title': 'ament_formation.FormationStatus',
    'type': 'object',
    'properties': {
        't_s': {'type': ['number', 'null']},
        'start_s': {'type': ['number', 'null']},
        'revision': {'type': 'integer'},
        'parents': {'type': 'object'},
        'avoiding': {'type': 'array', 'items': {'type': 'integer'}},
        'modes': {'type': 'object'},
    },
}


def _fx():
    """The foxglove.messages module (imported on first use: the SDK is a compiled extension)."""
    from foxglove import messages

    return messages


def _yaw_quat(fx, yaw_rad: float):
    half = 0.5 * float(yaw_rad)
    return fx.Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))


def _pose(fx, x: float, y: float, z: float = 0.0, yaw_rad: float = 0.0):
    return fx.Pose(
        position=fx.Vector3(x=float(x), y=float(y), z=float(z)), orientation=_yaw_quat(fx, yaw_rad)
    )


def _color(fx, rgb, a: float = 1.0):
    return fx.Color(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=float(a))


OUTLINE_RGBA = {'P': (0.8, 0.1, 0.1, 1.0), 'L': (0.1, 0.5, 0.9, 1.0), 'Q': (0.5, 0.5, 0.5, 0.7)}
CCW_RGB, CW_RGB = (0.1, 0.7, 0.2), (1.0, 0.55, 0.0)


def _robot_entities(fx, entity, r, t_text: str) -> None:
    """Robot r's entities: robot_<id> (body disc, heading arrow, label, metadata), goal_<id> (the
    goal and a line to it, empty without a goal), avoid_<id> (the circulation arrow and a line to
    the target while avoiding, else empty).
    """
    x, y, th = (float(v) for v in r.pose)
    rad = r.body_radius_m
    rgb = robot_rgb(r.id)
    meta = [
        fx.KeyValuePair(key='t_s', value=t_text),
        fx.KeyValuePair(key='mode', value=r.mode),
        fx.KeyValuePair(key='target', value='' if r.target is None else str(r.target)),
        fx.KeyValuePair(key='direction', value='' if r.direction is None else str(r.direction)),
    ]
    entity(
        f'robot_{r.id}',
        metadata=meta,
        cylinders=[
            fx.CylinderPrimitive(
                pose=_pose(fx, x, y, 0.025),
                size=fx.Vector3(x=2 * rad, y=2 * rad, z=0.05),
                bottom_scale=1.0,
                top_scale=1.0,
                color=_color(fx, (1.0, 0.2, 0.2) if r.avoiding else rgb, 0.85),
            )
        ],
        arrows=[
            fx.ArrowPrimitive(
                pose=_pose(fx, x, y, 0.07, th),
                shaft_length=1.2 * rad,
                shaft_diameter=0.02,
                head_length=0.05,
                head_diameter=0.05,
                color=_color(fx, rgb),
            )
        ],
        texts=[
            fx.TextPrimitive(
                pose=_pose(fx, x, y + rad + 0.05, 0.15),
                billboard=True,
                font_size=14.0,
                scale_invariant=True,
                color=_color(fx, (0.05, 0.05, 0.05)),
                text=r.label,
            )
        ],
    )
    if r.goal_m is not None:
        gx, gy = float(r.goal_m[0]), float(r.goal_m[1])
        entity(
            f'goal_{r.id}',
            spheres=[
                fx.SpherePrimitive(
                    pose=_pose(fx, gx, gy, 0.02),
                    size=fx.Vector3(x=0.05, y=0.05, z=0.05),
                    color=_color(fx, rgb, 0.8),
                )
            ],
            lines=[
                fx.LinePrimitive(
                    type=fx.LinePrimitiveLineType.LineStrip,
                    thickness=0.005,
                    points=[fx.Point3(x=x, y=y, z=0.02), fx.Point3(x=gx, y=gy, z=0.02)],
                    color=_color(fx, rgb, 0.5),
                )
            ],
        )
    else:
        entity(f'goal_{r.id}')
    if r.avoiding and r.circulation_rad is not None:
        rgb_dir = CCW_RGB if r.direction == 'ccw' else CW_RGB
        tx, ty = float(r.target_m[0]), float(r.target_m[1])
        entity(
            f'avoid_{r.id}',
            arrows=[
                fx.ArrowPrimitive(
                    pose=_pose(fx, x, y, 0.12, r.circulation_rad),
                    shaft_length=2.0 * rad,
                    shaft_diameter=0.025,
                    head_length=0.07,
                    head_diameter=0.07,
                    color=_color(fx, rgb_dir),
                )
            ],
            lines=[
                fx.LinePrimitive(
                    type=fx.LinePrimitiveLineType.LineStrip,
                    thickness=0.006,
                    points=[fx.Point3(x=x, y=y, z=0.12), fx.Point3(x=tx, y=ty, z=0.12)],
                    color=_color(fx, rgb_dir, 0.6),
                )
            ],
        )
    else:
        entity(f'avoid_{r.id}')  # empty: replaces the previous arrow


def _obstacle_entity(fx, entity, o, t_text: str, cache: dict) -> None:
    """obstacle_<name>: its P, L and Q outlines (points cached in ``cache``), P filled, name."""
    cx, cy = float(o.center_m[0]), float(o.center_m[1])
    pose = _pose(fx, cx, cy, 0.0, o.phi_rad)
    lines = []
    for key, (_scale, outline) in o.outlines.items():
        points = cache.get((o.name, key, id(outline)))
        if points is None:
            points = cache[(o.name, key, id(outline))] = [
                fx.Point3(x=float(px), y=float(py), z=0.005) for px, py in outline
            ]
        lines.append(
            fx.LinePrimitive(
                type=fx.LinePrimitiveLineType.LineStrip,
                pose=pose,
                thickness=0.012 if key == 'P' else 0.008,
                points=points,
                color=_color(fx, OUTLINE_RGBA[key][:3], OUTLINE_RGBA[key][3]),
            )
        )
    r1, r2 = (float(v) for v in o.semi_axes_m)
    entity(
        f'obstacle_{o.name}',
        metadata=[fx.KeyValuePair(key='t_s', value=t_text)],
        lines=lines,
        cylinders=[
            fx.CylinderPrimitive(
                pose=_pose(fx, cx, cy, 0.002, o.phi_rad),
                size=fx.Vector3(x=2 * r1, y=2 * r2, z=0.004),
                bottom_scale=1.0,
                top_scale=1.0,
                color=_color(fx, (0.8, 0.1, 0.1), 0.25),
            )
        ],
        texts=[
            fx.TextPrimitive(
                pose=_pose(fx, cx, cy, 0.1),
                billboard=True,
                font_size=13.0,
                scale_invariant=True,
                color=_color(fx, (0.5, 0.05, 0.05)),
                text=o.name,
            )
        ],
    )


def _graph_entity(fx, entity, edges) -> None:
    """graph_edges: one line per edge with an arrowhead half-way, the edges as metadata."""
    edge_points = []
    arrows = []
    for e in edges:
        (ax, ay), (bx, by) = (float(v) for v in e.parent_m), (float(v) for v in e.child_m)
        edge_points += [fx.Point3(x=ax, y=ay, z=0.1), fx.Point3(x=bx, y=by, z=0.1)]
        length = math.hypot(bx - ax, by - ay)
        if length > 1e-6:  # an arrowhead half-way, pointing at the child
            arrows.append(
                fx.ArrowPrimitive(
                    pose=_pose(
                        fx, 0.5 * (ax + bx), 0.5 * (ay + by), 0.1, math.atan2(by - ay, bx - ax)
                    ),
                    shaft_length=0.001,
                    shaft_diameter=0.001,
                    head_length=0.06,
                    head_diameter=0.05,
                    color=_color(fx, (0.1, 0.1, 0.1), 0.8),
                )
            )
    entity(
        'graph_edges',
        lines=[
            fx.LinePrimitive(
                type=fx.LinePrimitiveLineType.LineList,
                thickness=0.012,
                points=edge_points,
                color=_color(fx, (0.1, 0.1, 0.1), 0.8),
            )
        ]
        if edge_points
        else [],
        arrows=arrows,
        metadata=[
            fx.KeyValuePair(key='edges', value=json.dumps([[e.parent, e.child] for e in edges]))
        ],
    )


def scene_update(scene: Scene, stamp_ns: int, cache: dict | None = None):
    """Foxglove SceneUpdate of a core Scene (entities keep their ids from update to update, so each
    update replaces the previous one; ids: robot_<id>, goal_<id>, avoid_<id>, obstacle_<name>,
    graph_edges). Robot entities carry metadata t_s, mode, target, direction. ``cache``: a dict
    kept by the caller for the obstacle outlines' points (fixed in the obstacle frame).
    """
    fx = _fx()
    cache = {} if cache is None else cache
    ts = fx.Timestamp(sec=int(stamp_ns // 1_000_000_000), nsec=int(stamp_ns % 1_000_000_000))
    t_text = '' if scene.t_s is None else f'{scene.t_s:.3f}'
    entities = []

    def entity(eid: str, **kw):
        entities.append(fx.SceneEntity(timestamp=ts, frame_id=WORLD_FRAME, id=eid, **kw))

    for r in scene.robots:
        _robot_entities(fx, entity, r, t_text)
    for o in scene.obstacles:
        _obstacle_entity(fx, entity, o, t_text, cache)
    _graph_entity(fx, entity, scene.edges)
    return fx.SceneUpdate(entities=entities)


def jpeg_of(msg: Image, quality: int) -> bytes:
    """JPEG bytes of a sensor_msgs/Image (mono, BGR or RGB, 8 or 16 bit; ValueError otherwise)."""
    import cv2

    from ament_formation.ros.image import image_to_mono8, image_to_numpy

    if msg.encoding in ('mono8', '8UC1', 'bgr8', '8UC3'):
        pixels = image_to_numpy(msg)
    elif msg.encoding == 'rgb8':
        pixels = cv2.cvtColor(np.ascontiguousarray(image_to_numpy(msg)), cv2.COLOR_RGB2BGR)
    else:
        pixels = image_to_mono8(msg)
    ok, buf = cv2.imencode(
        '.jpg', np.ascontiguousarray(pixels), [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    )
    if not ok:
        raise ValueError('cv2.imencode failed')
    return buf.tobytes()


# ------------------------------------------------------------------------------ layout
LAYOUT_ROBOT_IDS = tuple(range(6))  # config/foxglove/formation_layout.json plots robots 0..5


def _layout_series(field: str, label: str, rid: int) -> dict:
    """A Plot panel's path: robot ``rid``'s series ``field`` in the robot's colour."""
    return {
        'value': f'{SERIES_TOPIC.format(id=rid)}.{field}',
        'enabled': True,
        'timestampMethod': 'receiveTime',
        'label': label,
        'color': '#{:02x}{:02x}{:02x}'.format(*(int(255 * c) for c in robot_rgb(rid))),
    }


def _layout_plot(title: str, paths: list[dict], y_label: str) -> dict:
    """A Plot panel of ``paths`` against time."""
    return {
        'foxglovePanelTitle': title,
        'paths': paths,
        'xAxisVal': 'timestamp',
        'showLegend': True,
        'legendDisplay': 'floating',
        'showXAxisLabels': True,
        'showYAxisLabels': True,
        'isSynced': True,
        'yAxisLabel': y_label,
        'timeWindowMode': 'automatic',
    }


def _layout_3d_panel() -> dict:
    """The 3D panel: top-down on the arena, /formation/scene, a grid."""
    return {
        'foxglovePanelTitle': 'arena (world frame, top-down)',
        'cameraState': {
            'perspective': False,
            'distance': 5.0,
            'phi': 0.0,
            'thetaOffset': 90.0,
            'target': [1.0, 0.6, 0.0],
            'targetOffset': [0.0, 0.0, 0.0],
            'targetOrientation': [0.0, 0.0, 0.0, 1.0],
            'fovy': 45.0,
            'near': 0.01,
            'far': 5000.0,
        },
        'followMode': 'follow-none',
        'followTf': WORLD_FRAME,
        'scene': {'enableStats': False},
        'transforms': {},
        'topics': {SCENE_TOPIC: {'visible': True}},
        'layers': {
            'grid': {
                'visible': True,
                'layerId': 'foxglove.Grid',
                'frameId': WORLD_FRAME,
                'size': 6.0,
                'divisions': 30,
                'lineWidth': 1.0,
                'color': '#24242440',
                'position': [1.0, 0.5, 0.0],
                'rotation': [0.0, 0.0, 0.0],
                'order': 1,
            }
        },
    }


def _layout_image_panel() -> dict:
    """The Image panel of the overhead camera."""
    return {
        'foxglovePanelTitle': 'overhead camera',
        'imageMode': {'imageTopic': IMAGE_TOPIC},
        'cameraState': {
            'distance': 20.0,
            'perspective': True,
            'phi': 60.0,
            'target': [0.0, 0.0, 0.0],
            'targetOffset': [0.0, 0.0, 0.0],
            'targetOrientation': [0.0, 0.0, 0.0, 1.0],
            'thetaOffset': 45.0,
            'fovy': 45.0,
            'near': 0.5,
            'far': 5000.0,
        },
        'followMode': 'follow-pose',
        'scene': {},
        'transforms': {},
        'topics': {},
        'layers': {},
    }


def _layout_mosaic() -> dict:
    """Where the panels go: the 3D panel on the left, the image and the three plots stacked."""
    return {
        'direction': 'row',
        'splitPercentage': 55,
        'first': '3D!formation',
        'second': {
            'direction': 'column',
            'splitPercentage': 34,
            'first': 'Image!camera',
            'second': {
                'direction': 'column',
                'splitPercentage': 33,
                'first': 'Plot!formation_error',
                'second': {
                    'direction': 'column',
                    'splitPercentage': 50,
                    'first': 'Plot!clearance',
                    'second': 'Plot!torques',
                },
            },
        },
    }


def foxglove_layout(robot_ids=LAYOUT_ROBOT_IDS) -> dict:
    """A Foxglove layout (the app's "Import from file" JSON: configById + mosaic) with the 3D panel
    (top-down on the arena, /formation/scene), the Image panel (/camera/image/compressed) and three
    Plot panels of the series of ``robot_ids``: formation error, clearance, wheel torques.
    config/foxglove/formation_layout.json is this for robots 0..5 (test_live_view keeps them
    equal).
    """
    torque_paths = []
    for rid in robot_ids:
        torque_paths += [
            _layout_series('torque_left_nm', f'robot {rid} left', rid),
            {
                **_layout_series('torque_right_nm', f'robot {rid} right', rid),
                'lineStyle': 'dashed',
            },
        ]
    return {
        'configById': {
            '3D!formation': _layout_3d_panel(),
            'Image!camera': _layout_image_panel(),
            'Plot!formation_error': _layout_plot(
                'formation error |p - g| [m]',
                [_layout_series('formation_error_m', f'robot {rid}', rid) for rid in robot_ids],
                'm',
            ),
            'Plot!clearance': _layout_plot(
                'clearance to the nearest P [m] (< 0 inside)',
                [_layout_series('clearance_m', f'robot {rid}', rid) for rid in robot_ids],
                'm',
            ),
            'Plot!torques': _layout_plot('wheel torques [N m]', torque_paths, 'N m'),
        },
        'globalVariables': {},
        'userNodes': {},
        'playbackConfig': {'speed': 1.0},
        'layout': _layout_mosaic(),
    }


# ------------------------------------------------------------------------------ node
class LiveViewNode(Node):
    """See the module docstring."""

    def __init__(self, *, context=None, params: LiveViewParams | None = None, **node_kw):
        super().__init__('formation_live_view', context=context, **node_kw)
        self.prm = params if params is not None else declare_dataclass(self, LiveViewParams)
        self.scenario = load_scenario(self.prm.scenario)
        self.live = LiveScene(self.scenario)
        self.ids = self.scenario.robot_ids
        self._raw_states: dict[int, bytes] = {}
        self._states: dict[int, np.ndarray] = {}
        self._raw_torques: dict[int, bytes] = {}
        self._torques: dict[int, np.ndarray] = {}
        self.modes: dict[int, dict] = {}
        self.graph: msgs.GraphMessage | None = None
        self.parents: dict = {}
        self.start_s: float | None = None
        self.sent = {'scene': 0, 'image': 0, 'series': 0, 'status': 0}
        kinds = ('graph', 'mode', 'state', 'torque', 'image')
        self.rejections = diag.Rejections(kinds, time.monotonic)
        self.rejected = self.rejections.counts  # kind -> count, reported as 'inputs'
        self._last_image_s = -math.inf
        self._groups: dict[str, list] = {'robots': [], 'torques': [], 'image': []}
        self._outline_points: dict = {}  # foxglove points of the obstacle outlines, made once

        import foxglove
        from foxglove.channels import CompressedImageChannel, SceneUpdateChannel
        from foxglove.websocket import Capability

        self.fox = foxglove.Context()  # this node's channels only (tests host several)
        try:
            self.server = foxglove.start_server(
                name=f'ament_formation {self.scenario.name}',
                host=self.prm.host,
                port=self.prm.port,
                capabilities=[Capability.Time],
                context=self.fox,
            )
        except RuntimeError as err:
            raise ConfigError(
                f'cannot serve on {self.prm.host}:{self.prm.port} ({err})', 'port'
            ) from None
        self.port = self.server.port
        self.ch_scene = SceneUpdateChannel(SCENE_TOPIC, context=self.fox)
        self.ch_image = (
            CompressedImageChannel(IMAGE_TOPIC, context=self.fox)
            if self.prm.image_rate_hz > 0
            else None
        )
        series_schema = foxglove.Schema(
            name=SERIES_SCHEMA['title'],
            encoding='jsonschema',
            data=json.dumps(SERIES_SCHEMA).encode(),
        )
        self.ch_series = {
            rid: foxglove.Channel(
                SERIES_TOPIC.format(id=rid),
                schema=series_schema,
                message_encoding='json',
                context=self.fox,
            )
            for rid in self.ids
        }
        self.ch_status = foxglove.Channel(
            STATUS_TOPIC,
            message_encoding='json',
            context=self.fox,
            schema=foxglove.Schema(
                name=STATUS_SCHEMA['title'],
                encoding='jsonschema',
                data=json.dumps(STATUS_SCHEMA).encode(),
            ),
        )

        self.create_subscription(String, '/formation/graph', self._on_graph, QOS_GRAPH)
        self.create_timer(1.0 / self.prm.scene_rate_hz, self._publish_scene)
        self.create_timer(1.0 / self.prm.series_rate_hz, self._publish_series)
        self.create_timer(1.0, self._publish_status)
        self.create_timer(0.25, self._update_subscriptions)
        self.diag = diag.Diagnostics(self)
        self.diag.add('server', self._server_status)
        self.diag.add('inputs', self.rejections.status)
        where = (
            'this machine only'
            if is_loopback(self.prm.host)
            else 'THE NETWORK (no authentication)'
        )
        self.get_logger().info(
            f'live view: ws://{self.prm.host}:{self.port} ({where}); open it in Foxglove '
            'as a Foxglove WebSocket connection, layout config/foxglove/formation_layout.json'
        )

    # ------------------------------------------------------------------ time
    def now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def scenario_time_s(self, now_ns: int) -> float | None:
        return scenario_time_s(now_ns * 1e-9, self.start_s)

    # ------------------------------------------------------------------ subscriptions on demand
    def _wanted(self) -> dict[str, bool]:
        series = any(ch.has_sinks() for ch in self.ch_series.values())
        return {
            'robots': series or self.ch_scene.has_sinks() or self.ch_status.has_sinks(),
            'torques': series,
            'image': self.ch_image is not None and self.ch_image.has_sinks(),
        }

    def _update_subscriptions(self) -> None:
        """Subscribe to what some Foxglove client shows, and drop what nobody shows any more."""
        for group, want in self._wanted().items():
            subs = self._groups[group]
            if want and not subs:
                subs.extend(self._subscribe(group))
                self.get_logger().info(f'a Foxglove client shows {group}: subscribed')
            elif not want and subs:
                for sub in subs:
                    self.destroy_subscription(sub)
                subs.clear()
                if group == 'torques':  # what is no longer heard is not shown as current later
                    self._raw_torques.clear()
                    self._torques.clear()
                elif group == 'robots':
                    self._raw_states.clear()
                    self._states.clear()
                    self.modes.clear()
                self.get_logger().info(f'no Foxglove client shows {group} any more: unsubscribed')

    def _subscribe(self, group: str) -> list:
        if group == 'robots':
            subs = []
            for rid in self.ids:
                subs.append(
                    self.create_subscription(
                        msgs.Odometry,
                        f'/robot_{rid}/state',
                        lambda m, rid=rid: self._raw_states.__setitem__(rid, m),
                        QOS_CONTROL,
                        raw=True,
                    )
                )
                subs.append(
                    self.create_subscription(
                        String,
                        f'/robot_{rid}/mode',
                        lambda m, rid=rid: self._on_mode(rid, m),
                        QOS_CONTROL,
                    )
                )
            return subs
        if group == 'torques':
            return [
                self.create_subscription(
                    JointState,
                    f'/robot_{rid}/wheel_torque',
                    lambda m, rid=rid: self._raw_torques.__setitem__(rid, m),
                    QOS_CONTROL,
                    raw=True,
                )
                for rid in self.ids
            ]
        return [
            self.create_subscription(
                Image, self.prm.image_topic, self._on_image, QOS_IMAGE, raw=True
            )
        ]

    # ------------------------------------------------------------------ diagnostics
    def _reject(self, kind: str) -> None:
        self.rejections.counts[kind] += 1
        self.diag.changed()  # the first of a flood is published at once

    def _server_status(self) -> tuple[int, str, dict]:
        shown = sorted(g for g, subs in self._groups.items() if subs)
        values = {
            'url': f'ws://{self.prm.host}:{self.port}',
            'shown': ' '.join(shown) or 'nothing',
            **{f'sent_{k}': v for k, v in self.sent.items()},
        }
        where = '' if is_loopback(self.prm.host) else ' to the network (no authentication)'
        return diag.OK, f'serving{where}' + ('' if shown else ', nothing shown'), values

    # ------------------------------------------------------------------ inputs
    @property
    def states(self) -> dict[int, np.ndarray]:
        """Every heard robot's newest finite state (5,)
        (decoded here, when a publisher reads it).
        """
        for rid, raw in self._raw_states.items():
            state, _ = msgs.state_from_odometry(deserialize_message(raw, msgs.Odometry))
            if np.all(np.isfinite(state)):
                self._states[rid] = state
            else:
                self._reject('state')
        self._raw_states.clear()
        return self._states

    @property
    def torques(self) -> dict[int, np.ndarray]:
        """Every robot's newest finite commanded torques, each (2,) [left, right] N m."""
        for rid, raw in self._raw_torques.items():
            try:
                tau, _ = msgs.torque_from_msg(deserialize_message(raw, JointState))
            except ValueError:
                self._reject('torque')
                continue
            if np.all(np.isfinite(tau)):
                self._torques[rid] = tau
            else:
                self._reject('torque')
        self._raw_torques.clear()
        return self._torques

    def _on_graph(self, msg: String) -> None:
        try:
            graph = msgs.graph_from_msg(msg)
        except ValueError as err:
            self._reject('graph')
            self.get_logger().warn(f'/formation/graph: {err}', throttle_duration_sec=5.0)
            return
        if self.graph is not None and graph.revision < self.graph.revision:
            return
        changed = (
            self.graph is None
            or graph.revision != self.graph.revision
            or graph.start_s != self.start_s
        )
        self.graph = graph
        self.parents = dict(graph.parents)
        if graph.start_s is not None:
            self.start_s = graph.start_s
        if changed:
            self._publish_status()

    def _on_mode(self, rid: int, msg: String) -> None:
        try:
            self.modes[rid] = msgs.mode_from_msg(msg)
        except ValueError as err:
            self._reject('mode')
            self.get_logger().warn(f'robot_{rid}/mode: {err}', throttle_duration_sec=5.0)

    def _on_image(self, raw: bytes) -> None:
        """Throttle to image_rate_hz before decoding anything: a skipped frame costs a
        copy only.
        """
        now_s = time.monotonic()
        if now_s - self._last_image_s < 1.0 / self.prm.image_rate_hz * 0.95:
            return
        self._last_image_s = now_s
        msg = deserialize_message(raw, Image)
        try:
            data = jpeg_of(msg, self.prm.jpeg_quality)
        except ValueError as err:
            self._reject('image')
            self.get_logger().warn(f'{self.prm.image_topic}: {err}', throttle_duration_sec=5.0)
            return
        from foxglove.messages import CompressedImage, Timestamp

        stamp = msg.header.stamp
        self.ch_image.log(
            CompressedImage(
                timestamp=Timestamp(sec=stamp.sec, nsec=stamp.nanosec),
                frame_id=msg.header.frame_id or 'camera',
                data=data,
                format='jpeg',
            ),
            log_time=msgs.stamp_to_ns(stamp) or self.now_ns(),
        )
        self.sent['image'] += 1

    # ------------------------------------------------------------------ output
    def _publish_scene(self) -> None:
        now = self.now_ns()
        if now <= 0:  # simulated time not started yet
            return
        self.server.broadcast_time(now)
        if not self.ch_scene.has_sinks():
            return
        scene = self.live.scene(self.scenario_time_s(now), self.states, self.modes, self.parents)
        self.ch_scene.log(scene_update(scene, now, self._outline_points), log_time=now)
        self.sent['scene'] += 1

    def _publish_series(self) -> None:
        now = self.now_ns()
        if now <= 0 or not any(ch.has_sinks() for ch in self.ch_series.values()):
            return
        t_s = self.scenario_time_s(now)
        for rid, values in self.live.series(t_s, self.states, self.torques).items():
            mode = self.modes.get(rid) or {}
            sample = {
                't_s': finite_or_none(t_s),
                **{
                    k: (finite_or_none(v) if not isinstance(v, str) else v)
                    for k, v in values.items()
                },
                'avoiding': int(bool(mode.get('avoiding', False))),
                'mode': mode.get('mode'),
            }
            self.ch_series[rid].log(sample, log_time=now)
            self.sent['series'] += 1

    def _publish_status(self) -> None:
        now = self.now_ns()
        if now <= 0 or not self.ch_status.has_sinks():
            return
        g = self.graph
        self.ch_status.log(
            {
                't_s': finite_or_none(self.scenario_time_s(now)),
                'start_s': self.start_s,
                'revision': 0 if g is None else g.revision,
                'parents': {str(k): v for k, v in sorted(self.parents.items())},
                'avoiding': [] if g is None else list(g.avoiding),
                'modes': {str(k): v for k, v in sorted(self.modes.items())},
            },
            log_time=now,
        )
        self.sent['status'] += 1

    # ------------------------------------------------------------------ shutdown
    def destroy_node(self):
        server = getattr(self, 'server', None)
        if server is not None:
            server.stop()
            self.server = None
        return super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node('formation_live_view', LiveViewNode, args)


if __name__ == '__main__':
    sys.exit(main())
