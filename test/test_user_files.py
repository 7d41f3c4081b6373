"""Every file a user hands over is read safely (issue 33): scenarios, params files, camera,
board and reference-marker files, a campaign's and a run's files. A NUL, a BEL or another
control character, invalid UTF-8 or a Latin-1 file is one line naming the file, the line and the
column, exit code 2, never a traceback; a byte-order mark, Windows line ends and UTF-16 with its
BOM are read correctly. Through the core's one reader (core/config_files.py read_user_text) and
through the real programs: `formation sim`, `sweep --perturb/--replay`, `plot`, `run`,
`calibrate`, a node with a bad ``--params-file`` or scenario or camera file, and the robot and
camera-PC launchers.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import shutil
import subprocess

import pytest
import yaml

from ament_formation.core.config_files import (
    check_user_text,
    decode_user_bytes,
    program_file,
    read_user_text,
    read_user_yaml,
)
from ament_formation.core.errors import ConfigError, MAX_LINE_CHARS
from ament_formation.core.scenario.loader import dump_scenario, load_scenario, parse_scenario_text

ROOT = Path(__file__).resolve().parents[1]
SHORT = ROOT / 'test' / 'data' / 'paper_short.yaml'
CAMERA = ROOT / 'config' / 'camera.yaml'
BRIDGE_PARAMS = ROOT / 'config' / 'params' / 'formation_bridge.yaml'
TIMEOUT_S = 180.0  # a program's start on a loaded 2-core machine (imports, numba cache load)

# damage -> (bytes put in, the words of the refusal)
DAMAGE = {
    'nul': (b'\x00', 'NUL character (U+0000)'),
    'bel': (b'\x07', 'control character U+0007 (BEL)'),
    'esc': (b'\x1b[2K', 'control character U+001B (ESC)'),
    'del': (b'\x7f', 'control character U+007F (DEL)'),
    'c1': (b'\xc2\x9b', 'C1 control character U+009B'),
    'bad_utf8': (b'\xff', 'invalid UTF-8 (byte 0xff)'),
    'latin1': ('caf\u00e9 '.encode('latin-1'), 'invalid UTF-8 (byte 0xe9)'),
    'surrogate': (b'\xed\xa0\x80', 'invalid UTF-8 (byte 0xed'),
}


def _damaged(raw: bytes, marker: bytes, damage: bytes) -> tuple[bytes, str]:
    """``raw`` with ``damage`` put just before the first ``marker``, and where that is
    (``line L, column C`` of the column the damage starts; the Latin-1 word: its accent).
    """
    pos = raw.index(marker)
    text = raw[:pos].decode()
    line = text.count('\n') + 1
    column = pos - (raw.rfind(b'\n', 0, pos) + 1) + 1
    if damage.startswith(b'caf'):
        column += 3  # 'caf' is fine, the Latin-1 e-acute is not
    return raw[:pos] + damage + raw[pos:], f'line {line}, column {column}'


def _valid_variants(raw: bytes) -> dict[str, bytes]:
    text = raw.decode()
    return {
        'bom': b'\xef\xbb\xbf' + raw,
        'crlf': raw.replace(b'\n', b'\r\n'),
        'bom_crlf': b'\xef\xbb\xbf' + raw.replace(b'\n', b'\r\n'),
        'utf16': text.encode('utf-16'),
    }


def _one_line(proc: subprocess.CompletedProcess, *phrases: str) -> str:
    """The one line of ``proc``'s refusal (exit 2, no traceback), holding every phrase."""
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert len(lines) == 1 and 'Traceback' not in proc.stderr, proc.stderr[-2000:]
    assert len(lines[0]) < 300 + 40, lines[0]  # the program's name and MAX_LINE_CHARS
    for phrase in phrases:
        assert phrase in lines[0], (phrase, lines[0])
    return lines[0]


def _run(cmd: list[str], cwd: Path, timeout_s: float = TIMEOUT_S) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout_s)


