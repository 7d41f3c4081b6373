"""Node parameters from frozen dataclasses: declare one ROS parameter per field (same name, same
default), read them back, build the dataclass (which validates itself), and turn any error into a
one-line ConfigError naming the node and the parameter. The node, the CLI and the tests build the
same object.

Every parameter gets a ParameterDescriptor: its type, a description with its unit and a
FloatingPointRange/IntegerRange from the field's metadata (core/params.py ``param``), and
``read_only`` unless the field is ``live`` and the node applies changes (``on_change``). So at run
time ``ros2 param set`` of a read-only parameter, of a value out of range or of a value the
dataclass rejects answers ``successful=False`` with the reason, instead of being accepted and
ignored. At start, a value of the wrong type (``-p torque_limit_nm:=abc``) is a ConfigError naming
the node, the parameter and the expected type (the process prints one line and exits 2). An integer
given for a float parameter (``-p control_rate_hz:=100``) is taken as that float.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from typing import Any, Callable, TypeVar

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterUninitializedException,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from ament_formation.core.config_files import check_user_yaml_syntax, read_user_text
from ament_formation.core.errors import ConfigError

T = TypeVar('T')

_T = Parameter.Type
_SCALAR = {bool: _T.BOOL, int: _T.INTEGER, float: _T.DOUBLE, str: _T.STRING}
_ARRAY = {bool: _T.BOOL_ARRAY, int: _T.INTEGER_ARRAY, float: _T.DOUBLE_ARRAY, str: _T.STRING_ARRAY}
_TYPE_WORDS = {
    _T.BOOL: 'a bool (true/false)',
    _T.INTEGER: 'an integer',
    _T.DOUBLE: 'a float',
    _T.STRING: 'a string',
    _T.BOOL_ARRAY: 'a list of bools',
    _T.INTEGER_ARRAY: 'a list of integers',
    _T.DOUBLE_ARRAY: 'a list of floats',
    _T.STRING_ARRAY: 'a list of strings',
    _T.BYTE_ARRAY: 'a list of bytes',
    _T.NOT_SET: 'unset',
}
# unit suffix of a parameter name -> unit, for descriptions of fields without metadata
_UNITS = (
    ('_nm', 'N m'),
    ('_mps2', 'm/s^2'),
    ('_mps', 'm/s'),
    ('_radps', 'rad/s'),
    ('_rad', 'rad'),
    ('_hz', 'Hz'),
    ('_px', 'px'),
    ('_kgm2', 'kg m^2'),
    ('_kg', 'kg'),
    ('_m', 'm'),
    ('_s', 's'),
)


def _default_of(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    raise ConfigError('has no default; the node cannot declare it', f.name)


def _ros_value(value: Any) -> Any:
    if isinstance(value, tuple):
        return list(value)
    return value


def _is_union(hint: Any) -> bool:
    return typing.get_origin(hint) in (typing.Union, types.UnionType)


def parameter_type(hint: Any, default: Any) -> Parameter.Type | None:
    """ROS parameter type of a field annotated ``hint`` with ``default``; None: dynamic typing
    (a union such as ``str | int``, or a None default).
    """
    if default is None:
        return None
    if _is_union(hint):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) != 1:
            return None
        hint = args[0]
    origin = typing.get_origin(hint)
    if origin in (tuple, list):
        args = [a for a in typing.get_args(hint) if a is not Ellipsis]
        if len(args) >= 1 and args[0] in _ARRAY:
            return _ARRAY[args[0]]
    elif hint in _SCALAR:
        return _SCALAR[hint]
    return Parameter.Type.from_parameter_value(_ros_value(default))


def describe(f: dataclasses.Field) -> str:
    """The field's description (metadata), else its name with the unit of its suffix."""
    text = f.metadata.get('description')
    if text:
        return text
    for suffix, unit in _UNITS:
        if f.name.endswith(suffix):
            return f'{f.name.replace("_", " ")} [{unit}]'
    return f.name.replace('_', ' ')


