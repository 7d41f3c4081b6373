"""Run directories: write a finished run to disk and read it back (for ``formation plot DIR``).

Layout of a run directory::

    metrics.json       docs/design.md §4 metrics
    figure.png         the Fig. 4-like figure (written by the caller, see core/sim/plot.py)
    trajectories.csv   t_s, then per robot <id>: r<id>_x_m, r<id>_y_m, r<id>_theta_rad,
    r<id>_v_mps,
                       r<id>_omega_radps, r<id>_tau_left_nm, r<id>_tau_right_nm, r<id>_goal_x_m,
                       r<id>_goal_y_m, r<id>_avoiding (0/1), r<id>_saturated (0/1)
    obstacles.csv      t_s, then per obstacle <name>: <name>_x_m, <name>_y_m, <name>_phi_rad
    events.json        mode_events, graph_events, reaching (lists of dicts)
    run.json           scenario name, robot ids, obstacle names, dt_s, wall_time_s, format version
    scenario.yaml      the validated scenario as it ran (parse_scenario reads it back)

The core never prints; errors in a run directory raise ConfigError naming the file.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from ament_formation.core.config_files import parse_user_yaml, read_user_text
from ament_formation.core.errors import ConfigError
from ament_formation.core.scenario.loader import dump_scenario, parse_scenario, Scenario
from ament_formation.core.sim.trajectory import SimResult

FORMAT_VERSION = 1
ROBOT_COLUMNS = (
    'x_m',
    'y_m',
    'theta_rad',
    'v_mps',
    'omega_radps',
    'tau_left_nm',
    'tau_right_nm',
    'goal_x_m',
    'goal_y_m',
    'avoiding',
    'saturated',
)
OBSTACLE_COLUMNS = ('x_m', 'y_m', 'phi_rad')


def _write_csv(path: Path, header: list[str], table: np.ndarray, int_cols: set[int]) -> None:
    buf = io.StringIO()
    fmt = ['%d' if c in int_cols else '%.10g' for c in range(table.shape[1])]
    np.savetxt(buf, table, fmt=fmt, delimiter=',', header=','.join(header), comments='')
    path.write_text(buf.getvalue())


def write_run(out_dir, result: SimResult, scenario: Scenario, metrics: dict | None = None) -> Path:
    """Write ``result`` (and ``metrics`` when given) into ``out_dir`` (created). Returns the
    path.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigError('exists and is not a directory', file=str(out))
    out.mkdir(parents=True, exist_ok=True)
    t = np.asarray(result.t_s, dtype=float)
    n_t = len(t)

    header = ['t_s']
    cols = [t[:, None]]
    int_cols: set[int] = set()
    for i, rid in enumerate(result.robot_ids):
        header += [f'r{rid}_{c}' for c in ROBOT_COLUMNS]
        block = np.concatenate(
            [
                result.state[:, i, :],
                result.torque_nm[:, i, :],
                result.goal_m[:, i, :],
                np.asarray(result.avoiding[:, i], dtype=float)[:, None],
                np.asarray(result.saturated[:, i], dtype=float)[:, None],
            ],
            axis=1,
        )
        base = sum(c.shape[1] for c in cols)
        int_cols |= {base + 9, base + 10}
        cols.append(block)
    _write_csv(
        out / 'trajectories.csv', header, np.concatenate(cols, axis=1).reshape(n_t, -1), int_cols
    )

    oheader = ['t_s']
    ocols = [t[:, None]]
    for j, name in enumerate(result.obstacle_names):
        oheader += [f'{name}_{c}' for c in OBSTACLE_COLUMNS]
        ocols.append(
            np.concatenate(
                [result.obstacle_center_m[:, j, :], result.obstacle_phi_rad[:, j, None]], axis=1
            )
        )
    _write_csv(
        out / 'obstacles.csv', oheader, np.concatenate(ocols, axis=1).reshape(n_t, -1), set()
    )

    events = {
        'mode_events': result.mode_events,
        'graph_events': result.graph_events,
        'reaching': result.reaching,
    }
    (out / 'events.json').write_text(json.dumps(_plain(events), indent=1) + '\n')
    meta = {
        'format_version': FORMAT_VERSION,
        'scenario': result.scenario_name,
        'robot_ids': list(result.robot_ids),
        'obstacle_names': list(result.obstacle_names),
        'dt_s': float(result.dt_s),
        'wall_time_s': float(result.wall_time_s),
        'samples': n_t,
    }
    (out / 'run.json').write_text(json.dumps(meta, indent=1) + '\n')
    (out / 'scenario.yaml').write_text(dump_scenario(scenario))
    if metrics is not None:
        write_metrics(out, metrics)
    return out


def write_metrics(out_dir, metrics: dict) -> Path:
    """``out_dir/metrics.json`` (indented, keys in docs/design.md §4 order)."""
    path = Path(out_dir) / 'metrics.json'
    path.write_text(json.dumps(_plain(metrics), indent=2) + '\n')
    return path


def _plain(value):
    from ament_formation.core.sim.metrics import json_ready

    return json_ready(value)


