"""Named QoS profiles: every publisher and subscription of the package picks one of these.

| name            | used for                                                         |
|-----------------|------------------------------------------------------------------|
| QOS_CONTROL     | wheel_torque, wheel_state, state, accel, mode, pose, truth       |
| QOS_IMAGE       | /camera/image_raw and debug images (drop old frames, never queue) |
| QOS_GRAPH       | /formation/graph (late joiners get the current graph)            |
| QOS_MARKERS     | /formation/markers (late joiners get the last set)               |
| QOS_DIAGNOSTICS | /diagnostics                                                     |
| QOS_CLOCK       | /clock (compatible with rclpy's best-effort time source)         |
"""

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

QOS_CONTROL = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

QOS_IMAGE = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=2,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)

QOS_GRAPH = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

QOS_MARKERS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

QOS_DIAGNOSTICS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

QOS_CLOCK = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
