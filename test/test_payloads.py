"""Versioned JSON payloads (ros/payloads.py): the schemas in docs/schemas/ are the ones the nodes
use, good payloads round-trip, bad ones are rejected with a message naming the member, and a
fuzz of >= 1,000 bad payloads into the controller (/formation/graph, /formation/encounters) and the
coordinator (robot_<id>/mode) crashes nothing and is counted in their diagnostics.
"""

from __future__ import annotations

import copy
import json
import math
import os
from pathlib import Path
import signal
import subprocess

import numpy as np
from processes import program
import pytest

from ament_formation.ros import messages as m
from ament_formation.ros import payloads as pl

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / 'data'


def _good_graph() -> dict:
    return json.loads(
        m.graph_msg(m.GraphMessage(7, {0: None, 1: 0}, {1: (0.0, 1.2)}, (), 12.5, 13.5)).data
    )


def _good_encounters() -> dict:
    return json.loads(
        m.encounters_msg(
            m.EncountersMessage(
                4,
                {
                    0: {'mode': 'yield', 'partner': 1, 'direction': -1.0, 't_entry_s': 3.0,
                        'drift_mps': None, 'park_at_s': -math.inf},
                    1: {'mode': 'mutual', 'partner': 0, 'direction': 1.0, 't_entry_s': 3.0,
                        'drift_mps': [0.1, 0.0], 'park_at_s': 7.5},
                    2: {'mode': 'make_way', 'partner': 2, 'direction': 1.0, 't_entry_s': 0.0,
                        'drift_mps': None, 'park_at_s': 9.0},
                },
                {3: 0.25},
                2.0,
                41.5,
            )
        ).data
    )


def _good_mode() -> dict:
    return json.loads(m.mode_msg('obstacle', 'O1', 'ccw', avoiding=True).data)


GOOD = {pl.GRAPH_V1: _good_graph, pl.ENCOUNTERS_V2: _good_encounters, pl.MODE_V1: _good_mode}


# --------------------------------------------------------------------------- schemas and round
# trips
def test_docs_schemas_are_the_ones_in_use():
    folder = ROOT / 'docs' / 'schemas'
    for sid in pl.SCHEMAS:
        path = folder / pl.schema_filename(sid)
        assert path.read_text() == pl.schema_text(sid), (
            f'{path} is stale: python -m ament_formation.ros.payloads'
        )
        doc = json.loads(path.read_text())
        assert doc['$id'] == sid and doc['properties']['schema'] == {'const': sid}


def test_round_trips_carry_the_schema_version():
    for sid, make in GOOD.items():
        data = make()
        assert data['schema'] == sid
        assert pl.decode(json.dumps(data), sid) == data
    g = m.graph_from_msg(m.String(data=json.dumps(_good_graph())))
    assert (g.revision, g.parents, g.offsets_m, g.start_s) == (
        7,
        {0: None, 1: 0},
        {1: (0.0, 1.2)},
        13.5,
    )
    enc = m.encounters_from_msg(m.String(data=json.dumps(_good_encounters())))
    assert (enc.revision, enc.stamp_s, enc.mission_end_s, enc.rates) == (4, 2.0, 41.5, {3: 0.25})
    assert enc.assignments[0]['direction'] == -1.0 and enc.assignments[0]['drift_mps'] is None
    assert enc.assignments[0]['park_at_s'] == -math.inf  # null: the parking factor at once
    assert enc.assignments[1]['drift_mps'] == [0.1, 0.0] and enc.assignments[1]['park_at_s'] == 7.5
    assert enc.assignments[2]['mode'] == 'make_way' and enc.assignments[2]['park_at_s'] == 9.0
    # before the mission's end: null
    before = m.encounters_msg(m.EncountersMessage(1, {}, {0: 1.0}, 0.5))
    assert json.loads(before.data)['mission_end_s'] is None
    assert m.encounters_from_msg(before).mission_end_s is None
    mode = m.mode_from_msg(m.String(data=json.dumps(_good_mode())))
    assert mode == {'mode': 'obstacle', 'target': 'O1', 'direction': 'ccw', 'avoiding': True}


