"""Conversions between standard ROS messages and the core's arrays (docs/design.md §6).

Every function is pure: message in, numpy/dict out (or the reverse). Units are SI, frames are the
world frame unless the name says otherwise; state rows are [x_m, y_m, theta_rad, v_mps,
omega_radps] with (x, y) the controlled point p (spec S2.1).

Topics (type): helpers

- robot_<id>/pose (geometry_msgs/PoseStamped): pose_stamped, pose_from_msg
- robot_<id>/state, truth (nav_msgs/Odometry): odometry, state_from_odometry
- robot_<id>/accel (geometry_msgs/AccelStamped): accel_stamped, accel_from_msg
- robot_<id>/wheel_* (sensor_msgs/JointState): wheel_torque, torque_from_msg, wheel_state,
  wheel_state_from_msg
- robot_<id>/mode (std_msgs/String (JSON mode/v1)): mode_msg, mode_from_msg
- /formation/graph (std_msgs/String (JSON graph/v1)): graph_msg, graph_from_msg (GraphMessage)
- /formation/encounters (std_msgs/String (JSON encounters/v2)): encounters_msg,
  encounters_from_msg
- /formation/markers (visualization_msgs/MarkerArray): robot_markers, ellipse_markers,
  edge_markers, delete_all_marker, marker_array
- /camera/image_raw (sensor_msgs/Image (mono8)): image_mono8, array_from_image
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import AccelStamped, Point, PoseStamped
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import ColorRGBA, String
from visualization_msgs.msg import Marker, MarkerArray

from ament_formation.core.model.ellipse import ellipse_outline
from ament_formation.core.sim.scene import robot_rgb
from ament_formation.ros import payloads

WORLD_FRAME = 'world'
WHEEL_NAMES = ('left_wheel', 'right_wheel')
_NS_PER_S = 1_000_000_000


# --------------------------------------------------------------------------- time
def stamp_from_s(t_s: float) -> Time:
    """builtin_interfaces/Time for ``t_s`` [s] (non-negative; rounded to the nanosecond)."""
    if not math.isfinite(t_s) or t_s < 0.0:
        raise ValueError(f't_s: must be a finite time >= 0 s (got {t_s!r})')
    ns = int(round(t_s * _NS_PER_S))
    return Time(sec=ns // _NS_PER_S, nanosec=ns % _NS_PER_S)


def stamp_from_ns(t_ns: int) -> Time:
    """builtin_interfaces/Time for ``t_ns`` [ns]."""
    return Time(sec=int(t_ns) // _NS_PER_S, nanosec=int(t_ns) % _NS_PER_S)


def stamp_to_s(stamp: Time) -> float:
    """Seconds [s] of a builtin_interfaces/Time."""
    return stamp.sec + stamp.nanosec * 1e-9


def stamp_to_ns(stamp: Time) -> int:
    """Nanoseconds [ns] of a builtin_interfaces/Time."""
    return stamp.sec * _NS_PER_S + stamp.nanosec


def duration_from_s(d_s: float) -> Duration:
    """builtin_interfaces/Duration for ``d_s`` >= 0 [s]."""
    ns = int(round(max(0.0, d_s) * _NS_PER_S))
    return Duration(sec=ns // _NS_PER_S, nanosec=ns % _NS_PER_S)


# --------------------------------------------------------------------------- yaw
def yaw_to_quaternion(theta_rad: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by ``theta_rad`` about +z."""
    half = 0.5 * float(theta_rad)
    return 0.0, 0.0, math.sin(half), math.cos(half)


