"""S9 graph rewiring: the worked example of the spec, and properties for random digraphs."""

from __future__ import annotations

from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from ament_formation.core.control.rewiring import FormationGraph
from ament_formation.core.errors import ConfigError
from ament_formation.core.scenario.loader import load_scenario

ROOT = Path(__file__).resolve().parents[1]
S9_EDGES = ((0, 1), (0, 2), (1, 3), (2, 4), (1, 2), (2, 1), (4, 3), (3, 4))


def s9_graph() -> FormationGraph:
    slots = {0: (0, 0), 1: (-0.4, 0.4), 2: (-0.4, -0.4), 3: (-0.8, 0.8), 4: (-0.8, -0.8)}
    return FormationGraph(robot_ids=(0, 1, 2, 3, 4), edges=S9_EDGES, leaders=(0,), slots=slots)


# ---------------------------------------------------------------------------------------------
# The worked example of S9 (scenario 2 edges)
# ---------------------------------------------------------------------------------------------


def test_s9_original_tree_is_bfs_from_the_leader():
    assert s9_graph().original_parent == {0: None, 1: 0, 2: 0, 3: 1, 4: 2}


def test_s9_r1_avoids():
    g = s9_graph()
    parents = g.rewire({1})
    assert FormationGraph.partition(parents) == {0: {0, 2, 4, 3}, 1: {1}}
    assert parents[3] == 4  # R3 re-parented from R1 to R4 via 4 -> 3
    np.testing.assert_allclose(g.offset(3, 4), [0.0, 1.6])  # delta = c3 - c4


def test_s9_r1_then_r4_avoid():
    parents = s9_graph().rewire({1, 4})
    assert FormationGraph.partition(parents) == {0: {0, 2}, 1: {1, 3}, 4: {4}}
    assert parents[3] == 1


def test_s9_mutual_r1_r2_lower_id_gets_shared_vertices():
    parents = s9_graph().rewire({2, 1})
    assert FormationGraph.partition(parents) == {0: {0}, 1: {1, 3, 4}, 2: {2}}
    assert parents[4] == 3  # R4 re-parented to R3 via 3 -> 4


def test_s9_restoration_after_each_exit():
    g = s9_graph()
    assert g.rewire({1, 4}) != g.original_parent
    assert g.rewire({1}) == s9_graph().rewire({1})
    assert g.rewire(()) == g.original_parent


def test_graph_from_v_formation_scenario_has_two_teams():
    g = FormationGraph.from_scenario(
        load_scenario(ROOT / 'config' / 'scenarios' / 'v_formation.yaml')
    )
    assert g.team_leader == {0: 0, 1: 0, 2: 0, 3: 0, 4: 0, 5: 5}
    assert g.rewire({1}) == {0: None, 1: None, 2: 0, 3: 4, 4: 2, 5: None}


def test_naive_rule_counterexample_stays_a_tree():
    # S9 step 2 warning: "keep the original parent else take the BFS parent" can make a 2-cycle.
    # 0 -> 1 -> 2 -> 3, 0 -> 4 -> 3, 3 -> 2: with 1 avoiding, 2 must hang below 3 (from 4), not
    # form 2 <-> 3.
    g = FormationGraph(
        robot_ids=(0, 1, 2, 3, 4),
        edges=((0, 1), (1, 2), (2, 3), (0, 4), (4, 3), (3, 2)),
        leaders=(0,),
    )
    assert g.original_parent == {0: None, 1: 0, 2: 1, 3: 4, 4: 0}
    parents = g.rewire({1})
    assert parents == {0: None, 1: None, 2: 3, 3: 4, 4: 0}
    assert FormationGraph.root_of(parents, 2) == 0


def test_bad_graphs_are_rejected():
    with pytest.raises(ConfigError, match='self-loop'):
        FormationGraph(robot_ids=(0, 1), edges=((0, 1), (1, 1)), leaders=(0,))
    with pytest.raises(ConfigError, match='unknown robot'):
        FormationGraph(robot_ids=(0, 1), edges=((0, 2),), leaders=(0,))
    with pytest.raises(ConfigError, match='cannot be reached'):
        FormationGraph(robot_ids=(0, 1, 2), edges=((0, 1),), leaders=(0,))
    with pytest.raises(ValueError, match='not in the graph'):
        s9_graph().rewire({9})


