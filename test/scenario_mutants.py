"""Seeded mutants of the shipped scenario files: what a user's typo, a broken generator or a
hostile file can put in front of the validator (test_scenario_limits.py, and
bench/bench_scenario_fuzz.py, which also simulates the mutants that are accepted).

``mutants(seed, count)`` yields ``(label, data)``: the bytes of one mutated scenario file.
Mutations of the parsed mapping (a value replaced by a huge, tiny, non-finite, wrongly typed, very
long or deeply nested value; a key deleted or misspelt; a list multiplied), of the text itself
(alias bombs, deep nesting, truncation, flipped characters) and of its bytes (what a bad copy, an
editor, a serial console or a damaged disk leaves: NUL, BEL, ESC sequences and other control
characters, DEL, C1 controls, a byte-order mark, Windows or old Mac line ends, invalid UTF-8
(stray, overlong, truncated or surrogate sequences, a Latin-1 file), UTF-16 with and without its
BOM, flipped bits, a tail of zeros). Some byte-level mutants are valid files (a BOM, CRLF, UTF-16
with its BOM): they must be read correctly.
"""

from __future__ import annotations

import codecs
import copy
from pathlib import Path
import random

import yaml

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / 'config' / 'scenarios').glob('*.yaml'))

_VALUES = (
    1e300,
    -1e300,
    1e15,
    1e6 + 1,
    -1.0,
    0.0,
    1e-300,
    10**30,
    float('nan'),
    float('inf'),
    True,
    None,
    '',
    'x',
    [],
    {},
    [1.0] * 1000,
    {'unexpected': 1},
)


def _leaves(node, path=()):
    """Every (path, value) of a nested mapping/list, collections included."""
    yield path, node
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _leaves(v, path + (i,))


def _set(root, path, value):
    node = root
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value


def _deep_list(depth: int) -> str:
    return '[' * depth + '1' + ']' * depth


def _alias_bomb(levels: int = 9, width: int = 9) -> str:
    lines = ['a0: &a0 [x, x, x, x, x, x, x, x, x]']
    for i in range(1, levels):
        refs = ', '.join([f'*a{i - 1}'] * width)
        lines.append(f'a{i}: &a{i} [{refs}]')
    return '\n'.join(lines)


def _mutate_mapping(rng: random.Random, data: dict) -> tuple[str, dict]:
    data = copy.deepcopy(data)
    paths = [p for p, _ in _leaves(data) if p]
    path = rng.choice(paths)
    kind = rng.randrange(10)
    where = '.'.join(map(str, path))
    if kind == 9 and data.get('obstacles'):  # many valid obstacles, moving, for a long time
        return _spread_obstacles(rng, data)
    if kind <= 3:
        value = rng.choice(_VALUES)
        _set(data, path, value)
        return f'{where} = {str(value)[:20]}', data
    if kind == 4:  # a very long value (a string of 10 MB, kept below the file limit here)
        _set(data, path, 'v' * rng.choice((1_000, 100_000, 900_000)))
        return f'{where} = long string', data
    if kind == 5 and isinstance(path[-1], str):  # a key deleted or misspelt
        parent = data
        for key in path[:-1]:
            parent = parent[key]
        value = parent.pop(path[-1])
        if rng.random() < 0.5:
            parent[path[-1] + '_typo'] = value
            return f'{where} misspelt', data
        return f'{where} deleted', data
    if kind == 6:  # a list multiplied (1000 robots, 600 obstacles)
        lists = [p for p, v in _leaves(data) if isinstance(v, list) and v and p]
        if lists:
            lpath = rng.choice(lists)
            node = data
            for key in lpath:
                node = node[key]
            factor = rng.choice((10, 300, 1000))
            _set(data, lpath, [copy.deepcopy(node[0]) for _ in range(len(node) * factor)])
            return f'{".".join(map(str, lpath))} x{factor}', data
    if kind == 7:  # a scalar replaced by a nested structure
        _set(data, path, yaml.safe_load(_deep_list(rng.choice((5, 20, 30)))))
        return f'{where} = nested list', data
    scale = rng.choice((1e-9, 1e3, 1e9, -1.0))
    value = None
    for p, v in _leaves(data):
        if p == path:
            value = v
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        _set(data, path, value * scale)
        return f'{where} x {scale:g}', data
    _set(data, path, rng.choice(_VALUES))
    return f'{where} replaced', data


