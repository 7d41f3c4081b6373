"""Locate files shipped with the package: its config/, docs/ and scripts/ folders.

From a source checkout (a clone, or the ``pip install -e`` of scripts/setup.sh's .venv, which
installs no data_files) they are the checkout's own folders next to the package. Installed by
``colcon build`` they are in ``<prefix>/share/ament_formation/`` (setup.py data_files): the share
folder of the installation this module was imported from, else the one the ament index names
(when ament_index_python is importable). ``config/params/<node>.yaml`` are the nodes' params files;
``scripts/`` holds the launchers (``scripts/launch_*.sh``), which `formation run` starts.
This module is ROS-free: ament_index_python is pure Python and optional.

It also reads the files a user hands over (scenarios, params files, camera and calibration
files, a campaign's or a run's files): :func:`read_user_text` is the one way in, bytes to checked
text, so a stray control character, a byte-order mark, invalid UTF-8 or Windows line ends give a
one-line :class:`~ament_formation.core.errors.ConfigError` naming the file, line and column (or
are read correctly), never a traceback; :func:`parse_user_yaml` parses such text strictly.
"""

from __future__ import annotations

import codecs
import os
from pathlib import Path
import re
import shutil
import sys

import yaml

from ament_formation.core.errors import ConfigError, excerpt

PACKAGE = 'ament_formation'
_PACKAGE_DIR = Path(__file__).resolve().parents[1]  # .../ament_formation (the Python package)


def source_root() -> Path | None:
    """The source checkout this module was imported from, or None (an installed copy).

    A checkout is recognised by its package.xml and setup.py next to the package, not by a
    ``config`` folder alone (an installed copy's site-packages may hold anything).
    """
    root = _PACKAGE_DIR.parent
    if (root / 'package.xml').is_file() and (root / 'setup.py').is_file():
        return root
    return None


def share_dir() -> Path | None:
    """``share/ament_formation`` of this installation (``<prefix>/lib/pythonX.Y/site-packages/
    ament_formation`` -> ``<prefix>/share/ament_formation``), else the ament index's, else None.
    """
    prefix = _PACKAGE_DIR.parents[3] if len(_PACKAGE_DIR.parents) > 3 else None
    if prefix is not None and (prefix / 'share' / PACKAGE / 'package.xml').is_file():
        return prefix / 'share' / PACKAGE
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(PACKAGE))
    except Exception:  # noqa: BLE001 - ament index absent or package not registered
        return None


def package_dir(name: str) -> Path:
    """The package's ``name`` folder (``config``, ``docs`` or ``scripts``): the source checkout's,
    else the installed ``share/ament_formation/<name>``. Raises FileNotFoundError naming it.
    """
    for base in (source_root(), share_dir()):
        if base is not None and (base / name).is_dir():
            return base / name
    raise FileNotFoundError(
        f'{name}/ of {PACKAGE} not found (neither a source checkout nor an installed share folder)'
    )


def config_dir() -> Path:
    """The package's config directory (source checkout first, then the installed share
    directory, then ``$AMENT_FORMATION_CONFIG_DIR``).
    """
    try:
        return package_dir('config')
    except FileNotFoundError:
        pass
    env = os.environ.get('AMENT_FORMATION_CONFIG_DIR')
    if env and Path(env).is_dir():
        return Path(env)
    raise FileNotFoundError(
        'config/ of ament_formation not found (set AMENT_FORMATION_CONFIG_DIR)'
    )


def params_file(node: str) -> Path:
    """The params file of node ``node`` (``config/params/<node>.yaml``: ``/**/<node>:
    ros__parameters:`` with every parameter and its default), for ``--ros-args --params-file``.
    """
    return config_file(f'params/{node}.yaml')


def config_file(relative: str) -> Path:
    """Path of ``config/<relative>``; raises FileNotFoundError naming it when absent."""
    path = config_dir() / relative
    if not path.exists():
        raise FileNotFoundError(f'{path}: no such config file')
    return path


def script_file(name: str) -> Path:
    """Path of ``scripts/<name>`` (a launcher); raises FileNotFoundError naming it when absent."""
    path = package_dir('scripts') / name
    if not path.exists():
        raise FileNotFoundError(f'{path}: no such script')
    return path


def docs_file(name: str) -> Path:
    """Path of ``docs/<name>`` (it need not exist yet: a generator writes it)."""
    return package_dir('docs') / name


def program_file(name: str) -> str:
    """The console script ``name`` of this package (``formation_world``, ...): beside this
    interpreter (a venv's bin/: scripts/setup.sh links them there), else the installed
    ``<prefix>/lib/ament_formation/<name>`` (where colcon build puts them and ``ros2 run`` looks),
    else ``name`` as found on PATH.
    """
    here = Path(sys.executable).parent / name
    if here.exists():
        return str(here)
    share = share_dir()
    if share is not None:
        installed = share.parents[1] / 'lib' / PACKAGE / name
        if installed.exists():
            return str(installed)
    return shutil.which(name) or name