@pytest.mark.parametrize(
    'text, where',
    [
        ('{"schema": "ament_formation/graph/v2", "revision": 1}', '/schema: expected'),
        (
            '{"revision": 1, "parents": {}, "offsets_m": {}, "avoiding": [], '
            '"stamp_s": 0, "start_s": null}',
            "missing member 'schema'",
        ),
        (
            None,
            '/revision: must be of type integer',
        ),  # revision true (a boolean is not an integer)
        (
            pl.encode(_good_graph()).replace('"stamp_s":12.5', '"stamp_s":NaN'),
            'NaN is not a JSON number',
        ),
        (
            pl.encode(_good_graph()).replace('"stamp_s":12.5', '"stamp_s":1e400'),
            '/stamp_s: must be a finite',
        ),
        ('[' * 100_000 + ']' * 100_000, 'nested too deeply'),
        ('{"a": "' + 'x' * (pl.MAX_PAYLOAD_BYTES + 1) + '"}', 'exceeds'),
        (b'\xff\xfe', 'not JSON'),
    ],
)
def test_bad_graph_payloads_name_the_problem(text, where):
    if text is None:
        data = _good_graph()
        data['revision'] = True
        text = json.dumps(data)
    with pytest.raises(
        pl.PayloadError, match=f'^{pl.GRAPH_V1}: .*' + where.replace('[', r'\[')[:30]
    ):
        pl.decode(text, pl.GRAPH_V1)


def test_specific_members():
    data = _good_graph()
    data['parents']['x1'] = 0
    with pytest.raises(ValueError, match='/parents/x1: must match'):
        m.graph_from_msg(m.String(data=json.dumps(data)))
    data = _good_encounters()
    data['assignments']['0']['direction'] = 0.5
    with pytest.raises(ValueError, match='/assignments/0/direction: must be one of'):
        m.encounters_from_msg(m.String(data=json.dumps(data)))
    data = _good_encounters()
    data['rates']['3'] = 1.5  # a progress rate target is in [0, 1] (S17)
    with pytest.raises(ValueError, match='/rates/3: must be <= 1'):
        m.encounters_from_msg(m.String(data=json.dumps(data)))
    data = _good_encounters()
    data['assignments']['2']['mode'] = 'obstacle'  # robots decide their obstacle modes themselves
    with pytest.raises(ValueError, match='/assignments/2/mode: must be one of'):
        m.encounters_from_msg(m.String(data=json.dumps(data)))
    # an encounters/v1 payload (no rates, no mission end) is another version: refused
    data = _good_encounters()
    for key in ('rates', 'mission_end_s'):
        del data[key]
    for a in data['assignments'].values():
        del a['park_at_s']
    data['schema'] = 'ament_formation/encounters/v1'
    with pytest.raises(ValueError, match="/schema: expected 'ament_formation/encounters/v2'"):
        m.encounters_from_msg(m.String(data=json.dumps(data)))
    data = _good_graph()
    data['extra'] = 1
    with pytest.raises(ValueError, match="unexpected member 'extra'"):
        m.graph_from_msg(m.String(data=json.dumps(data)))
    data = _good_mode()
    data['since_s'] = 3.0  # a mode may carry more members (ignored)
    assert m.mode_from_msg(m.String(data=json.dumps(data)))['since_s'] == 3.0
    data['direction'] = 'up'
    with pytest.raises(ValueError, match='/direction'):
        m.mode_from_msg(m.String(data=json.dumps(data)))


# --------------------------------------------------------------------------- fuzz
_BAD_VALUE = {'__bad__': [1]}  # wrong wherever a schema member is: never a valid value or key