def quaternion_to_yaw(x: float, y: float, z: float, w: float) -> float:
    """Yaw [rad] in (-pi, pi] of a quaternion (x, y, z, w) (any roll/pitch is discarded)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


# --------------------------------------------------------------------------- pose
def pose_stamped(pose_xyt, stamp: Time, frame_id: str = WORLD_FRAME) -> PoseStamped:
    """A PoseStamped from ``pose_xyt`` (3,) [x_m, y_m, theta_rad] of the controlled point."""
    x, y, th = (float(v) for v in pose_xyt)
    msg = PoseStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.pose.position.x = x
    msg.pose.position.y = y
    q = msg.pose.orientation
    q.x, q.y, q.z, q.w = yaw_to_quaternion(th)
    return msg


def pose_from_msg(msg: PoseStamped) -> tuple[np.ndarray, float]:
    """((3,) [x_m, y_m, theta_rad], stamp [s]) from a PoseStamped."""
    p, q = msg.pose.position, msg.pose.orientation
    return (
        np.array([p.x, p.y, quaternion_to_yaw(q.x, q.y, q.z, q.w)]),
        stamp_to_s(msg.header.stamp),
    )


# --------------------------------------------------------------------------- odometry
def odometry(
    state,
    stamp: Time,
    child_frame_id: str,
    frame_id: str = WORLD_FRAME,
    out: Odometry | None = None,
) -> Odometry:
    """Odometry from ``state`` (5,) [x_m, y_m, theta_rad, v_mps, omega_radps].

    Pose = controlled point p and heading; twist (body frame, REP 105) = (v, 0, 0), (0, 0, omega)
    with v the axle-midpoint speed; followers recompute p-dot from (theta, v, omega) and d (S2.2).
    ``out``: a message this function filled before (same frames), refilled instead of building a
    new one (a publisher at 100 Hz; rclpy serializes at publish, so reuse is safe).
    """
    x, y, th, v, w = map(float, state)
    if out is None:
        msg = Odometry()
        msg.header.frame_id = frame_id
        msg.child_frame_id = child_frame_id
    else:
        msg = out
    msg.header.stamp = stamp
    msg.pose.pose.position.x = x
    msg.pose.pose.position.y = y
    q = msg.pose.pose.orientation
    q.x, q.y, q.z, q.w = yaw_to_quaternion(th)
    msg.twist.twist.linear.x = v
    msg.twist.twist.angular.z = w
    return msg


def state_from_odometry(msg: Odometry) -> tuple[np.ndarray, float]:
    """((5,) [x_m, y_m, theta_rad, v_mps, omega_radps], stamp [s]) from an Odometry."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    t = msg.twist.twist
    return (
        np.array([p.x, p.y, quaternion_to_yaw(q.x, q.y, q.z, q.w), t.linear.x, t.angular.z]),
        stamp_to_s(msg.header.stamp),
    )


# --------------------------------------------------------------------------- accel
def accel_stamped(
    accel_mps2, stamp: Time, frame_id: str = WORLD_FRAME, out: AccelStamped | None = None
) -> AccelStamped:
    """An AccelStamped carrying the commanded point acceleration a_j (2,) [m/s^2, world] (S4).
    ``out``: refill this message (built here before) instead of a new one.
    """
    if out is None:
        msg = AccelStamped()
        msg.header.frame_id = frame_id
    else:
        msg = out
    msg.header.stamp = stamp
    msg.accel.linear.x = float(accel_mps2[0])
    msg.accel.linear.y = float(accel_mps2[1])
    return msg


def accel_from_msg(msg: AccelStamped) -> tuple[np.ndarray, float]:
    """((2,) [m/s^2], stamp [s]) from an AccelStamped."""
    return np.array([msg.accel.linear.x, msg.accel.linear.y]), stamp_to_s(msg.header.stamp)


# --------------------------------------------------------------------------- wheels
def wheel_torque(torque_nm, stamp: Time, out: JointState | None = None) -> JointState:
    """A JointState with effort = (2,) [left, right] wheel torques [N m].
    ``out``: refill this message (built here before) instead of a new one.
    """
    if out is None:
        msg = JointState()
        msg.name = list(WHEEL_NAMES)
    else:
        msg = out
    msg.header.stamp = stamp
    msg.effort = [float(torque_nm[0]), float(torque_nm[1])]
    return msg


def torque_from_msg(msg: JointState) -> tuple[np.ndarray, float]:
    """((2,) [left, right] N m, stamp [s]); raises ValueError unless exactly two efforts."""
    if len(msg.effort) != 2:
        raise ValueError(f'effort: expected 2 values [left, right] (got {len(msg.effort)})')
    return np.array(msg.effort, dtype=float), stamp_to_s(msg.header.stamp)


def wheel_state(position_rad, velocity_radps, stamp: Time) -> JointState:
    """A JointState with (2,) [left, right] wheel angles [rad] and rates [rad/s]."""
    msg = JointState()
    msg.header.stamp = stamp
    msg.name = list(WHEEL_NAMES)
    msg.position = [float(position_rad[0]), float(position_rad[1])]
    msg.velocity = [float(velocity_radps[0]), float(velocity_radps[1])]
    return msg


