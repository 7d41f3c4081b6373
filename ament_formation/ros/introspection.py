"""Runtime introspection of the ROS graph without rosidl_runtime_py: message classes from type
names, a QoS compatible with a topic's publishers, .msg definition text with dependencies (for
MCAP schemas), and messages as plain dictionaries (for echo).
"""

from __future__ import annotations

import importlib
from pathlib import Path
import re

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

_PRIMITIVES = frozenset(
    {
        'bool',
        'byte',
        'char',
        'float32',
        'float64',
        'int8',
        'uint8',
        'int16',
        'uint16',
        'int32',
        'uint32',
        'int64',
        'uint64',
        'string',
        'wstring',
    }
)


def message_class(type_name: str):
    """The Python class of ``pkg/msg/Type`` (or ``pkg/Type``); ValueError when unknown."""
    parts = type_name.split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        pkg, name = parts[0], parts[2]
    elif len(parts) == 2:
        pkg, name = parts
    else:
        raise ValueError(f'type: expected pkg/msg/Type (got {type_name!r})')
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError):
        raise ValueError(f'type: message type {type_name!r} is not installed') from None


def full_type_name(msg_class) -> str:
    """``pkg/msg/Type`` of a generated message class."""
    module = msg_class.__module__.split('.')
    return f'{module[0]}/msg/{msg_class.__name__}'


def topic_types(node: Node) -> dict[str, str]:
    """{topic: first type name} currently visible to ``node``."""
    return {name: types[0] for name, types in node.get_topic_names_and_types() if types}


def compatible_qos(node: Node, topic: str, depth: int = 10) -> QoSProfile:
    """A subscription QoS that matches every current publisher of ``topic``.

    Best effort if any publisher is best effort (a reliable reader would not match it);
    transient local only if every publisher offers it (so late joiners get latched data).
    """
    infos = node.get_publishers_info_by_topic(topic)
    reliable = all(i.qos_profile.reliability != ReliabilityPolicy.BEST_EFFORT for i in infos)
    latched = bool(infos) and all(
        i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos
    )
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


# --------------------------------------------------------------------------- .msg definitions
def _share_dir(pkg: str) -> Path:
    """share/<pkg> of an installed interface package (ament index or next to the module)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(pkg))
    except Exception:  # not in the ament index: fall back to the venv layout
        module = importlib.import_module(pkg)
        for parent in Path(module.__file__).resolve().parents:
            cand = parent / 'share' / pkg
            if cand.is_dir():
                return cand
    raise ValueError(f'type: no share/{pkg} folder with .msg files')


def _msg_text(pkg: str, name: str) -> str:
    path = _share_dir(pkg) / 'msg' / f'{name}.msg'
    if not path.is_file():
        raise ValueError(f'type: {path} not found')
    return path.read_text()


def _dependencies(pkg: str, text: str) -> list[tuple[str, str]]:
    """(pkg, Type) of every non-primitive field type in a .msg text, in order of appearance.

    Constants and default values only exist for primitive types, so the type token decides.
    """
    deps = []
    for line in text.splitlines():
        tokens = line.split('#', 1)[0].split()
        if len(tokens) < 2:
            continue
        base = re.sub(r'\[.*\]$', '', tokens[0])  # arrays: T[], T[N], T[<=N]
        base = re.sub(r'<=\d+$', '', base)  # bounded strings: string<=N
        if base in _PRIMITIVES:
            continue
        if '/' in base:
            parts = base.split('/')
            dep = (parts[0], parts[-1])
        elif base == 'Header':
            dep = ('std_msgs', 'Header')
        else:
            dep = (pkg, base)
        deps.append(dep)
    return deps


def message_definition(type_name: str) -> str:
    """The ros2msg schema text: the type's .msg followed by every dependency (depth first),
    each introduced by a line of 80 '=' and ``MSG: pkg/Type`` (the rosbag2/MCAP convention).
    """
    cls = message_class(type_name)
    pkg, name = full_type_name(cls).split('/msg/')
    root = _msg_text(pkg, name)
    seen: set[tuple[str, str]] = set()
    order: list[tuple[str, str, str]] = []

    def visit(p: str, text: str) -> None:
        for dep in _dependencies(p, text):
            if dep in seen:
                continue
            seen.add(dep)
            dep_text = _msg_text(*dep)
            order.append((dep[0], dep[1], dep_text))
            visit(dep[0], dep_text)

    visit(pkg, root)
    parts = [root.rstrip('\n')]
    for p, n, text in order:
        parts.append('=' * 80 + f'\nMSG: {p}/{n}\n' + text.rstrip('\n'))
    return '\n'.join(parts) + '\n'


# --------------------------------------------------------------------------- dictionaries
def message_to_dict(msg, max_array: int | None = None):
    """A message as nested dicts/lists of plain values (arrays longer than ``max_array`` become
    the string ``'<N values>'``).
    """
    if hasattr(msg, 'get_fields_and_field_types'):
        return {
            name: message_to_dict(getattr(msg, name), max_array)
            for name in msg.get_fields_and_field_types()
        }
    if isinstance(msg, (bytes, bytearray)):
        msg = list(msg)
    elif hasattr(msg, 'tolist') and not isinstance(msg, (str, int, float, bool)):
        msg = msg.tolist()
    elif hasattr(msg, 'typecode'):  # array.array
        msg = list(msg)
    if isinstance(msg, (list, tuple)):
        if max_array is not None and len(msg) > max_array:
            return f'<{len(msg)} values>'
        return [message_to_dict(v, max_array) for v in msg]
    return msg