def _descriptor(
    name: str, f: dataclasses.Field, kind: Parameter.Type | None, read_only: bool
) -> ParameterDescriptor:
    desc = ParameterDescriptor(name=name, description=describe(f), read_only=read_only)
    if kind is None:
        desc.dynamic_typing = True
        return desc
    desc.type = kind.value
    bounds = f.metadata.get('range')
    if bounds is not None and None not in bounds:
        lo, hi = bounds
        if kind == _T.DOUBLE:
            desc.floating_point_range = [
                FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)
            ]
        elif kind == _T.INTEGER:
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        desc.additional_constraints = f'in [{lo:g}, {hi:g}]'
    return desc


def _type_word(value: Any) -> str:
    try:
        return _TYPE_WORDS.get(Parameter.Type.from_parameter_value(value), type(value).__name__)
    except TypeError:
        return type(value).__name__


def _coerce(value: Any, kind: Parameter.Type | None) -> tuple[bool, Any]:
    """(ok, value) of an override for a parameter of type ``kind``: an integer (list) given for a
    float (list) is that float; anything else must already have the type.
    """
    if kind is None:
        return True, value
    if kind == _T.DOUBLE and isinstance(value, int) and not isinstance(value, bool):
        return True, float(value)
    if (
        kind == _T.DOUBLE_ARRAY
        and isinstance(value, (list, tuple))
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    ):
        return True, [float(v) for v in value]
    try:
        ok = Parameter.Type.from_parameter_value(value) == kind
    except TypeError:
        ok = False
    return ok, value


def declare_dataclass(
    node: Node,
    cls: type[T],
    prefix: str = '',
    overrides: dict | None = None,
    on_change: Callable[[T], None] | None = None,
) -> T:
    """Declare every field of ``cls`` as parameter ``prefix + name`` and return the built object.

    ``overrides`` replace defaults (e.g. values from a scenario). Fields whose default is None or
    whose annotation is a union (``str | int``) or whose metadata says ``dynamic_typing`` are
    declared with a dynamic type (None read back when left unset). With ``on_change``, the fields
    marked ``live`` stay writable: a run-time change is validated by building the dataclass again
    (rejected with its reason when it fails) and ``on_change(new_object)`` applies it (it must
    not raise); every other parameter is read-only.
    Raises ConfigError("node: parameter: problem") for bad values or types.
    """
    overrides = overrides or {}
    node_name = node.get_fully_qualified_name()
    hints = typing.get_type_hints(cls)
    given = getattr(node, '_parameter_overrides', {})  # rclpy: command line and params files
    values: dict[str, Any] = {}
    names: dict[str, str] = {}
    for f in dataclasses.fields(cls):
        name = prefix + f.name
        names[name] = f.name
        default = overrides.get(f.name, _default_of(f))
        kind = (
            None
            if f.metadata.get('dynamic_typing')
            else parameter_type(hints.get(f.name), default)
        )
        live = bool(f.metadata.get('live')) and on_change is not None
        desc = _descriptor(name, f, kind, read_only=not live)
        ignore_override = False
        value = _ros_value(default)
        if name in given:
            ok, value_given = _coerce(given[name].value, kind)
            if not ok:
                raise ConfigError(
                    f'expected {_TYPE_WORDS[kind]}, got {given[name].value!r} '
                    f'({_type_word(given[name].value)}); {describe(f)}',
                    name,
                    node_name,
                )
            if value_given is not given[name].value:
                value, ignore_override = value_given, True
        try:
            if kind is not None and isinstance(value, list) and not value:
                # an empty list says nothing of its element type: declare by type only
                node.declare_parameter(name, kind, desc, ignore_override=ignore_override)
                try:
                    value = node.get_parameter(name).value
                except ParameterUninitializedException:
                    value = []
            else:
                value = node.declare_parameter(
                    name, value, desc, ignore_override=ignore_override
                ).value
        except InvalidParameterTypeException:
            raise ConfigError(
                f'expected {_TYPE_WORDS.get(kind, kind)}; {describe(f)}', name, node_name
            ) from None
        except InvalidParameterValueException as err:
            bounds = f.metadata.get('range')
            got = given[name].value if name in given else value
            problem = (
                f'must be in [{bounds[0]:g}, {bounds[1]:g}] (got {got!r})' if bounds else str(err)
            )
            raise ConfigError(problem, name, node_name) from None
        values[f.name] = _from_ros(value, hints.get(f.name))
    try:
        obj = cls(**values)
    except ConfigError as err:
        field = prefix + err.field if err.field else None
        raise ConfigError(err.problem, field, node_name) from None
    except (TypeError, ValueError) as err:
        raise ConfigError(str(err), None, node_name) from None
    if on_change is not None and any(f.metadata.get('live') for f in dataclasses.fields(cls)):
        _watch(node, obj, names, hints, on_change)
    return obj