def _formation(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return _run([program_file('formation'), *args], cwd)


# ------------------------------------------------------------------------------------------------
# The one reader
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize('kind', sorted(DAMAGE))
def test_each_damage_is_one_line_naming_file_line_and_column(tmp_path, kind):
    damage, words = DAMAGE[kind]
    data, where = _damaged(SHORT.read_bytes(), b'duration_s:', damage)
    path = tmp_path / f'{kind}.yaml'
    path.write_bytes(data)
    for read in (lambda: read_user_text(path, 'scenario'), lambda: load_scenario(path)):
        with pytest.raises(ConfigError) as info:
            read()
        line = str(info.value)
        assert line.startswith(f'{path}: {where}: {words}'), line
        assert '\n' not in line and len(line) <= MAX_LINE_CHARS


def test_every_control_character_but_tab_newline_and_cr_is_refused():
    for code in [*range(0x20), 0x7F, *range(0x80, 0xA0), 0xFFFE, 0xFFFF]:
        text = f'name: a\nduration_s: 1{chr(code)}\n'
        if code in (0x09, 0x0A, 0x0D):
            assert check_user_text(text, 'f.yaml', 'scenario') == text.replace('\r\n', '\n')
            continue
        with pytest.raises(ConfigError, match=r'f\.yaml: line 2, column 14: ') as info:
            check_user_text(text, 'f.yaml', 'scenario')
        assert f'U+{code:04X}' in str(info.value)
    assert check_user_text('a: caf\u00e9 \u2014 \U0001f916\n', None, 'x')  # any other text


@pytest.mark.parametrize(
    ('bad', 'shown'),
    [
        (b'\x80', '0x80'),  # a continuation byte alone
        (b'\xc3(', '0xc3'),  # a lead byte without its continuation
        (b'\xe2\x82', '0xe2 0x82'),  # cut short at the end of the file
        (b'\xc0\xaf', '0xc0'),  # overlong
        (b'\xf8\x88\x80\x80\x80', '0xf8'),  # five bytes
    ],
)
def test_invalid_utf8_names_its_bytes_and_where(bad, shown):
    data = b'name: x\nrobots:\n  - id: ' + bad
    with pytest.raises(ConfigError) as info:
        decode_user_bytes(data, 'f.yaml', 'scenario')
    assert str(info.value).startswith(f'f.yaml: line 3, column 9: invalid UTF-8 (byte {shown}')


def test_bom_crlf_and_utf16_are_read_as_the_same_text(tmp_path):
    raw = SHORT.read_bytes()
    want = raw.decode()
    variants = {
        **_valid_variants(raw),
        'two_boms': b'\xef\xbb\xbf' * 2 + raw,
        'utf16_be': b'\xfe\xff' + want.encode('utf-16-be'),
        'utf32': want.encode('utf-32'),
    }
    for name, data in variants.items():
        path = tmp_path / f'{name}.yaml'
        path.write_bytes(data)
        assert read_user_text(path, 'scenario') == want, name
        assert dump_scenario(load_scenario(path)) == dump_scenario(load_scenario(SHORT)), name
    # UTF-16 without its BOM is NUL bytes all over: refused, not guessed
    (tmp_path / 'utf16_nobom.yaml').write_bytes(want.encode('utf-16-le'))
    with pytest.raises(ConfigError, match='line 1, column 2: NUL character'):
        load_scenario(tmp_path / 'utf16_nobom.yaml')


def test_a_bom_inside_the_text_is_refused_where_it_is():
    """Invisible in a key (``rob<BOM>ots: unknown key (did you mean robots?)`` before): two files
    joined, the second with its byte-order mark.
    """
    text = SHORT.read_text()
    line = text[: text.index('robots:')].count('\n') + 1
    with pytest.raises(ConfigError) as info:
        parse_scenario_text(text.replace('robots:', 'rob\ufeffots:', 1), 'k.yaml')
    assert str(info.value).startswith(f'k.yaml: line {line}, column 4: byte-order mark U+FEFF')


def test_text_given_as_a_string_is_checked_too():
    """parse_scenario_text (campaigns, tests, the sweep's workers) gets the same checks: a BEL
    ended PyYAML's reader with a ReaderError before (outside the one-line refusal).
    """
    text = SHORT.read_text()
    bel = r'^s\.yaml: line 4, column 1: control character U\+0007'
    with pytest.raises(ConfigError, match=bel):
        parse_scenario_text(text.replace('duration_s', '\x07duration_s', 1), 's.yaml')
    assert parse_scenario_text('\ufeff' + text.replace('\n', '\r\n'), 's.yaml').name


def test_files_that_are_not_files_or_too_big(tmp_path):
    with pytest.raises(ConfigError, match='no such file'):
        read_user_text(tmp_path / 'nope.yaml', 'scenario')
    with pytest.raises(ConfigError, match='is a directory, not a scenario'):
        read_user_text(tmp_path, 'scenario')
    with pytest.raises(ConfigError, match='more than 1000 bytes; a scenario is at most 1000'):
        read_user_text('/dev/zero', 'scenario', max_bytes=1000)  # no size: read one more
    big = tmp_path / 'big.yaml'
    big.write_bytes(b'#' * 2000)
    with pytest.raises(ConfigError, match='file of 2000 bytes; a camera file is at most 1000'):
        read_user_text(big, 'camera file', max_bytes=1000)


def test_yaml_files_of_the_camera_and_calibration_go_through_the_reader(tmp_path):
    raw = CAMERA.read_bytes()
    for name, data in _valid_variants(raw).items():
        (tmp_path / f'{name}.yaml').write_bytes(data)
        assert read_user_yaml(tmp_path / f'{name}.yaml', 'camera file') == yaml.safe_load(raw)
    data, where = _damaged(raw, b'intrinsics:', b'\x00')
    (tmp_path / 'nul.yaml').write_bytes(data)
    with pytest.raises(ConfigError, match=f'nul.yaml: {where}: NUL'):
        read_user_yaml(tmp_path / 'nul.yaml', 'camera file')
    (tmp_path / 'dup.yaml').write_bytes(raw + b'\nfloor: {}\n')
    with pytest.raises(ConfigError, match="duplicate key 'floor'"):
        read_user_yaml(tmp_path / 'dup.yaml', 'camera file')


# ------------------------------------------------------------------------------------------------
# The programs
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope='module')
def damaged_scenarios(tmp_path_factory) -> tuple[Path, dict[str, tuple[Path, str, str]]]:
    """Damaged copies of paper_short.yaml: name -> (path, where, words)."""
    folder = tmp_path_factory.mktemp('damaged')
    raw = SHORT.read_bytes()
    files = {}
    for kind, (damage, words) in DAMAGE.items():
        data, where = _damaged(raw, b'robots:', damage)
        (folder / f'{kind}.yaml').write_bytes(data)
        files[kind] = (folder / f'{kind}.yaml', where, words)
    return folder, files


