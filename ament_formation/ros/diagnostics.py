"""Build diagnostic_msgs/DiagnosticArray messages from plain key/value dictionaries."""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

OK = DiagnosticStatus.OK
WARN = DiagnosticStatus.WARN
ERROR = DiagnosticStatus.ERROR
STALE = DiagnosticStatus.STALE


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def status(name: str, hardware_id: str, level: int, message: str, values: dict) -> DiagnosticStatus:
    """One DiagnosticStatus; ``values`` become KeyValue pairs (floats to 6 significant digits)."""
    msg = DiagnosticStatus()
    msg.level = level if isinstance(level, bytes) else bytes([level])
    msg.name = name
    msg.hardware_id = hardware_id
    msg.message = message
    msg.values = [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]
    return msg


def array(stamp, statuses: list[DiagnosticStatus]) -> DiagnosticArray:
    """A DiagnosticArray stamped ``stamp`` (builtin_interfaces/Time)."""
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = list(statuses)
    return msg