def wheel_state_from_msg(msg: JointState) -> tuple[np.ndarray, np.ndarray, float]:
    """((2,) angles [rad], (2,) rates [rad/s], stamp [s]); ValueError unless two of each."""
    if len(msg.position) != 2 or len(msg.velocity) != 2:
        raise ValueError(
            'position/velocity: expected 2 values each [left, right] '
            f'(got {len(msg.position)}, {len(msg.velocity)})'
        )
    return (
        np.array(msg.position, dtype=float),
        np.array(msg.velocity, dtype=float),
        stamp_to_s(msg.header.stamp),
    )


# --------------------------------------------------------------------------- JSON strings
# Versioned JSON payloads (ros/payloads.py, docs/schemas/): every receiver validates; a bad
# payload raises ValueError (payloads.PayloadError) for the node to count, never anything else.
def mode_msg(
    mode: str, target: str | int | None = None, direction: str | None = None, **extra
) -> String:
    """std_msgs/String JSON ament_formation/mode/v1 {"schema", "mode", "target", "direction", ...}
    for robot_<id>/mode (``extra``: more members, e.g. ``avoiding``).
    """
    return String(
        data=payloads.encode(
            {
                **extra,
                'schema': payloads.MODE_V1,
                'mode': mode,
                'target': target,
                'direction': direction,
            }
        )
    )


def mode_from_msg(msg: String) -> dict:
    """The mode dictionary (without its "schema" member); ValueError unless it follows
    ament_formation/mode/v1.
    """
    data = payloads.decode(msg.data, payloads.MODE_V1)
    data.pop('schema')
    return data


@dataclass(frozen=True)
class GraphMessage:
    """Decoded /formation/graph: revision, parent of each robot (None = root), offsets delta [m],
    the robots avoiding, when it was made [s, ROS time] and the mission start ``start_s`` [s, ROS
    time] (None until the coordinator has started the mission; scenario time t = now - start_s).
    """

    revision: int
    parents: dict[int, int | None]
    offsets_m: dict[int, tuple[float, float]] = field(default_factory=dict)
    avoiding: tuple[int, ...] = ()
    stamp_s: float = 0.0
    start_s: float | None = None


def graph_msg(graph: GraphMessage) -> String:
    """std_msgs/String JSON ament_formation/graph/v1 of a GraphMessage
    (integer keys as strings).
    """
    return String(
        data=payloads.encode(
            {
                'schema': payloads.GRAPH_V1,
                'revision': int(graph.revision),
                'parents': {
                    str(k): (None if v is None else int(v))
                    for k, v in sorted(graph.parents.items())
                },
                'offsets_m': {
                    str(k): [float(v[0]), float(v[1])] for k, v in sorted(graph.offsets_m.items())
                },
                'avoiding': sorted(int(a) for a in graph.avoiding),
                'stamp_s': float(graph.stamp_s),
                'start_s': None if graph.start_s is None else float(graph.start_s),
            }
        )
    )


def graph_from_msg(msg: String) -> GraphMessage:
    """A GraphMessage from the JSON; ValueError naming the member unless it follows
    ament_formation/graph/v1.
    """
    data = payloads.decode(msg.data, payloads.GRAPH_V1)
    return GraphMessage(
        data['revision'],
        {int(k): v for k, v in data['parents'].items()},
        {int(k): (float(v[0]), float(v[1])) for k, v in data['offsets_m'].items()},
        tuple(data['avoiding']),
        float(data['stamp_s']),
        None if data['start_s'] is None else float(data['start_s']),
    )


@dataclass(frozen=True)
class EncountersMessage:
    """Decoded /formation/encounters (encounters/v2): revision, {robot id: assignment dict},
    {leader id: progress rate target}, ``stamp_s`` [s, the coordinator's ROS time] and
    ``mission_end_s`` [s, scenario time] (None before the mission ends).
    """

    revision: int
    assignments: dict
    rates: dict
    stamp_s: float
    mission_end_s: float | None = None


def encounters_msg(m: EncountersMessage) -> String:
    """std_msgs/String JSON ament_formation/encounters/v2 of the coordinator's decision
    (assignment dicts as core/control/coordinator.py makes them).
    """
    def one(a: dict) -> dict:
        park = a.get('park_at_s')
        return {
            'mode': a['mode'],
            'partner': int(a['partner']),
            'direction': float(a['direction']),
            't_entry_s': float(a['t_entry_s']),
            'drift_mps': None if a['drift_mps'] is None else [float(v) for v in a['drift_mps']],
            'park_at_s': None if park is None or not math.isfinite(park) else float(park),
        }

    return String(data=payloads.encode({
        'schema': payloads.ENCOUNTERS_V2,
        'revision': int(m.revision),
        'stamp_s': float(m.stamp_s),
        'assignments': {str(k): one(a) for k, a in sorted(m.assignments.items())},
        'rates': {str(k): float(v) for k, v in sorted(m.rates.items())},
        'mission_end_s': None if m.mission_end_s is None else float(m.mission_end_s),
    }))