# ------------------------------------------------------------------------------------------------
# Files a user hands over
# ------------------------------------------------------------------------------------------------

MAX_USER_FILE_BYTES = 10_000_000  # any user's text file (a scenario: 1 MB, its own limit)
MAX_NESTING = 32  # YAML collections inside collections
MAX_YAML_NODES = 100_000  # scalars and collections once aliases are expanded (alias bombs)

# What no text file of ours holds: C0 control characters but tab, newline and carriage return;
# DEL and the C1 controls (0x80-0x9f, bytes of another encoding read as Latin-1); lone
# surrogates; the non-characters U+FFFE/U+FFFF (PyYAML and libyaml refuse the same set); and a
# byte-order mark after the first character (two files joined; invisible in a key or a value).
_BAD_CHAR = re.compile('[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\ud800-\udfff\ufeff\ufffe\uffff]')
_C0_NAMES = (
    'NUL SOH STX ETX EOT ENQ ACK BEL BS HT LF VT FF CR SO SI DLE DC1 DC2 DC3 DC4 NAK SYN ETB CAN '
    'EM SUB ESC FS GS RS US'
).split()
# byte-order marks, longest first (UTF-32 LE starts like UTF-16 LE): a Windows editor's
# "UTF-8 with BOM" or "Unicode" (UTF-16) is read as the text it is
_BOMS = (
    (codecs.BOM_UTF32_LE, 'utf-32'),
    (codecs.BOM_UTF32_BE, 'utf-32'),
    (codecs.BOM_UTF8, 'utf-8-sig'),
    (codecs.BOM_UTF16_LE, 'utf-16'),
    (codecs.BOM_UTF16_BE, 'utf-16'),
)


def _where(text: str, pos: int) -> str:
    """``line L, column C`` (1-based; columns in characters) of character ``pos`` of ``text``."""
    line = text.count('\n', 0, pos) + 1
    line_start = text.rfind('\n', 0, pos) + 1
    return f'line {line}, column {pos - line_start + 1}'


def _char_name(ch: str) -> str:
    code = ord(ch)
    if code == 0:
        return 'NUL character (U+0000)'
    if code < 0x20:
        return f'control character U+{code:04X} ({_C0_NAMES[code]})'
    if code == 0x7F:
        return 'control character U+007F (DEL)'
    if code <= 0x9F:
        return f'C1 control character U+{code:04X}'
    if 0xD800 <= code <= 0xDFFF:
        return f'lone surrogate U+{code:04X}'
    if code == 0xFEFF:
        return 'byte-order mark U+FEFF inside the text (two files joined?)'
    return f'non-character U+{code:04X}'


def check_user_text(text: str, source: str | None, what: str) -> str:
    """``text`` of a user's ``what`` (a scenario, a params file, ...) from ``source``, checked:
    leading byte-order marks stripped, Windows line ends (CRLF) made Unix ones (LF), and a
    ConfigError naming the line and column of the first character no text file holds (NUL, C0
    control characters but tab/newline/CR, DEL, C1 controls, lone surrogates, U+FFFE/U+FFFF, a
    byte-order mark after the leading ones).
    """
    text = text.lstrip('\ufeff')
    bad = _BAD_CHAR.search(text)
    if bad is not None:
        raise ConfigError(
            f'{_char_name(bad.group())}: a {what} must be text without control characters '
            '(tab, newline and carriage return allowed)',
            _where(text, bad.start()),
            source,
        )
    return text.replace('\r\n', '\n')


def decode_user_bytes(data: bytes, source: str | None, what: str) -> str:
    """Checked text (:func:`check_user_text`) of a user's file given as bytes: UTF-8, or UTF-16 /
    UTF-32 with a byte-order mark; ConfigError naming the line and column of invalid UTF-8.
    """
    encoding = next((enc for bom, enc in _BOMS if data.startswith(bom)), 'utf-8')
    body = data[len(codecs.BOM_UTF8):] if encoding == 'utf-8-sig' else data
    codec = 'utf-8' if encoding == 'utf-8-sig' else encoding
    try:
        text = body.decode(codec)
    except UnicodeDecodeError as err:
        bad = body[err.start:err.end]
        head = body[: err.start].decode(codec, errors='replace')
        where = _where(head, len(head))
        shown = ' '.join(f'0x{b:02x}' for b in bad[:4])
        raise ConfigError(
            f'invalid {codec.upper()} (byte {shown}): a {what} must be UTF-8 text; '
            'save it as UTF-8',
            where,
            source,
        ) from None
    return check_user_text(text, source, what)