def _paths(value, prefix=()):
    """Every (path to a member) of a JSON value."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield (*prefix, k)
            yield from _paths(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield (*prefix, i)
            yield from _paths(v, (*prefix, i))


def _set(data, path, value):
    for p in path[:-1]:
        data = data[p]
    data[path[-1]] = value


def _delete(data, path):
    for p in path[:-1]:
        data = data[p]
    del data[path[-1]]


def bad_payloads(schema_id: str, n: int, seed: int) -> list[str]:
    """``n`` payloads, each invalid for ``schema_id`` by construction: truncated JSON text, a
    member replaced by an object, a required member deleted, an unknown member or schema version,
    a NaN, random bytes, a JSON value of another kind.
    """
    rng = np.random.default_rng(seed)
    good = GOOD[schema_id]()
    text = json.dumps(good)
    known = [p for p in _paths(good) if not (schema_id == pl.MODE_V1 and len(p) > 1)]
    schema = pl.SCHEMAS[schema_id]
    required = [(k,) for k in schema['required']]
    if schema_id == pl.ENCOUNTERS_V2:
        item = schema['properties']['assignments']['additionalProperties']
        required += [
            ('assignments', rid, k) for rid in good['assignments'] for k in item['required']
        ]
    out = []
    while len(out) < n:
        kind = len(out) % 8
        data = copy.deepcopy(good)
        if kind == 0:
            out.append(text[: int(rng.integers(0, len(text)))])  # truncated: never closed
        elif kind == 1:
            _set(data, known[int(rng.integers(len(known)))], _BAD_VALUE)
            out.append(json.dumps(data))
        elif kind == 2:
            _delete(data, required[int(rng.integers(len(required)))])
            out.append(json.dumps(data))
        elif kind == 3:
            version = int(schema_id.rsplit('v', 1)[1])  # another version than this one
            data['schema'] = f'{schema_id[:-1]}{version + int(rng.integers(1, 8))}'
            out.append(json.dumps(data))
        elif kind == 4:
            path = known[int(rng.integers(len(known)))]
            _set(data, path, float('nan'))
            out.append(json.dumps(data))  # NaN token
        elif kind == 5:
            out.append(rng.bytes(int(rng.integers(1, 64))).decode('latin-1'))
        elif kind == 6:
            out.append(json.dumps([good, 1, 'x', None][int(rng.integers(1, 4))]))
        else:
            if schema_id == pl.MODE_V1:
                data['mode'] = 'Obstacle avoidance!'  # not a mode name
            else:
                data[f'extra_{int(rng.integers(100))}'] = 1
            out.append(json.dumps(data))
    return out


def test_fuzzed_payloads_are_all_rejected_with_value_errors():
    for seed, sid in enumerate(pl.SCHEMAS):
        for text in bad_payloads(sid, 800, seed):
            with pytest.raises(pl.PayloadError):
                pl.decode(text, sid)


def test_fuzz_into_controller_and_coordinator(ros_context):
    """1,000 bad /formation/graph and 1,000 bad /formation/encounters payloads through the
    controller's callbacks, 1,000 bad robot_<id>/mode payloads through the coordinator's: nothing
    raises, every one is counted and reported (WARN) on /diagnostics, and good payloads still work.
    """
    from std_msgs.msg import String

    from ament_formation.core.control.switching import MODE_YIELD
    from ament_formation.nodes.controller import ControllerNode, ControllerParams
    from ament_formation.nodes.coordinator import CoordinatorNode, CoordinatorParams
    from ament_formation.ros import diagnostics as diag

    scenario = str(DATA / 'redundant_chain.yaml')
    ctrl = ControllerNode(
        context=ros_context,
        params=ControllerParams(scenario=scenario, robot_id=2),
        tick_timer=False,
    )
    coord = CoordinatorNode(
        context=ros_context,
        params=CoordinatorParams(scenario=scenario, encounter_rate_hz=1.0, markers_rate_hz=0.0),
    )
    try:
        for text in bad_payloads(pl.GRAPH_V1, 1000, 11):
            ctrl._on_graph(String(data=text))
        for text in bad_payloads(pl.ENCOUNTERS_V2, 1000, 12):
            ctrl._on_encounters(String(data=text))
        for k, text in enumerate(bad_payloads(pl.MODE_V1, 1000, 13)):
            coord._on_mode(k % 4, String(data=text))
        assert ctrl.rejected['graph'] == 1000 and ctrl.rejected['encounters'] == 1000
        assert coord.rejected['mode'] == 1000
        level, _, values = ctrl.rejections.status()
        assert (
            level == diag.WARN
            and values['rejected_graph'] == 1000
            and values['rejected_encounters'] == 1000
        )
        level, _, values = coord.rejections.status()
        assert level == diag.WARN and values['rejected_mode'] == 1000
        assert ctrl.graph is None and coord.modes == {}  # nothing bad was taken
        # still working: a good graph (robot 2 follows 3) and a good mode are taken
        ctrl._on_graph(
            m.graph_msg(m.GraphMessage(5, {0: None, 1: 0, 2: 3, 3: 0}, {2: (-0.5, 0.5)}))
        )
        b = ctrl.batch
        assert ctrl.graph.revision == 5 and b.state.parent[ctrl.r, b.row[2]] == b.row[3]
        np.testing.assert_allclose(b.state.offset[ctrl.r], (-0.5, 0.5))  # c_2 - c_3
        ctrl._on_encounters(
            m.encounters_msg(m.EncountersMessage(2, {2: _good_encounters()['assignments']['0']
                                                     | {'partner': 3}}, {0: 0.5}, 1.0))
        )
        assert ctrl.encounter_revision == 2
        assert tuple(b.state.assigned[ctrl.r, :3]) == (MODE_YIELD, b.row[3], -1.0)
        coord._on_mode(1, m.mode_msg('obstacle', 'O1', 'ccw', avoiding=True))
        assert coord.avoiding == {1}
    finally:
        ctrl.destroy_node()
        coord.destroy_node()


def test_fuzz_into_world_and_live_view(ros_context, tmp_path):
    """The other receivers: 1,000 bad /formation/graph payloads through the world's and the live
    view's callbacks, 1,000 bad /formation/encounters payloads through the world's and 1,000 bad
    robot_<id>/mode payloads through the live view's: nothing raises, every one is counted in
    their 'inputs' status (WARN), and a good graph and a good decision still work.
    """
    from std_msgs.msg import String

    from ament_formation.nodes.live_view import LiveViewNode, LiveViewParams
    from ament_formation.nodes.world import WorldNode, WorldParams
    from ament_formation.ros import diagnostics as diag

    scenario = str(DATA / 'paper_short.yaml')
    world = WorldNode(
        context=ros_context,
        params=WorldParams(
            scenario=scenario,
            pty_dir=str(tmp_path / 'pty'),
            camera_enabled=False,
            exit_at_end=False,
        ),
    )
    live = LiveViewNode(context=ros_context, params=LiveViewParams(scenario=scenario, port=0))
    try:
        for text in bad_payloads(pl.GRAPH_V1, 1000, 31):
            world._on_graph(String(data=text))
            live._on_graph(String(data=text))
        for k, text in enumerate(bad_payloads(pl.MODE_V1, 1000, 32)):
            live._on_mode(k % 2, String(data=text))
        for text in bad_payloads(pl.ENCOUNTERS_V2, 1000, 33):
            world._on_encounters(String(data=text))
        assert world.rejections.counts == {'graph': 1000, 'encounters': 1000}
        assert live.rejected['graph'] == 1000 and live.rejected['mode'] == 1000
        assert live.graph is None and live.modes == {} and world.start_s is None
        assert world.mission_end_s is None
        for node, expected in (
            (world, {'rejected_graph': 1000, 'rejected_encounters': 1000}),
            (live, {'rejected_mode': 1000}),
        ):
            statuses = {t.name: (lvl, vals) for t, lvl, _m, vals in node.diag._evaluate()}
            level, values = statuses[f'{node.get_name()}: inputs']
            assert level == diag.WARN and expected.items() <= values.items(), values
        good = m.graph_msg(m.GraphMessage(3, {0: None, 1: 0}, {}, start_s=12.5))
        world._on_graph(good)
        live._on_graph(good)
        assert world.start_s == 12.5 and live.graph.revision == 3 and live.start_s == 12.5
        # the mission's end (the world ends hold_s after it)
        world._on_encounters(m.encounters_msg(m.EncountersMessage(4, {}, {0: 1.0}, 30.0, 15.5)))
        assert world.mission_end_s == 15.5
    finally:
        live.destroy_node()
        world.destroy_node()


def test_running_controller_process_survives_bad_payloads(tmp_path):
    """Sanity check on the real program: formation_controller gets 60 bad graphs and 60 bad
    encounter payloads over DDS, stays up and reports each one in /diagnostics.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import HistoryPolicy, QoSProfile
    from std_msgs.msg import String

    from ament_formation.ros.executors import spin_until
    from ament_formation.ros.qos import QOS_DIAGNOSTICS, QOS_GRAPH

    proc = subprocess.Popen(
        [
            program('formation_controller'),
            '--ros-args',
            '-r',
            '__ns:=/robot_1',
            '-p',
            f'scenario:={DATA / "redundant_chain.yaml"}',
            '-p',
            'robot_id:=1',
        ],
        stdout=open(tmp_path / 'controller.log', 'w'),
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(os.environ['ROS_DOMAIN_ID']))
    node = rclpy.create_node('fuzzer', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    inputs: list[dict] = []

    def on_diag(arr):
        for st in arr.status:
            if st.name == 'formation_controller: robot_1 inputs':
                inputs.append({kv.key: kv.value for kv in st.values})

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, QOS_DIAGNOSTICS)
    # keep every sample until acknowledged (the controller's subscriptions keep the newest only)
    qos = QoSProfile(
        history=HistoryPolicy.KEEP_ALL,
        reliability=QOS_GRAPH.reliability,
        durability=QOS_GRAPH.durability,
    )
    graph_pub = node.create_publisher(String, '/formation/graph', qos)
    enc_pub = node.create_publisher(String, '/formation/encounters', qos)
    try:
        assert spin_until(
            ex,
            lambda: (
                bool(inputs)
                and graph_pub.get_subscription_count() > 0
                and enc_pub.get_subscription_count() > 0
            ),
            60.0,
        ), (tmp_path / 'controller.log').read_text()
        # The controller's subscriptions keep the newest sample only, so on a loaded machine a
        # payload sent while the last one waits is replaced, never read. Send in paced rounds and
        # top up with fresh bad payloads until the controller has rejected n of each; it must
        # never count more than were sent, and must still be running.
        n = 60
        graphs = iter(bad_payloads(pl.GRAPH_V1, 4 * n, 21))
        encounters = iter(bad_payloads(pl.ENCOUNTERS_V2, 4 * n, 22))
        sent = {'graph': 0, 'encounters': 0}

        def rejected(k: int = -1) -> dict:
            return {kind: int(inputs[k][f'rejected_{kind}']) for kind in sent}

        def settled() -> bool:  # two new reports since the last send, the last two alike
            seen = len(inputs)
            return spin_until(
                ex,
                lambda: len(inputs) >= seen + 2 and rejected(-1) == rejected(-2),
                30.0,
            )

        for _round in range(6):
            missing = {k: n - v for k, v in rejected().items()}
            if max(missing.values()) <= 0:
                break
            for i in range(max(missing.values())):
                if i < missing['graph']:
                    graph_pub.publish(String(data=next(graphs)))
                    sent['graph'] += 1
                if i < missing['encounters']:
                    enc_pub.publish(String(data=next(encounters)))
                    sent['encounters'] += 1
                spin_until(ex, lambda: False, 0.04)
            assert settled(), inputs[-3:]
        counts = rejected()
        assert all(n <= counts[k] <= sent[k] for k in sent), (counts, sent)
        assert proc.poll() is None, (tmp_path / 'controller.log').read_text()
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    assert 'Traceback' not in (tmp_path / 'controller.log').read_text()
