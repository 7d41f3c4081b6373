"""Node parameters from frozen dataclasses: declare one ROS parameter per field (same name, same
default), read them back, build the dataclass (which validates itself), and turn any error into a
one-line ConfigError naming the parameter. The node, the CLI and the tests build the same object."""
from __future__ import annotations

import dataclasses
import typing
from typing import Any, TypeVar

from rclpy.node import Node

from ament_formation.core.errors import ConfigError

T = TypeVar("T")


def _default_of(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    raise ConfigError("has no default; the node cannot declare it", f.name)


def _ros_value(value: Any) -> Any:
    if isinstance(value, tuple):
        return list(value)
    return value


def declare_dataclass(node: Node, cls: type[T], prefix: str = "", overrides: dict | None = None) -> T:
    """Declare every field of ``cls`` as parameter ``prefix + name`` and return the built object.

    ``overrides`` replace defaults (e.g. values from a scenario). Fields whose default is None are
    declared with a dynamic type and read back as None when left unset.
    Raises ConfigError("node: parameter: problem") for bad values.
    """
    overrides = overrides or {}
    hints = typing.get_type_hints(cls)
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        name = prefix + f.name
        default = overrides.get(f.name, _default_of(f))
        if default is None:
            from rcl_interfaces.msg import ParameterDescriptor

            node.declare_parameter(name, None, ParameterDescriptor(dynamic_typing=True))
            value = node.get_parameter(name).value
        elif isinstance(default, (tuple, list)) and not default:
            # an empty default says nothing of the element type: take it from the annotation
            from rclpy.exceptions import ParameterUninitializedException
            from rclpy.parameter import Parameter

            hint = str(hints.get(f.name, ""))
            kind = next((t for key, t in (("int", Parameter.Type.INTEGER_ARRAY),
                                          ("float", Parameter.Type.DOUBLE_ARRAY),
                                          ("str", Parameter.Type.STRING_ARRAY),
                                          ("bool", Parameter.Type.BOOL_ARRAY)) if f"[{key}" in hint), None)
            if kind is None:
                raise ConfigError(f"empty default of unknown element type ({hint})", name)
            node.declare_parameter(name, kind)
            try:
                value = node.get_parameter(name).value
            except ParameterUninitializedException:
                value = type(default)()
        else:
            node.declare_parameter(name, _ros_value(default))
            value = node.get_parameter(name).value
        if isinstance(value, list) and "tuple" in str(hints.get(f.name, "")):
            value = tuple(value)
        values[f.name] = value
    try:
        return cls(**values)
    except ConfigError as err:
        field = prefix + err.field if err.field else None
        raise ConfigError(err.problem, field, node.get_fully_qualified_name()) from None
    except (TypeError, ValueError) as err:
        raise ConfigError(str(err), None, node.get_fully_qualified_name()) from None