_RUN_FILE_MAX_BYTES = 200_000_000  # a run directory's JSON and YAML files (events of long runs)


def _read_json(path: Path) -> dict:
    if not path.exists():
        raise ConfigError('missing (not a run directory of `formation sim`?)', file=str(path))
    text = read_user_text(path, 'run file', _RUN_FILE_MAX_BYTES)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise ConfigError(
            f'invalid JSON at line {err.lineno}, column {err.colno}: {err.msg}', file=str(path)
        ) from None
    except RecursionError:
        raise ConfigError('invalid JSON: nested too deep', file=str(path)) from None
    if not isinstance(data, dict):
        raise ConfigError('must be a JSON object', file=str(path))
    return data


def _read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    try:
        with path.open() as fh:
            header = next(csv.reader([fh.readline()]))
            table = np.loadtxt(fh, delimiter=',', ndmin=2)
    except FileNotFoundError:
        raise ConfigError(
            'missing (not a run directory of `formation sim`?)', file=str(path)
        ) from None
    except ValueError as err:
        raise ConfigError(f'malformed CSV: {err}', file=str(path)) from None
    if table.size and table.shape[1] != len(header):
        raise ConfigError(
            f'{table.shape[1]} columns but {len(header)} header names', file=str(path)
        )
    return header, table.reshape(-1, len(header))


def _column(header: list[str], table: np.ndarray, name: str, path: Path) -> np.ndarray:
    try:
        return table[:, header.index(name)]
    except ValueError:
        raise ConfigError('missing column', field=name, file=str(path)) from None


def read_run(run_dir) -> tuple[SimResult, Scenario, dict | None]:
    """Load a run directory: (SimResult, Scenario, metrics or None)."""
    root = Path(run_dir)
    if not root.is_dir():
        raise ConfigError('no such run directory', file=str(root))
    meta = _read_json(root / 'run.json')
    scen_path = root / 'scenario.yaml'
    if not scen_path.exists():
        raise ConfigError('missing', file=str(scen_path))
    text = read_user_text(scen_path, 'scenario', _RUN_FILE_MAX_BYTES)
    scenario = parse_scenario(parse_user_yaml(text, str(scen_path), 'scenario'), str(scen_path))
    try:
        ids = [int(i) for i in meta['robot_ids']]
        names = [str(n) for n in meta['obstacle_names']]
    except (KeyError, TypeError, ValueError) as err:
        raise ConfigError(
            f'robot_ids and obstacle_names: lists expected ({type(err).__name__})',
            file=str(root / 'run.json'),
        ) from None

    tpath = root / 'trajectories.csv'
    header, table = _read_csv(tpath)
    t = _column(header, table, 't_s', tpath)
    n_t = len(t)

    def robot_cols(rid, names_):
        return np.stack([_column(header, table, f'r{rid}_{c}', tpath) for c in names_], axis=-1)

    state = np.stack([robot_cols(r, ROBOT_COLUMNS[:5]) for r in ids], axis=1).reshape(
        n_t, len(ids), 5
    )
    torque = np.stack([robot_cols(r, ROBOT_COLUMNS[5:7]) for r in ids], axis=1).reshape(
        n_t, len(ids), 2
    )
    goal = np.stack([robot_cols(r, ROBOT_COLUMNS[7:9]) for r in ids], axis=1).reshape(
        n_t, len(ids), 2
    )
    avoiding = (
        np.stack([_column(header, table, f'r{r}_avoiding', tpath) for r in ids], axis=1) > 0.5
    )
    saturated = (
        np.stack([_column(header, table, f'r{r}_saturated', tpath) for r in ids], axis=1) > 0.5
    )

    opath = root / 'obstacles.csv'
    oheader, otable = _read_csv(opath)
    if len(otable) != n_t:
        raise ConfigError(f'{len(otable)} rows but trajectories.csv has {n_t}', file=str(opath))
    centers = np.zeros((n_t, len(names), 2))
    phis = np.zeros((n_t, len(names)))
    for j, name in enumerate(names):
        centers[:, j, 0] = _column(oheader, otable, f'{name}_x_m', opath)
        centers[:, j, 1] = _column(oheader, otable, f'{name}_y_m', opath)
        phis[:, j] = _column(oheader, otable, f'{name}_phi_rad', opath)

    events = _read_json(root / 'events.json') if (root / 'events.json').exists() else {}
    metrics = _read_json(root / 'metrics.json') if (root / 'metrics.json').exists() else None
    result = SimResult(
        scenario_name=str(meta.get('scenario', scenario.name)),
        robot_ids=tuple(ids),
        obstacle_names=tuple(names),
        t_s=t,
        state=state,
        torque_nm=torque,
        goal_m=goal,
        avoiding=avoiding,
        saturated=saturated,
        obstacle_center_m=centers,
        obstacle_phi_rad=phis,
        mode_events=list(events.get('mode_events', [])),
        graph_events=list(events.get('graph_events', [])),
        reaching=list(events.get('reaching', [])),
        dt_s=float(meta.get('dt_s', 0.001)),
        wall_time_s=float(meta.get('wall_time_s', 0.0)),
    )
    return result, scenario, metrics