# ---------------------------------------------------------------------------------------------
# Properties for random digraphs with leaders and random avoider sets
# ---------------------------------------------------------------------------------------------


@st.composite
def graphs(draw):
    """A random digraph on n vertices where every vertex is reachable from one of 1-3 leaders."""
    n = draw(st.integers(2, 12))
    n_leaders = draw(st.integers(1, min(3, n)))
    ids = draw(st.permutations(list(range(n))))  # ids not in BFS order
    leaders = sorted(ids[:n_leaders])
    edges = set()
    # spanning structure: each non-leader gets an edge from some earlier vertex
    for k in range(n_leaders, n):
        parent = ids[draw(st.integers(0, k - 1))]
        edges.add((parent, ids[k]))
    # random extra edges, never into... anything goes except self-loops
    extra = draw(st.lists(st.tuples(st.sampled_from(ids), st.sampled_from(ids)), max_size=3 * n))
    edges |= {(u, v) for u, v in extra if u != v}
    slots = {i: (float(i), -float(i)) for i in ids}
    graph = FormationGraph(
        robot_ids=tuple(ids), edges=tuple(sorted(edges)), leaders=tuple(leaders), slots=slots
    )
    avoiding = draw(st.sets(st.sampled_from(ids)))
    return graph, avoiding


def _check_forest(graph: FormationGraph, avoiding: set[int], parents: dict) -> None:
    ids = set(graph.robot_ids)
    roots = set(graph.leaders) | avoiding
    edges = set(graph.edges)
    # covers every robot, exactly once
    assert set(parents) == ids
    # roots are exactly leaders and avoiders
    assert {v for v, p in parents.items() if p is None} == roots
    for child, parent in parents.items():
        if parent is not None:
            assert (parent, child) in edges  # each parent edge exists in G
            assert child not in roots  # no edge into a root survives pruning
    # acyclic and every vertex reaches a root
    for v in ids:
        assert FormationGraph.root_of(parents, v) in roots


@settings(max_examples=120, deadline=None)
@given(graphs())
def test_rewired_graph_is_a_forest_rooted_at_leaders_and_avoiders(case):
    graph, avoiding = case
    _check_forest(graph, avoiding, graph.rewire(avoiding))


@settings(max_examples=60, deadline=None)
@given(graphs())
def test_no_avoiders_gives_the_original_tree(case):
    graph, _ = case
    assert graph.rewire(()) == graph.original_parent
    _check_forest(graph, set(), graph.original_parent)


@settings(max_examples=60, deadline=None)
@given(graphs(), st.randoms(use_true_random=False))
def test_restoration_after_exits_in_any_order(case, rnd):
    """Avoiders enter one by one, exit in a random order: each step equals the fresh rewiring of
    the current set (no history), and after the last exit the original tree is back (S9 step 6).
    """
    graph, avoiding = case
    current: set[int] = set()
    order = sorted(avoiding)
    rnd.shuffle(order)
    for a in order:
        current.add(a)
        assert graph.rewire(current) == graph.rewire(sorted(current, reverse=True))
    exits = list(order)
    rnd.shuffle(exits)
    for a in exits:
        current.discard(a)
        parents = graph.rewire(current)
        _check_forest(graph, current, parents)
    assert graph.rewire(current) == graph.original_parent


@settings(max_examples=60, deadline=None)
@given(graphs())
def test_unaffected_robots_keep_their_original_parent(case):
    """A robot none of whose original ancestors (itself included) avoids keeps pi0."""
    graph, avoiding = case
    parents = graph.rewire(avoiding)
    pi0 = graph.original_parent
    for v in graph.robot_ids:
        chain, u = [], v
        while u is not None:
            chain.append(u)
            u = pi0[u]
        if not set(chain) & avoiding:
            assert parents[v] == pi0[v]


@settings(max_examples=40, deadline=None)
@given(graphs())
def test_offsets_keep_the_formation_geometry(case):
    """delta_vk = c_v - c_k for any new parent: following the tree from a root reproduces the
    slots.
    """
    graph, avoiding = case
    parents = graph.rewire(avoiding)
    offsets = graph.offsets(parents)
    for v in graph.robot_ids:
        total, u = np.zeros(2), v
        while parents[u] is not None:
            total += offsets[u]
            u = parents[u]
        np.testing.assert_allclose(total, np.subtract(graph.slots[v], graph.slots[u]), atol=1e-12)