def _spread_obstacles(rng: random.Random, data: dict) -> tuple[str, dict]:
    """Copies of the first obstacle on a grid (apart or close enough that only the check's
    sampling tells), oscillating or not, for up to a day: valid files whose limit-cycle check
    (S13 #3) is work in proportion to pairs x instants.
    """
    n, spacing = rng.choice((64, 256)), rng.choice((0.5, 1.0, 2.0))
    duration = rng.choice((600.0, 3600.0, 86_400.0))
    first = data['obstacles'][0]
    x0, y0 = first.get('center_m', [0.0, 0.0])
    copies = []
    for i in range(n):
        o = copy.deepcopy(first)
        o['name'] = f'g{i}'
        o['center_m'] = [x0 + 20.0 + spacing * (i % 16), y0 + 20.0 + spacing * (i // 16)]
        if rng.random() < 0.5:
            o['oscillation'] = {'amplitude_m': [0.0, 0.2], 'period_s': 7.0}
        copies.append(o)
    data['obstacles'], data['duration_s'] = copies, duration
    return f'{n} obstacles {spacing:g} m apart for {duration:g} s', data


def _mutate_text(rng: random.Random, text: str) -> tuple[str, str]:
    kind = rng.randrange(6)
    if kind == 0:
        return 'alias bomb', _alias_bomb() + '\n' + text
    if kind == 1:
        depth = rng.choice((100, 1_000, 100_000))
        return f'nesting {depth}', text.replace('name:', f'extra: {_deep_list(depth)}\nname:', 1)
    if kind == 2:
        cut = rng.randrange(len(text))
        return f'truncated at {cut}', text[:cut]
    if kind == 3:
        chars = list(text)
        for _ in range(rng.randint(1, 5)):
            chars[rng.randrange(len(chars))] = rng.choice(':-[]{}&*!|>\'"%@`#,\t\n ')
        return 'flipped characters', ''.join(chars)
    if kind == 4:
        return 'recursive alias', 'loop: &l [*l]\n' + text
    return 'duplicated document', text + '\n---\n' + text


# control characters a bad copy, an editor or a serial console leaves (tab, LF, CR excluded)
_CONTROLS = [bytes([c]) for c in range(0x20) if c not in (0x09, 0x0A, 0x0D)] + [
    b'\x7f',  # DEL
    b'\x1b[2K',  # ESC sequence of a terminal (erase line)
    b'\x1b[0m',
    b'\xc2\x85',  # C1 NEL, valid UTF-8
    b'\xc2\x9b',  # C1 CSI, valid UTF-8
    b'\xef\xbf\xbe',  # U+FFFE, a non-character
]
# byte sequences that are not UTF-8
_INVALID_UTF8 = (
    b'\xff',
    b'\xfe',
    b'\x80',  # a continuation byte alone
    b'\xc3',  # a lead byte without its continuation
    b'\xe2\x82',  # a three-byte sequence cut short
    b'\xc0\xaf',  # overlong '/'
    b'\xed\xa0\x80',  # an encoded surrogate (U+D800)
    b'\xf8\x88\x80\x80\x80',  # a five-byte form
    b'caf\xe9',  # Latin-1 'cafe' with an accent
)


def _mutate_bytes(rng: random.Random, raw: bytes) -> tuple[str, bytes]:
    """Byte-level damage of a file's bytes ``raw`` (UTF-8)."""
    kind = rng.randrange(12)
    at = rng.randrange(len(raw) + 1)
    if kind <= 2:  # one to three control characters (NUL and BEL most often)
        picks = [rng.choice((b'\x00', b'\x07', *_CONTROLS)) for _ in range(rng.randint(1, 3))]
        out = raw
        for c in picks:
            pos = rng.randrange(len(out) + 1)
            out = out[:pos] + c + out[pos:]
        return f'control characters {b"".join(picks)!r}', out
    if kind == 3:
        bad = rng.choice(_INVALID_UTF8)
        return f'invalid UTF-8 {bad!r} at byte {at}', raw[:at] + bad + raw[at:]
    if kind == 4:  # a Latin-1 or cp1252 comment, as a Windows editor saves it
        comment = '  # d\u00e9j\u00e0 vu\n'.encode('latin-1')
        return 'Latin-1 comment', raw.replace(b'\n', comment, 1)
    if kind == 5:  # a byte-order mark, once or twice (valid)
        return 'UTF-8 BOM', codecs.BOM_UTF8 * rng.randint(1, 2) + raw
    if kind == 6:  # Windows, old Mac or mixed line ends (valid)
        ends = rng.choice((b'\r\n', b'\r', 'mixed'))
        if ends == 'mixed':
            lines = raw.split(b'\n')
            return 'mixed line ends', b''.join(
                ln + rng.choice((b'\r\n', b'\n')) for ln in lines[:-1]
            ) + lines[-1]
        return f'line ends {ends!r}', raw.replace(b'\n', ends)
    if kind == 7:  # UTF-16 with its BOM (valid), or without (NUL bytes everywhere)
        text = raw.decode('utf-8')
        if rng.random() < 0.5:
            return 'UTF-16 with BOM', text.encode('utf-16')
        return 'UTF-16 without BOM', text.encode('utf-16-le')
    if kind == 8:  # flipped bits
        out = bytearray(raw)
        for _ in range(rng.randint(1, 4)):
            out[rng.randrange(len(out))] ^= 1 << rng.randrange(8)
        return 'flipped bits', bytes(out)
    if kind == 9:  # a damaged disk's tail of zeros, or zeros in place of a block
        n = rng.choice((1, 16, 512, 4096))
        if rng.random() < 0.5:
            return f'{n} zero bytes appended', raw + b'\x00' * n
        return f'{n} bytes zeroed at {at}', raw[:at] + b'\x00' * n + raw[at + n:]
    if kind == 10:  # cut in the middle of a multi-byte character
        accented = raw.replace(b'name: ', 'name: \u00e9t\u00e9_'.encode(), 1)
        cut = accented.index(b'\xc3') + 1 if b'\xc3' in accented else at
        return 'cut inside a UTF-8 character', accented[:cut]
    # a zero-width no-break space (a BOM) inside a key: valid UTF-8, invisible
    return 'BOM inside a key', raw.replace(b'robots:', b'rob\xef\xbb\xbfots:', 1)


def mutants(seed: int, count: int):
    """``count`` seeded mutants ``(label, data)`` of the shipped scenarios: the bytes of each
    file (a quarter byte-level damage, labelled ``NAME: bytes: ...``, a fifth text mutations,
    the rest mapping mutations).
    """
    rng = random.Random(seed)
    sources = [(p.name, p.read_text()) for p in SHIPPED]
    parsed = {name: yaml.safe_load(text) for name, text in sources}
    for _ in range(count):
        name, text = rng.choice(sources)
        draw = rng.random()
        if draw < 0.25:
            label, data = _mutate_bytes(rng, text.encode())
            yield f'{name}: bytes: {label}', data
            continue
        if draw < 0.45:
            label, out = _mutate_text(rng, text)
        else:
            label, mapping = _mutate_mapping(rng, parsed[name])
            try:
                out = yaml.safe_dump(mapping, sort_keys=False, width=1 << 30)
            except (RecursionError, yaml.YAMLError):
                continue
        yield f'{name}: {label}', out.encode()