def encounters_from_msg(msg: String) -> EncountersMessage:
    """An :class:`EncountersMessage`; ValueError naming the problem unless it follows
    ament_formation/encounters/v2.
    """
    data = payloads.decode(msg.data, payloads.ENCOUNTERS_V2)
    assignments = {}
    for k, a in data['assignments'].items():
        park = a['park_at_s']
        assignments[int(k)] = {**a, 'park_at_s': -math.inf if park is None else float(park)}
    rates = {int(k): float(v) for k, v in data['rates'].items()}
    end = data['mission_end_s']
    return EncountersMessage(data['revision'], assignments, rates, float(data['stamp_s']),
                             None if end is None else float(end))


# --------------------------------------------------------------------------- image
def image_mono8(pixels: np.ndarray, stamp: Time, frame_id: str = 'camera') -> Image:
    """sensor_msgs/Image (mono8) from a (H, W) uint8 array."""
    if pixels.ndim != 2 or pixels.dtype != np.uint8:
        raise ValueError(
            f'pixels: expected a (H, W) uint8 array (got {pixels.shape} {pixels.dtype})'
        )
    msg = Image()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.height, msg.width = pixels.shape
    msg.encoding = 'mono8'
    msg.is_bigendian = 0
    msg.step = pixels.shape[1]
    msg.data = np.ascontiguousarray(pixels).tobytes()
    return msg


def array_from_image(msg: Image) -> np.ndarray:
    """(H, W) uint8 view of a mono8 Image (ValueError for other encodings or a bad size)."""
    if msg.encoding != 'mono8':
        raise ValueError(f'encoding: expected mono8 (got {msg.encoding!r})')
    buf = np.frombuffer(
        bytes(msg.data) if not isinstance(msg.data, (bytes, bytearray, memoryview)) else msg.data,
        dtype=np.uint8,
    )
    if buf.size != msg.step * msg.height or msg.step < msg.width:
        raise ValueError(
            f'data: {buf.size} bytes do not match step {msg.step} x height {msg.height}'
        )
    return buf.reshape(msg.height, msg.step)[:, : msg.width]


# --------------------------------------------------------------------------- markers
def _color(rgba) -> ColorRGBA:
    r, g, b, a = (float(c) for c in rgba)
    return ColorRGBA(r=r, g=g, b=b, a=a)


def robot_color(robot_id: int, alpha: float = 1.0) -> ColorRGBA:
    """A stable colour per robot id."""
    return _color((*robot_rgb(robot_id), alpha))


def _marker(
    ns: str, mid: int, mtype: int, stamp: Time, frame_id: str, lifetime_s: float = 0.0
) -> Marker:
    m = Marker()
    m.header.stamp = stamp
    m.header.frame_id = frame_id
    m.ns = ns
    m.id = int(mid)
    m.type = mtype
    m.action = Marker.ADD
    m.pose.orientation.w = 1.0
    m.lifetime = duration_from_s(lifetime_s)
    return m


def delete_all_marker(stamp: Time, frame_id: str = WORLD_FRAME) -> Marker:
    """A DELETEALL marker: put first in an array, the viewer drops every marker it holds from
    this topic before drawing the rest of the array (a new layout: no stale object survives).
    """
    m = Marker()
    m.header.stamp = stamp
    m.header.frame_id = frame_id
    m.action = Marker.DELETEALL
    return m


