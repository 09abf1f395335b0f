"""Cells that divide the objects, whatever the view (`MeshPlan.balance` "objects").

Cells cut from the image follow the view: a scene whose objects gather in one region (a
fractal mountain under a wide sky) lands on one node, however many there are. Here the scene's
box is bisected recursively, as a k-d tree is built, along whichever world axis its objects
spread furthest on, at the position that leaves each side the share of the objects its nodes
will hold; the mesh of nodes is halved alongside (its columns, or its rows when it has more
of them), so the two halves of every cut land on two halves of the torus and most rays leaving
a cell enter a neighbour's. Cells may be any boxes: a ray is handed to whichever node's cell
holds it and routed there over as many links as it takes (`meshnode.engine.trace.owners`).

An object is counted where the centre of its bounds lies; one straddling a cut is held by both
sides, so the fullest node holds about 1/N of the objects plus those its cuts cross (and the
overlap's).
"""

import numpy as np

from meshnode.engine.tables import build_tables
from protocols.scene import SceneData


def object_cells(scene: SceneData, box, rows: int, cols: int):
    """(los, his), each (rows*cols, 3): node r*cols+c's cell, the cells tiling `box`, cut so
    that the node holding most objects (its cell's, those crossing its cuts included) holds
    as few as the cuts can make it."""
    tb = build_tables(scene)
    lo, hi = (np.asarray(b, float) for b in box)
    bounds = (tb.lo, tb.hi) if tb.n else (np.zeros((0, 3)), np.zeros((0, 3)))
    los, his = np.empty((rows * cols, 3)), np.empty((rows * cols, 3))
    _bisect(bounds, np.arange(tb.n), lo, hi, (0, rows, 0, cols), cols, los, his)
    return los, his


def _bisect(bounds, idx, lo, hi, block, cols, los, his) -> None:
    """Cut the box (lo, hi), which holds the objects `idx`, among the nodes of `block` (rows
    r0..r1, columns c0..c1 of the mesh): halve the block's longer side, and the box where
    the objects divide as the two halves' node counts do."""
    r0, r1, c0, c1 = block
    if (r1 - r0) * (c1 - c0) == 1:
        los[r0 * cols + c0], his[r0 * cols + c0] = lo, hi
        return
    if c1 - c0 >= r1 - r0:
        k = c0 + (c1 - c0) // 2
        first, second, nodes = (r0, r1, c0, k), (r0, r1, k, c1), (k - c0, c1 - k)
    else:
        k = r0 + (r1 - r0) // 2
        first, second, nodes = (r0, k, c0, c1), (k, r1, c0, c1), (k - r0, r1 - k)
    olo, ohi = bounds[0][idx], bounds[1][idx]
    axis, cut = _cut(olo, ohi, lo, hi, nodes)
    mid_hi, mid_lo = hi.copy(), lo.copy()
    mid_hi[axis] = mid_lo[axis] = cut
    _bisect(bounds, idx[olo[:, axis] <= cut], lo, mid_hi, first, cols, los, his)
    _bisect(bounds, idx[ohi[:, axis] >= cut], mid_lo, hi, second, cols, los, his)


CANDIDATES = 64  # cut positions tried on each axis, between the centres' quantiles


def _cut(olo: np.ndarray, ohi: np.ndarray, lo, hi, nodes: tuple[int, int]) -> tuple[int, float]:
    """(axis, position) of the cut whose fuller side, per node, holds fewest objects: the
    objects below it (those crossing it too) shared by `nodes[0]` nodes, those above by
    `nodes[1]`. Tried at CANDIDATES quantiles of the objects' centres on each axis (an object
    crossing the cut is held on both sides, so the cut that divides the count best is not
    always the one at the count's quantile: a tree's long branches)."""
    if not len(olo):
        axis = int(np.argmax(hi - lo))
        return axis, float(lo[axis] + nodes[0] / sum(nodes) * (hi[axis] - lo[axis]))
    share = nodes[0] / sum(nodes)
    q = np.clip(share + np.linspace(-0.5, 0.5, CANDIDATES) * min(share, 1 - share), 0, 1)
    best = (np.inf, 0, 0.0)
    for axis in range(3):
        centres = 0.5 * (olo[:, axis] + ohi[:, axis])
        cuts = np.clip(np.quantile(centres, q), lo[axis], hi[axis])
        below = np.searchsorted(np.sort(olo[:, axis]), cuts, side="right")
        above = len(olo) - np.searchsorted(np.sort(ohi[:, axis]), cuts, side="left")
        score = np.maximum(below / nodes[0], above / nodes[1])
        score += 1e-9 * np.abs(q - share)  # ties: nearest the even share
        i = int(np.argmin(score))
        if score[i] < best[0]:
            best = (float(score[i]), axis, float(cuts[i]))
    return best[1], best[2]