def _from_ros(value: Any, hint: Any) -> Any:
    if isinstance(value, list) and 'tuple' in str(hint):
        return tuple(value)
    return value


def _watch(node: Node, obj: Any, names: dict[str, str], hints: dict, on_change: Callable) -> None:
    """Validate run-time changes of ``obj``'s live parameters with the dataclass (on-set
    callback: a rejection answers ``successful=False`` with the reason), then apply them
    (post-set callback: ``on_change(new_object)``).
    """
    state = {'obj': obj}

    def changed(params: list[Parameter]) -> Any:
        changes = {
            names[p.name]: _from_ros(p.value, hints.get(names[p.name]))
            for p in params
            if p.name in names
        }
        for key, value in changes.items():
            if isinstance(value, float) and not math.isfinite(value):
                raise ConfigError(f'must be finite (got {value!r})', key)
        return dataclasses.replace(state['obj'], **changes) if changes else None

    def on_set(params: list[Parameter]) -> SetParametersResult:
        try:
            changed(params)
        except (ConfigError, TypeError, ValueError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def post_set(params: list[Parameter]) -> None:
        new = changed(params)
        if new is not None:
            state['obj'] = new
            on_change(new)

    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(post_set)


# ------------------------------------------------------------------------------------------------
# Params files (--ros-args --params-file FILE): rcl reads them, we check them first
# ------------------------------------------------------------------------------------------------

_RCL_AT = re.compile(r',? at /\S+:\d+')
_RCL_PARAMS = re.compile(r"Couldn't parse params file: '--params-file (.*?)'\. Error: (.*)", re.S)


def params_files_in(argv: list[str]) -> list[str]:
    """The FILE of every ``--params-file FILE`` among the ROS arguments of ``argv`` (those after
    ``--ros-args``, up to a ``--``), as rcl takes them.
    """
    files, ros = [], False
    for i, arg in enumerate(argv):
        if arg == '--ros-args':
            ros = True
        elif arg == '--':
            ros = False
        elif ros and arg == '--params-file' and i + 1 < len(argv):
            files.append(argv[i + 1])
    return files


def check_params_file(path: str) -> None:
    """A params file a user hands over, checked before rcl reads it: the safe reader's checks
    (no control characters, UTF-8 or a BOM, a size limit) and well-formed YAML; ConfigError
    naming the file, line and column. (rcl itself reads it afterwards: a byte-order mark, CRLF
    and UTF-16 are read correctly by it too.)
    """
    check_user_yaml_syntax(read_user_text(path, 'params file'), str(path), 'params file')


def rcl_args_error(err: Exception) -> ConfigError:
    """One line for rcl's refusal of the ROS arguments (``RCLError`` of ``rclpy.init``): a params
    file it cannot take (``FILE: not a ROS params file: <rcl's reason>``), else the reason,
    without rcl's source locations.
    """
    text = _RCL_AT.sub('', str(err))
    found = _RCL_PARAMS.search(text)
    if found:
        return ConfigError(f'not a ROS params file: {found.group(2)}', None, found.group(1))
    return ConfigError(f'bad ROS arguments: {text}')


def init_rclpy_checked(argv: list[str], **init_kw) -> None:
    """``rclpy.init(args=argv, **init_kw)`` after :func:`check_params_file` of each params file
    in ``argv``; what rcl still refuses is a ConfigError of one line (:func:`rcl_args_error`), and
    rcl's own error log is not printed (stderr is held while rcl parses: printed on success).
    """
    import os
    import sys
    import tempfile

    import rclpy
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    for path in params_files_in(argv):
        check_params_file(path)
    sys.stderr.flush()
    saved = os.dup(2)
    failure = None
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            rclpy.init(args=argv, **init_kw)
        except _rclpy.RCLError as err:
            failure = err
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        if failure is None:
            held.seek(0)
            said = held.read()
            if said:
                os.write(2, said)
    if failure is not None:
        raise rcl_args_error(failure)