def robot_markers(
    robot_ids,
    states,
    body_radius_m,
    stamp: Time,
    avoiding=None,
    frame_id: str = WORLD_FRAME,
    lifetime_s: float = 0.0,
) -> list[Marker]:
    """Per robot a disc (CYLINDER, radius R_body; ns ``robots``) and a heading ARROW (ns
    ``headings``), marker id = robot id.

    ``states`` (N, 5) rows [x_m, y_m, theta_rad, ...]; ``body_radius_m`` scalar or (N,);
    ``avoiding`` (N,) bool makes the disc translucent while avoiding; ``lifetime_s`` > 0: the
    viewer removes a robot not re-sent within that time [s] (0: kept until replaced or deleted).
    """
    states = np.asarray(states, dtype=float).reshape(-1, 5)
    radius = np.broadcast_to(np.asarray(body_radius_m, dtype=float), (len(states),))
    out = []
    for k, rid in enumerate(robot_ids):
        x, y, th = states[k, :3]
        disc = _marker('robots', rid, Marker.CYLINDER, stamp, frame_id, lifetime_s)
        disc.pose.position.x, disc.pose.position.y = float(x), float(y)
        disc.scale.x = disc.scale.y = 2.0 * float(radius[k])
        disc.scale.z = 0.05
        disc.color = robot_color(rid, 0.5 if (avoiding is not None and avoiding[k]) else 0.9)
        arrow = _marker('headings', rid, Marker.ARROW, stamp, frame_id, lifetime_s)
        arrow.points = [
            Point(x=float(x), y=float(y), z=0.06),
            Point(
                x=float(x + 1.5 * radius[k] * math.cos(th)),
                y=float(y + 1.5 * radius[k] * math.sin(th)),
                z=0.06,
            ),
        ]
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.02, 0.04, 0.04
        arrow.color = robot_color(rid)
        out.append(disc)
        out.append(arrow)
    return out


def ellipse_points(center_m, phi_rad: float, semi_axes_m, n: int = 48) -> np.ndarray:
    """(n + 1, 2) closed polyline of the ellipse (centre, orientation, (r1, r2)) [m, world]."""
    local = ellipse_outline(semi_axes_m, n)
    c, s = math.cos(phi_rad), math.sin(phi_rad)
    rot = np.array([[c, -s], [s, c]])
    return local @ rot.T + np.asarray(center_m, dtype=float)


def ellipse_markers(
    names, centers_m, phis_rad, semi_axes_m, scales, stamp: Time, frame_id: str = WORLD_FRAME
) -> list[Marker]:
    """LINE_STRIP per obstacle and scale: P (scale 1), L (rho_L) and Q (kappa) (S6.1).

    ``centers_m`` (M, 2), ``phis_rad`` (M,), ``semi_axes_m`` (M, 2) of P_j; ``scales`` dict
    {"P": 1.0, "L": rho_L, "Q": kappa} (namespace = key). Marker id = obstacle index.
    """
    colors = {'P': (0.8, 0.1, 0.1, 1.0), 'L': (0.1, 0.5, 0.9, 1.0), 'Q': (0.5, 0.5, 0.5, 0.6)}
    out = []
    for ns, scale in scales.items():
        for j, _name in enumerate(names):
            m = _marker(f'ellipse_{ns}', j, Marker.LINE_STRIP, stamp, frame_id)
            pts = ellipse_points(
                centers_m[j], float(phis_rad[j]), np.asarray(semi_axes_m[j]) * scale
            )
            m.points = [Point(x=float(px), y=float(py), z=0.0) for px, py in pts]
            m.scale.x = 0.01
            m.color = _color(colors.get(ns, (0.3, 0.3, 0.3, 1.0)))
            out.append(m)
    return out


def edge_markers(
    parents: dict,
    positions_m: dict,
    stamp: Time,
    frame_id: str = WORLD_FRAME,
    lifetime_s: float = 0.0,
) -> list[Marker]:
    """One ARROW parent -> child per active graph edge (ns ``graph_edges``, id = child id), for
    edges whose two robots are in ``positions_m`` (id -> (2,) [m]); ``lifetime_s`` as for robots.
    """
    out = []
    for child, parent in sorted(parents.items()):
        if parent is None or parent not in positions_m or child not in positions_m:
            continue
        m = _marker('graph_edges', child, Marker.ARROW, stamp, frame_id, lifetime_s)
        a, b = positions_m[parent], positions_m[child]
        m.points = [
            Point(x=float(a[0]), y=float(a[1]), z=0.1),
            Point(x=float(b[0]), y=float(b[1]), z=0.1),
        ]
        m.scale.x, m.scale.y, m.scale.z = (
            0.012,
            0.03,
            0.04,
        )  # shaft, head diameter, head length [m]
        m.color = _color((0.1, 0.1, 0.1, 0.8))
        out.append(m)
    return out


def marker_array(*groups: list[Marker]) -> MarkerArray:
    """A MarkerArray of all markers in ``groups``."""
    msg = MarkerArray()
    msg.markers = [m for g in groups for m in g]
    return msg
