"""Versioned JSON payloads carried in std_msgs/String, their JSON Schemas and a small validator.

Three topics carry JSON because no standard message holds what they say (docs/schemas/README.md):

| topic | schema id | made by | read by |
|---|---|---|---|
| /formation/graph | ament_formation/graph/v1 | coordinator | controllers, world, recorder |
| /formation/encounters | ament_formation/encounters/v2 | coordinator | controllers |
| robot_<id>/mode | ament_formation/mode/v1 | controller | coordinator, other controllers |

Every payload names its schema in a ``"schema"`` field. A receiver decodes with :func:`decode`,
which rejects (``PayloadError``, a ValueError) anything that is not the expected schema: not UTF-8
JSON, too large or too deeply nested, NaN/inf, a missing or extra field, a wrong type or range.
Nodes count what they reject and report it on /diagnostics; a bad payload never raises further.

The schemas are plain dictionaries here (installed with the package); ``docs/schemas/*.json`` are
written from them (``python -m ament_formation.ros.payloads docs/schemas``) and a test keeps both
equal. The validator understands the JSON Schema (2020-12) keywords these schemas use: ``type``,
``const``, ``enum``, ``properties``, ``required``, ``additionalProperties``, ``propertyNames``,
``maxProperties``, ``items``, ``minItems``, ``maxItems``, ``minimum``, ``maximum``, ``minLength``,
``maxLength``, ``pattern``. Numbers must be finite; a boolean is never an integer or number.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
import re
import sys

GRAPH_V1 = 'ament_formation/graph/v1'
ENCOUNTERS_V2 = 'ament_formation/encounters/v2'
MODE_V1 = 'ament_formation/mode/v1'

MAX_PAYLOAD_BYTES = 256 * 1024  # a graph of 1000 robots is ~60 kB
MAX_ROBOTS = 10_000
_ROBOT_KEY = {'type': 'string', 'pattern': r'^(0|[1-9][0-9]{0,8})$'}  # "<robot id>" object keys
_NUMBER = {'type': 'number'}
_ROBOT_ID = {'type': 'integer', 'minimum': 0, 'maximum': 999_999_999}
_XY = {'type': 'array', 'items': _NUMBER, 'minItems': 2, 'maxItems': 2}


class PayloadError(ValueError):
    """A payload that does not follow its schema (message: ``<what>: <where>: <problem>``)."""


SCHEMAS: dict[str, dict] = {
    GRAPH_V1: {
        'title': 'formation graph (/formation/graph)',
        'description': 'The communication graph of S9: the current parent of every robot '
        '(null = a '
        'root: team leader or avoider), the formation offsets delta_i [m, world] to '
        'that parent, the robots avoiding, when it was made (stamp_s, ROS time [s]) and '
        'the mission start start_s (ROS time [s]; null until the coordinator starts the '
        'mission; scenario time t = now - start_s). Same revision re-sent every '
        'republish_s; a new revision on every change.',
        'type': 'object',
        'required': [
            'schema',
            'revision',
            'parents',
            'offsets_m',
            'avoiding',
            'stamp_s',
            'start_s',
        ],
        'additionalProperties': False,
        'properties': {
            'schema': {'const': GRAPH_V1},
            'revision': {'type': 'integer', 'minimum': 0},
            'parents': {
                'type': 'object',
                'propertyNames': _ROBOT_KEY,
                'maxProperties': MAX_ROBOTS,
                'additionalProperties': {
                    'type': ['integer', 'null'],
                    'minimum': 0,
                    'maximum': 999_999_999,
                },
            },
            'offsets_m': {
                'type': 'object',
                'propertyNames': _ROBOT_KEY,
                'maxProperties': MAX_ROBOTS,
                'additionalProperties': _XY,
            },
            'avoiding': {'type': 'array', 'items': _ROBOT_ID, 'maxItems': MAX_ROBOTS},
            'stamp_s': {'type': 'number', 'minimum': 0},
            'start_s': {'type': ['number', 'null'], 'minimum': 0},
        },
    },
    ENCOUNTERS_V2: {
        'title': "the coordinator's decisions (/formation/encounters)",
        'description': "The coordinator's robot-robot encounters (docs/control-law.md S7.1): for "
        'each robot told to yield or to avoid mutually, its partner, direction (+1 CCW, -1 CW), '
        'common entry time t_entry_s (scenario time [s]), the shared drift w_c [m/s, world] of '
        'a mutual pair (null otherwise) and from when its parking factor applies (park_at_s, '
        'scenario time; null: at once); a robot on an obstacle asked to make way for a stalled '
        'robot (mode make_way, partner that robot, S8.9). A robot not listed has no '
        "assignment. rates: each team leader's progress rate target in [0, 1] (S17); "
        'mission_end_s: when every reference reached its end (scenario time [s]; null before).',
        'type': 'object',
        'required': ['schema', 'revision', 'stamp_s', 'assignments', 'rates', 'mission_end_s'],
        'additionalProperties': False,
        'properties': {
            'schema': {'const': ENCOUNTERS_V2},
            'revision': {'type': 'integer', 'minimum': 0},
            'stamp_s': {'type': 'number', 'minimum': 0},
            'assignments': {
                'type': 'object',
                'propertyNames': _ROBOT_KEY,
                'maxProperties': MAX_ROBOTS,
                'additionalProperties': {
                    'type': 'object',
                    'required': ['mode', 'partner', 'direction', 't_entry_s', 'drift_mps',
                                 'park_at_s'],
                    'additionalProperties': False,
                    'properties': {
                        'mode': {'enum': ['yield', 'mutual', 'make_way']},
                        'partner': _ROBOT_ID,
                        'direction': {'enum': [1.0, -1.0]},
                        't_entry_s': {'type': 'number'},
                        'drift_mps': {
                            'type': ['array', 'null'],
                            'items': _NUMBER,
                            'minItems': 2,
                            'maxItems': 2,
                        },
                        'park_at_s': {'type': ['number', 'null']},
                    },
                },
            },
            'rates': {
                'type': 'object',
                'propertyNames': _ROBOT_KEY,
                'maxProperties': MAX_ROBOTS,
                'additionalProperties': {'type': 'number', 'minimum': 0, 'maximum': 1},
            },
            'mission_end_s': {'type': ['number', 'null'], 'minimum': 0},
        },
    },
    MODE_V1: {
        'title': "a robot's avoidance mode (robot_<id>/mode)",
        'description': "The S8 mode of the robot's controller: mode (coordination, obstacle, "
        'yield, '
        'mutual; hold or stopped when its safety layer holds or stops the robot), the '
        'target (obstacle name or robot_<id>; null in coordination), the direction of '
        'travel on the limit cycle (ccw, cw or null) and whether it counts as avoiding '
        'for the S9 rewiring. Sent on change and every second. Other keys are allowed '
        '(and ignored by the receivers).',
        'type': 'object',
        'required': ['schema', 'mode', 'target', 'direction'],
        'additionalProperties': True,
        'properties': {
            'schema': {'const': MODE_V1},
            'mode': {'type': 'string', 'pattern': r'^[a-z_]{1,32}$'},
            'target': {'type': ['string', 'null'], 'minLength': 1, 'maxLength': 128},
            'direction': {'enum': ['ccw', 'cw', None]},
            'avoiding': {'type': 'boolean'},
        },
    },
}


# --------------------------------------------------------------------------- validation
_TYPES = {
    'object': lambda v: isinstance(v, dict),
    'array': lambda v: isinstance(v, list),
    'string': lambda v: isinstance(v, str),
    'integer': lambda v: isinstance(v, int) and not isinstance(v, bool),
    'number': lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
    'boolean': lambda v: isinstance(v, bool),
    'null': lambda v: v is None,
}


def _same(a, b) -> bool:
    """JSON equality for const/enum: 1 == 1.0, but a boolean equals only a boolean."""
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    if a is None or b is None:
        return a is b
    if isinstance(a, (int, float)) or isinstance(b, (int, float)):
        return isinstance(a, (int, float)) and isinstance(b, (int, float)) and a == b
    return type(a) is type(b) and a == b


_PATTERNS: dict[str, re.Pattern] = {}


def _pattern(text: str) -> re.Pattern:
    p = _PATTERNS.get(text)
    if p is None:
        p = _PATTERNS[text] = re.compile(text)
    return p


class _Invalid(Exception):
    """A failed check deep in a value; the member path is collected while it unwinds."""

    def __init__(self, problem: str):
        super().__init__(problem)
        self.problem = problem
        self.path: list[str] = []


def _descend(value, schema: dict, member) -> None:
    try:
        _check(value, schema)
    except _Invalid as err:
        err.path.append(str(member))
        raise


def _check(value, schema: dict) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise _Invalid('must be a finite number')
    if 'const' in schema and not _same(value, schema['const']):
        raise _Invalid(f'must be {schema["const"]!r}')
    if 'enum' in schema and not any(_same(value, e) for e in schema['enum']):
        raise _Invalid(f'must be one of {schema["enum"]!r}')
    types = schema.get('type')
    if types is not None:
        types = [types] if isinstance(types, str) else types
        if not any(_TYPES[t](value) for t in types):
            raise _Invalid(f'must be of type {" or ".join(types)} (got {type(value).__name__})')
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if 'minimum' in schema and value < schema['minimum']:
            raise _Invalid(f'must be >= {schema["minimum"]}')
        if 'maximum' in schema and value > schema['maximum']:
            raise _Invalid(f'must be <= {schema["maximum"]}')
    elif isinstance(value, str):
        if len(value) < schema.get('minLength', 0):
            raise _Invalid(f'must have at least {schema["minLength"]} characters')
        if 'maxLength' in schema and len(value) > schema['maxLength']:
            raise _Invalid(f'must have at most {schema["maxLength"]} characters')
        if 'pattern' in schema and _pattern(schema['pattern']).search(value) is None:
            raise _Invalid(f'must match {schema["pattern"]}')
    elif isinstance(value, list):
        if len(value) < schema.get('minItems', 0):
            raise _Invalid(f'must have at least {schema["minItems"]} items')
        if 'maxItems' in schema and len(value) > schema['maxItems']:
            raise _Invalid(f'must have at most {schema["maxItems"]} items')
        items = schema.get('items')
        if items is not None:
            for k, item in enumerate(value):
                _descend(item, items, k)
    elif isinstance(value, dict):
        if 'maxProperties' in schema and len(value) > schema['maxProperties']:
            raise _Invalid(f'must have at most {schema["maxProperties"]} members')
        for key in schema.get('required', ()):
            if key not in value:
                raise _Invalid(f'missing member {key!r}')
        props = schema.get('properties', {})
        extra = schema.get('additionalProperties', True)
        names = schema.get('propertyNames')
        for key, item in value.items():
            if names is not None:
                _descend(key, names, key)
            sub = props.get(key)
            if sub is not None:
                _descend(item, sub, key)
            elif extra is False:
                raise _Invalid(f'unexpected member {key!r}')
            elif extra is not True:
                _descend(item, extra, key)


def validate(value, schema: dict) -> None:
    """Raise PayloadError ``<JSON pointer>: <problem>`` unless ``value`` follows ``schema`` (the
    member path is only built for a failure: a valid payload costs no string work).
    """
    try:
        _check(value, schema)
    except _Invalid as err:
        raise PayloadError('/' + '/'.join(reversed(err.path)) + ': ' + err.problem) from None


def _no_constant(name: str):
    raise PayloadError(f'/: {name} is not a JSON number')


def decode(text, schema_id: str) -> dict:
    """The JSON object of ``text`` (str or bytes) checked against ``SCHEMAS[schema_id]``.

    Raises PayloadError (``<schema id>: <pointer>: <problem>``) for anything else, including
    payloads over MAX_PAYLOAD_BYTES, nesting deeper than the interpreter allows, NaN/Infinity,
    duplicate-free but unknown members and a different ``schema`` field (another version).
    """
    schema = SCHEMAS[schema_id]
    try:
        if isinstance(text, (bytes, bytearray)):
            text = bytes(text).decode('utf-8')
        if not isinstance(text, str):
            raise PayloadError(f'/: expected a JSON text (got {type(text).__name__})')
        if len(text) > MAX_PAYLOAD_BYTES:
            raise PayloadError(f'/: payload of {len(text)} characters exceeds {MAX_PAYLOAD_BYTES}')
        data = json.loads(text, parse_constant=_no_constant)
        if isinstance(data, dict) and 'schema' in data and data['schema'] != schema_id:
            raise PayloadError(f'/schema: expected {schema_id!r} (got {data["schema"]!r})')
        validate(data, schema)
    except PayloadError as err:
        raise PayloadError(f'{schema_id}: {err}') from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise PayloadError(f'{schema_id}: /: not JSON ({err})') from None
    except RecursionError:
        raise PayloadError(f'{schema_id}: /: nested too deeply') from None
    return data


def encode(data: dict) -> str:
    """Compact, key-sorted JSON of a payload (``data`` must already carry its ``schema``)."""
    return json.dumps(data, sort_keys=True, separators=(',', ':'), allow_nan=False)


# --------------------------------------------------------------------------- schema documents
def schema_document(schema_id: str) -> dict:
    """The JSON Schema document of ``schema_id`` as published in docs/schemas/."""
    doc = {'$schema': 'https://json-schema.org/draft/2020-12/schema', '$id': schema_id}
    doc.update(SCHEMAS[schema_id])
    return doc


_FILES = {
    GRAPH_V1: 'formation_graph.v1.json',
    ENCOUNTERS_V2: 'formation_encounters.v2.json',
    MODE_V1: 'robot_mode.v1.json',
}


def schema_filename(schema_id: str) -> str:
    """File name of a schema in docs/schemas/ (``formation_graph.v1.json``, ...)."""
    return _FILES[schema_id]


def schema_text(schema_id: str) -> str:
    return json.dumps(schema_document(schema_id), indent=2, ensure_ascii=False) + '\n'


def write_schemas(folder: str | Path) -> list[Path]:
    """Write every schema document into ``folder``; the paths written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for sid in SCHEMAS:
        path = folder / schema_filename(sid)
        path.write_text(schema_text(sid))
        out.append(path)
    return out


if __name__ == '__main__':
    for p in write_schemas(sys.argv[1] if len(sys.argv) > 1 else 'docs/schemas'):
        print(p)
