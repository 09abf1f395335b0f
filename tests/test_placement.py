"""Cells placed on the torus so the rays they pass each other cross links, not relays
(`host.planning.placement`)."""

import itertools

import numpy as np
import pytest

from host.planning.placement import MAX_CELLS, _hops, _relayed, _trade_deltas, placed
from protocols.topology import Torus


def relays(traffic: np.ndarray, torus: Torus, node) -> float:
    """Rays relayed, counted pair by pair: rays from cell i to cell j cross
    distance(node i, node j) links, so all but the first hop are relays."""
    return sum(
        traffic[i, j] * max(torus.distance(node[i], node[j]) - 1, 0)
        for i in range(torus.size)
        for j in range(torus.size)
    )


@pytest.mark.parametrize("shape", [(2, 2), (3, 3), (2, 3), (4, 4)])
def test_a_trade_changes_the_relays_by_what_it_says(shape):
    torus = Torus(*shape)
    n = torus.size
    rng = np.random.default_rng(n)
    traffic = rng.integers(0, 50, (n, n)).astype(float)
    np.fill_diagonal(traffic, 0)
    pairs = traffic + traffic.T
    extra = np.array([[max(torus.distance(a, b) - 1, 0) for b in range(n)] for a in range(n)])
    node = rng.permutation(n)
    base = relays(traffic, torus, node)
    assert _relayed(pairs, extra.astype(float), node) == pytest.approx(base)
    for a in range(n):
        deltas = _trade_deltas(pairs, extra[node][:, node].astype(float), a)
        for b in range(n):
            swapped = node.copy()
            swapped[[a, b]] = swapped[[b, a]]
            assert deltas[b] == pytest.approx(relays(traffic, torus, swapped) - base)


@pytest.mark.parametrize("shape", [(3, 3), (2, 3), (4, 4)])
def test_placed_cells_relay_fewer_rays_and_each_node_gets_one(shape):
    torus = Torus(*shape)
    n = torus.size
    rng = np.random.default_rng(7)
    traffic = rng.exponential(1.0, (n, n)) ** 3  # a few pairs pass most rays
    np.fill_diagonal(traffic, 0)
    node, before, after = placed(traffic, torus)
    assert sorted(node) == list(range(n))
    assert before == pytest.approx(relays(traffic, torus, list(range(n))))
    assert after == pytest.approx(relays(traffic, torus, node))
    assert after < before


def test_two_cells_on_a_diagonal_move_next_to_each_other():
    # On a 3x3 torus node 0 (row 0, column 0) and node 4 (row 1, column 1) are two hops
    # apart: every ray between their cells is relayed until one of them moves.
    torus = Torus(3, 3)
    traffic = np.zeros((9, 9))
    traffic[0, 4] = traffic[4, 0] = 100.0
    node, before, after = placed(traffic, torus)
    assert before == 200.0 and after == 0.0
    assert torus.distance(node[0], node[4]) == 1


def test_traffic_only_between_linked_nodes_stays_put():
    torus = Torus(3, 3)
    traffic = np.zeros((9, 9))
    for a, b in itertools.product(range(9), repeat=2):
        if torus.distance(a, b) == 1:
            traffic[a, b] = 1.0 + a + b
    node, before, after = placed(traffic, torus)
    assert node == list(range(9)) and before == after == 0.0


def test_past_max_cells_the_cells_stay_put():
    # the search costs N^3 a round: past MAX_CELLS nodes planning would grow with the mesh
    torus = Torus(9, 9)
    assert torus.size > MAX_CELLS
    traffic = np.zeros((81, 81))
    traffic[0, 40] = 5.0
    node, before, after = placed(traffic, torus)
    assert node == list(range(81)) and before == after > 0


@pytest.mark.parametrize("shape", [(3, 3), (2, 5), (4, 4)])
def test_hops_are_the_toruss_distances(shape):
    torus = Torus(*shape)
    n = torus.size
    expected = [[torus.distance(a, b) for b in range(n)] for a in range(n)]
    assert _hops(torus).tolist() == expected
