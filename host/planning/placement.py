"""Which node of the torus each cell goes to, so the cells that pass each other most rays sit on
linked nodes (`MeshPlan.balance` "objects").

Cells cut by the objects land on the torus as the k-d cuts halve it, but a cell's neighbours
in space are more than its four links: a ray for a cell on an unlinked node is relayed by a
node between (3x3 under a quarter share, balls at 400 spp: 26% of the rays crossing links were
relays). The cost pre-pass measures the rays each cell passes each other (its simulated mesh
sends straight to the taker); here cells trade places, two at a time, while that lowers the
rays relayed (the rays of each pair times the hops past the first between their nodes). The
cells and their work are the same; only their nodes change.
"""

import numpy as np

from protocols.topology import Torus

PASSES = 8  # rounds of trades at most (each: every cell's best trade, in turn)
# Cells traded at most: a round costs N^3 (8x8: 0.02 s of CPU for the whole search, 16x16:
# 1.3 s, past what planning may take as the mesh grows)
MAX_CELLS = 64


def placed(traffic: np.ndarray, torus: Torus) -> tuple[list[int], float, float]:
    """(node of each cell, rays relayed before, after): `traffic[i, j]` rays cell i passes
    cell j (each on its own node at first: cell i on node i). Pairwise trades, best first
    for each cell in turn, while any lowers the relays (never above the start); on a mesh
    of more than MAX_CELLS nodes the cells stay where they are."""
    n = torus.size
    pairs = np.asarray(traffic, float)
    pairs = pairs + pairs.T
    np.fill_diagonal(pairs, 0.0)
    extra = np.maximum(_hops(torus) - 1.0, 0.0)  # hops past the first: relays
    node = np.arange(n)
    before = after = _relayed(pairs, extra, node)
    for _ in range(PASSES if n <= MAX_CELLS else 0):
        traded = False
        for a in range(n):
            w = extra[node][:, node]  # between the nodes of each pair of cells
            gain = _trade_deltas(pairs, w, a)
            b = int(np.argmin(gain))
            if gain[b] < -1e-9 * max(after, 1.0):
                node[[a, b]] = node[[b, a]]
                after = _relayed(pairs, extra, node)
                traded = True
        if not traded:
            break
    return node.tolist(), before, after


def _hops(torus: Torus) -> np.ndarray:
    """`Torus.distance` between every two nodes, as one array."""
    row, col = np.divmod(np.arange(torus.size), torus.cols)
    dr = (row[None, :] - row[:, None]) % torus.rows
    dc = (col[None, :] - col[:, None]) % torus.cols
    return (np.minimum(dr, torus.rows - dr) + np.minimum(dc, torus.cols - dc)).astype(float)


def _relayed(pairs: np.ndarray, extra: np.ndarray, node: np.ndarray) -> float:
    """Rays relayed with cell i on node[i] (`pairs` symmetric: each pair once)."""
    return float((pairs * extra[node][:, node]).sum() / 2)


def _trade_deltas(pairs: np.ndarray, w: np.ndarray, a: int) -> np.ndarray:
    """Change in the rays relayed if cell a traded nodes with each cell b (0 for b = a):
    only pairs holding a or b change, sum over k of (pairs[a, k] - pairs[b, k]) times
    (w[b, k] - w[a, k]), the pair (a, b) itself unchanged."""
    full = w @ pairs[a] - pairs[a] @ w[a] - np.einsum("bk,bk->b", pairs, w) + pairs @ w[a]
    delta = full + 2.0 * pairs[a] * w[a]
    delta[a] = 0.0
    return delta


def sends(outcome) -> np.ndarray:
    """Rays each simulated node sent each other, nodes x nodes (the simulated mesh sends
    to the node taking them on, not through the nodes between)."""
    nodes = len(outcome.nodes)
    out = np.zeros((nodes, nodes))
    for n, record in enumerate(outcome.nodes):
        for m, rays in record.sent_to.items():
            out[n, m] += rays
    return out