def test_formation_sim_refuses_damage_in_one_line_and_reads_bom_crlf_utf16(
    tmp_path, damaged_scenarios
):
    """The issue's case first: a NUL or a BEL ended `formation sim` with PyYAML's ReaderError
    traceback and exit 1.
    """
    _folder, files = damaged_scenarios
    for kind, (path, where, words) in files.items():
        proc = _formation('sim', str(path), '--out', str(tmp_path / kind), cwd=tmp_path)
        _one_line(proc, f'formation sim: {path}: {where}: {words}')
        assert not (tmp_path / kind).exists()
    ref = _formation('sim', str(SHORT), '--out', str(tmp_path / 'ref'), '--quiet', '--no-figure',
                     cwd=tmp_path)  # fmt: skip
    assert ref.returncode == 0, ref.stderr
    want = json.loads((tmp_path / 'ref' / 'metrics.json').read_text())
    for name, data in _valid_variants(SHORT.read_bytes()).items():
        path = tmp_path / f'{name}.yaml'
        path.write_bytes(data)
        out = tmp_path / f'out_{name}'
        proc = _formation('sim', str(path), '--out', str(out), '--quiet', '--no-figure',
                          cwd=tmp_path)  # fmt: skip
        assert proc.returncode == 0, (name, proc.stderr)
        got = json.loads((out / 'metrics.json').read_text())
        for key in ('prohibited_entries', 'min_clearance_m', 'min_inter_robot_distance_m'):
            assert got[key] == want[key], (name, key)