def read_user_text(path, what: str, max_bytes: int = MAX_USER_FILE_BYTES) -> str:
    """The text of the file ``path`` a user handed over as a ``what`` ('scenario', 'params
    file', 'camera file', ...): read as bytes (at most ``max_bytes``, refused above before more is
    read) and decoded by :func:`decode_user_bytes`. Every problem is a one-line ConfigError naming
    the file (and the line and column of a bad character): missing, a directory, unreadable, too
    big, not UTF-8, a control character.
    """
    source = str(path)
    try:
        with open(path, 'rb') as fh:
            size = os.fstat(fh.fileno()).st_size
            if size > max_bytes:
                raise ConfigError(f'file of {size} bytes; a {what} is at most {max_bytes}',
                                  file=source)  # fmt: skip
            data = fh.read(max_bytes + 1)  # a pipe or a device has no size: read one more
    except FileNotFoundError:
        raise ConfigError('no such file', file=source) from None
    except IsADirectoryError:
        raise ConfigError(f'is a directory, not a {what}', file=source) from None
    except PermissionError:
        raise ConfigError('cannot read: permission denied', file=source) from None
    except OSError as err:
        raise ConfigError(f'cannot read: {err.strerror or type(err).__name__}',
                          file=source) from None  # fmt: skip
    if len(data) > max_bytes:
        raise ConfigError(f'more than {max_bytes} bytes; a {what} is at most {max_bytes}',
                          file=source)  # fmt: skip
    return decode_user_bytes(data, source, what)


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that rejects a key repeated inside one mapping, and nesting deeper than
    :data:`MAX_NESTING` (checked before descending: no RecursionError on deep input).
    """

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > MAX_NESTING:
                mark = self.peek_event().start_mark
                raise ConfigError(
                    f'nested deeper than {MAX_NESTING} levels (line {mark.line + 1})'
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _expanded_size(root, limit: int) -> int:
    """Number of YAML nodes once every alias is expanded (what a constructed value would hold),
    counted without expanding; ConfigError above ``limit`` or for a recursive alias.
    """
    sizes: dict[int, int] = {}
    active: set[int] = set()

    def size(node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in active:
            raise ConfigError('recursive alias (a collection that contains itself)')
        active.add(key)
        if isinstance(node, yaml.SequenceNode):
            n = 1 + sum(size(child) for child in node.value)
        elif isinstance(node, yaml.MappingNode):
            n = 1 + sum(size(k) + size(v) for k, v in node.value)
        else:
            n = 1
        active.discard(key)
        if n > limit:
            raise ConfigError(
                f'more than {limit} values once aliases are expanded (an alias bomb?)'
            )
        sizes[key] = n
        return n

    return 0 if root is None else size(root)


def _construct_mapping(loader, node, deep=False):
    seen = {}
    for key_node, _value in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise ConfigError(
                f'duplicate key {excerpt(key)} (line {key_node.start_mark.line + 1}; '
                f'first at line {seen[key]})'
            )
        seen[key] = key_node.start_mark.line + 1
    return loader.construct_mapping(node, deep=deep)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def parse_user_yaml(text: str, source: str | None, what: str):
    """The value of one YAML document a user handed over as a ``what`` (None when empty),
    parsed strictly: the text checked by :func:`check_user_text`, a key repeated in one mapping,
    nesting deeper than :data:`MAX_NESTING`, more than :data:`MAX_YAML_NODES` values once aliases
    are expanded, a recursive alias, several documents and malformed YAML are each a one-line
    ConfigError naming ``source`` (and the line and column PyYAML reports).
    """
    text = check_user_text(text, source, what)
    loader = None
    try:
        loader = _StrictLoader(text)
        node = loader.get_single_node()
        _expanded_size(node, MAX_YAML_NODES)
        return None if node is None else loader.construct_document(node)
    except ConfigError as err:
        raise err.with_file(source) from None
    except yaml.YAMLError as err:
        raise yaml_error(err, source) from None
    except RecursionError:  # a structure deeper than Python's stack in a PyYAML internal
        raise ConfigError(f'nested deeper than {MAX_NESTING} levels', file=source) from None
    finally:
        if loader is not None:
            loader.dispose()


def yaml_error(err: yaml.YAMLError, source: str | None) -> ConfigError:
    """One-line ConfigError of a PyYAML error: ``malformed YAML at line L, column C: problem``."""
    mark = getattr(err, 'problem_mark', None)
    where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark else ''
    problem = getattr(err, 'problem', None) or str(err).splitlines()[0]
    return ConfigError(f'malformed YAML{where}: {problem}', file=source)


def check_user_yaml_syntax(text: str, source: str | None, what: str) -> str:
    """``text`` checked (:func:`check_user_text`) and well-formed YAML (every document; parsed
    to events only, nothing constructed or expanded), for a file another parser reads (rcl reads
    a params file itself); returns the checked text.
    """
    text = check_user_text(text, source, what)
    try:
        for _event in yaml.parse(text, Loader=yaml.SafeLoader):
            pass
    except yaml.YAMLError as err:
        raise yaml_error(err, source) from None
    return text


def read_user_yaml(path, what: str, max_bytes: int = MAX_USER_FILE_BYTES):
    """:func:`parse_user_yaml` of :func:`read_user_text` (``path``, ``what``, ``max_bytes``)."""
    return parse_user_yaml(read_user_text(path, what, max_bytes), str(path), what)