def test_formation_plot_sweep_and_run_refuse_damaged_files(tmp_path, damaged_scenarios):
    _folder, files = damaged_scenarios
    nul, where, words = files['nul']
    # sweep --perturb: the scenario it varies
    proc = _formation('sweep', '--perturb', str(nul), '--count', '2', '--workers', '0',
                      '--out', str(tmp_path / 'sw'), cwd=tmp_path)  # fmt: skip
    _one_line(proc, f'{nul}: {where}: {words}')
    # sweep --replay: a campaign's summary.json, runs.csv and failures/*.yaml
    campaign = tmp_path / 'campaign'
    (campaign / 'failures').mkdir(parents=True)
    (campaign / 'summary.json').write_bytes(b'{"seed": 1, "sensing": "ideal"\x07}')
    replay = ('sweep', '--replay', str(campaign), '--workers', '0', '--out', str(tmp_path / 'r'))
    _one_line(_formation(*replay, cwd=tmp_path), 'summary.json: line 1, column 31: control')
    (campaign / 'summary.json').write_text('{"seed": 1, "sensing": "ideal"}')
    (campaign / 'runs.csv').write_bytes(b'index,family\n1,formation\xff\n')
    _one_line(_formation(*replay, cwd=tmp_path), 'runs.csv: line 2, column 12: invalid UTF-8')
    (campaign / 'runs.csv').write_text('index,family\n1,formation\n')
    shutil.copy(files['bel'][0], campaign / 'failures' / '00001-formation.yaml')
    _one_line(_formation(*replay, cwd=tmp_path), f'00001-formation.yaml: {files["bel"][1]}: ')
    # plot: a run directory's scenario.yaml and run.json
    run = tmp_path / 'run'
    proc = _formation('sim', str(SHORT), '--out', str(run), '--quiet', '--no-figure', cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    good = (run / 'scenario.yaml').read_bytes()
    (run / 'scenario.yaml').write_bytes(good.replace(b'name:', b'\x00name:', 1))
    _one_line(_formation('plot', str(run), cwd=tmp_path), 'scenario.yaml: line ', ': NUL')
    (run / 'scenario.yaml').write_bytes(good)
    (run / 'run.json').write_bytes(b'\xef\xbb\xbf' + (run / 'run.json').read_bytes() + b'\xfe')
    _one_line(_formation('plot', str(run), cwd=tmp_path), 'run.json: line ', 'invalid UTF-8')
    # run: the whole system refuses before it starts anything
    bel, where, words = files['bel']
    proc = _formation('run', str(bel), '--out', str(tmp_path / 'sys'), cwd=tmp_path)
    _one_line(proc, f'formation run: {bel}: {where}: {words}')


def test_formation_calibrate_refuses_damaged_board_markers_and_camera_files(tmp_path):
    board = tmp_path / 'board.yaml'
    board.write_bytes(b'squares_x: 7\nsquares_y: 5\x00\n')
    proc = _formation('calibrate', 'intrinsics', 'a.png', '--board', str(board),
                      '--out', str(tmp_path / 'c.yaml'), cwd=tmp_path)  # fmt: skip
    _one_line(proc, f'{board}: line 2, column 13: NUL character')
    markers = tmp_path / 'refs.yaml'
    refs = (
        'size_m: 0.15\ndictionary: DICT_4X4_50\nmarkers:\n'
        '  - {id: 10, center_m: [0.2, 0.2]}\n  - {id: 11, center_m: [2.8, 0.2]}\n'
        '  - {id: 12, center_m: [1.5, 2.2]}\n'
    ).encode()
    markers.write_bytes(refs.replace(b'markers:', b'mark\xe9rs:'))
    proc = _formation('calibrate', 'floor', 'floor.png', '--markers', str(markers),
                      '--out', str(tmp_path / 'c.yaml'), cwd=tmp_path)  # fmt: skip
    _one_line(proc, f'{markers}: line 3, column 5: invalid UTF-8 (byte 0xe9)')
    markers.write_bytes(b'\xef\xbb\xbf' + refs.replace(b'\n', b'\r\n'))  # read correctly
    camera = tmp_path / 'camera.yaml'
    data, where = _damaged(CAMERA.read_bytes(), b'intrinsics:', b'\x1b[2K')
    camera.write_bytes(data)
    proc = _formation('calibrate', 'floor', 'floor.png', '--markers', str(markers),
                      '--camera', str(camera), '--out', str(tmp_path / 'c.yaml'),
                      cwd=tmp_path)  # fmt: skip
    _one_line(proc, f'{camera}: {where}: control character U+001B (ESC)')


def _node(name: str, *ros_args: str, cwd: Path) -> subprocess.CompletedProcess:
    return _run([program_file(name), '--ros-args', *ros_args], cwd)


def test_a_node_refuses_a_damaged_params_file_in_one_line(tmp_path):
    """The rcl library reads a params file itself: before, a BEL, a NUL or invalid UTF-8 made it
    log "Failed to parse global arguments" and rclpy.init raise (a traceback, exit 1).
    """
    raw = BRIDGE_PARAMS.read_bytes()
    ns = ('-r', '__ns:=/robot_0')
    for kind in ('nul', 'bel', 'bad_utf8', 'latin1'):
        damage, words = DAMAGE[kind]
        data, where = _damaged(raw, b'ros__parameters:', damage)
        path = tmp_path / f'{kind}.yaml'
        path.write_bytes(data)
        proc = _node('formation_bridge', *ns, '--params-file', str(path), cwd=tmp_path)
        _one_line(proc, f'formation_bridge: {path}: {where}: {words}')
    malformed = tmp_path / 'malformed.yaml'
    malformed.write_text('/**:\n  ros__parameters:\n    port: [/dev/ttyACM0\n')
    proc = _node('formation_bridge', *ns, '--params-file', str(malformed), cwd=tmp_path)
    _one_line(proc, f'{malformed}: malformed YAML at line 4, column 1')
    not_ros = tmp_path / 'not_ros.yaml'  # well-formed YAML that rcl refuses: its reason
    not_ros.write_text('/**:\n  ros__parameters:\n    port: x\n  other: 2\n')
    proc = _node('formation_bridge', *ns, '--params-file', str(not_ros), cwd=tmp_path)
    _one_line(proc, f'{not_ros}: not a ROS params file: Cannot have a value before '
                    'ros__parameters at line 4')  # fmt: skip
    # a BOM, CRLF and UTF-16 are read (by us and by rcl): the port named in the file is used
    text = '/**:\n  ros__parameters:\n    port: /nonexistent/tty_{}\n'
    for name in ('bom', 'crlf', 'utf16'):
        data = _valid_variants(text.format(name).encode())[name]
        path = tmp_path / f'{name}.yaml'
        path.write_bytes(data)
        proc = _node('formation_bridge', *ns, '--params-file', str(path), cwd=tmp_path)
        _one_line(proc, f'port: cannot open /nonexistent/tty_{name}')


def test_nodes_refuse_a_damaged_scenario_or_camera_file_in_one_line(tmp_path, damaged_scenarios):
    _folder, files = damaged_scenarios
    bel, where, words = files['bel']
    proc = _node('formation_coordinator', '-p', f'scenario:={bel}', cwd=tmp_path)
    _one_line(proc, f'formation_coordinator: {bel}: {where}: {words}')
    camera = tmp_path / 'camera.yaml'
    data, where = _damaged(CAMERA.read_bytes(), b'intrinsics:', b'\xff')
    camera.write_bytes(data)
    proc = _node('formation_tracker', '-p', f'camera_config:={camera}', cwd=tmp_path)
    _one_line(proc, f'formation_tracker: {camera}: {where}: invalid UTF-8 (byte 0xff)')


def test_the_launchers_refuse_a_damaged_scenario_or_params_file_in_one_line(
    tmp_path, damaged_scenarios
):
    _folder, files = damaged_scenarios
    nul, where, words = files['nul']
    robot = [str(ROOT / 'scripts' / 'launch_robot.sh'), '--id', '0', '--port', 'loop://']
    base = [str(ROOT / 'scripts' / 'launch_base.sh')]
    env_run = dict(os.environ)
    for launcher in (robot, base):
        proc = subprocess.run([*launcher, '--scenario', str(nul), '--loopback'],
                              capture_output=True, text=True, timeout=TIMEOUT_S, env=env_run,
                              cwd=tmp_path)  # fmt: skip
        _one_line(proc, f'{nul}: {where}: {words}')
    params = tmp_path / 'params.yaml'
    params.write_bytes(b'/**:\n  ros__parameters:\n    pose_timeout_s: 0.5\x07\n')
    for launcher in (robot, base):
        proc = subprocess.run([*launcher, '--scenario', str(SHORT), '--params', str(params),
                               '--loopback'], capture_output=True, text=True, timeout=TIMEOUT_S,
                              env=env_run, cwd=tmp_path)  # fmt: skip
        _one_line(proc, f'{params}: line 3, column 24: control character U+0007 (BEL)')
