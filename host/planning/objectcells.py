"""Cells that divide the objects, whatever the view (`MeshPlan.balance` "objects").

Cells cut from the image follow the view: a scene whose objects gather in one region (a
fractal mountain under a wide sky) lands on one node, however many there are. Here the scene's
box is bisected recursively, as a k-d tree is built, along whichever world axis its objects
spread furthest on, at the position that leaves each side the share of the objects its nodes
will hold; the mesh of nodes is halved alongside (its columns, or its rows when it has more
of them; a square block its columns: halving its rows makes the same cells, transposed on
the torus, since each cut picks its own axis), so the two halves of every cut land on two
halves of the torus and most rays leaving a cell enter a
neighbour's. Cells may be any boxes: a ray is handed to whichever node's cell
holds it and routed there over as many links as it takes (`meshnode.engine.locator.owners`).

An object straddling a cut is held by both sides, so the fullest node holds about 1/N of the
objects plus those its cuts cross (and the overlap's). With an estimate of where in space the
work lies (the cost pre-pass's, `host.planning.objectwork`), each cut instead evens the work of
the two sides per node, among the cuts that leave each side at most SLACK times the fewest
objects per node the cut could leave, and never more than a limit (the memory budget's):
memory first, then work.
"""

import numpy as np

from host.scene.derived import kept, scene_tables
from protocols.scene import SceneData

CANDIDATES = 64  # cut positions tried on each axis
# A work-evening cut may leave this much over the fewest objects a node (never over the limit):
# the room left under a budget takes the hottest cells' copies (`host.planning.replicas`)
SLACK = 1.25


def object_cells(scene: SceneData, box, rows: int, cols: int, work=None, limit=None):
    """(los, his), each (rows*cols, 3): node r*cols+c's cell, the cells tiling `box`. Without
    `work`, cut so that the node holding most objects (its cell's, and those crossing its
    cuts) holds as few as the cuts can make it; with `work` (a `WorkGrid`: where in space
    the work lies), so that the nodes' work is even, each side of a cut holding at most
    SLACK times the fewest objects per node that cut could leave, and at most `limit`."""
    tb = scene_tables(scene)
    lo, hi = (np.asarray(b, float) for b in box)
    bounds = (tb.lo, tb.hi) if tb.n else (np.zeros((0, 3)), np.zeros((0, 3)))
    los, his = np.empty((rows * cols, 3)), np.empty((rows * cols, 3))
    cut = _Cutter(bounds, work, limit, kept(scene, "sorted bounds", lambda: _sorted(*bounds)))
    cut.bisect(np.arange(tb.n), lo, hi, (0, rows, 0, cols), cols, los, his)
    return los, his


class WorkGrid:
    """Where in space the work lies: work per voxel of a grid over the scene's box (`lo`,
    `hi`, `density` indexed x, y, z). Work is spatial, not only per object: a teapot's floor
    is one object whose work (eye rays, shadow rays) spreads over the whole floor."""

    def __init__(self, lo, hi, density: np.ndarray):
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.density = np.asarray(density, float)
        self.edges = [
            np.linspace(self.lo[a], self.hi[a], self.density.shape[a] + 1) for a in range(3)
        ]

    def fractions(self, lo, hi) -> np.ndarray:
        """The share of every voxel inside the box (lo, hi)."""
        parts = []
        for a, e in enumerate(self.edges):
            inside = np.minimum(e[1:], hi[a]) - np.maximum(e[:-1], lo[a])
            parts.append(np.clip(inside / np.maximum(np.diff(e), 1e-300), 0.0, 1.0))
        return parts[0][:, None, None] * parts[1][None, :, None] * parts[2][None, None, :]

    def profiles(self, lo, hi) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per axis, (the voxels' edges clipped to the box (lo, hi), the box's work below
        each): its mass is made once for the cuts on all three axes (`below`), where each
        axis made it anew (a third of a 4x4's cutting)."""
        mass = self.density * self.fractions(lo, hi)
        out = []
        for axis in range(3):
            profile = mass.sum(axis=tuple(a for a in range(3) if a != axis))
            e = np.clip(self.edges[axis], lo[axis], hi[axis])
            out.append((e, np.concatenate([[0.0], np.cumsum(profile)])))
        return out

    def below(self, lo, hi, axis: int, cuts: np.ndarray, profiles=None) -> tuple:
        """(work of the box (lo, hi) below each cut on `axis`, the box's whole work), the
        work spread evenly inside each voxel; `profiles`: the box's (`profiles`), if made."""
        e, cum = (profiles or self.profiles(lo, hi))[axis]
        return np.interp(cuts, e, cum), float(cum[-1])


def _sorted(lo, hi) -> list:
    """Per kind (lower bounds, upper bounds, centres) and axis, (the objects' order, their
    values sorted): a cut takes its box's objects from them in order, where sorting each
    box's anew took half of a 65,536-triangle tetra's cut search; kept while the scene
    lives, for every cut the plan tries (`object_cells`)."""
    centres = 0.5 * (lo + hi)
    return [
        [(np.argsort(v[:, a], kind="stable"), np.sort(v[:, a])) for a in range(3)]
        for v in (lo, hi, centres)
    ]


class _Cutter:
    """The recursive bisection's inputs: every object's bounds, where the work lies (a
    `WorkGrid`, or None) and the objects a node may hold (or None)."""

    def __init__(self, bounds, work, limit, sorted_=None):
        self.lo, self.hi = bounds
        self.work, self.limit = work, limit
        self.sorted = _sorted(*bounds) if sorted_ is None else sorted_
        self.member = np.zeros(len(self.lo), bool)

    def values(self, idx: np.ndarray) -> tuple:
        """Per axis, the lower bounds, upper bounds and centres of the objects `idx`, each
        sorted (`_cut`'s inputs)."""
        self.member[:] = False
        self.member[idx] = True
        return tuple(
            [values[self.member[order]] for order, values in per_axis] for per_axis in self.sorted
        )

    def bisect(self, idx, lo, hi, block, cols, los, his) -> None:
        """Cut the box (lo, hi), which holds the objects `idx`, among the nodes of `block`
        (rows r0..r1, columns c0..c1 of the mesh): halve the block's longer side, and the box
        where the objects (or their work) divide as the halves' node counts do."""
        r0, r1, c0, c1 = block
        if (r1 - r0) * (c1 - c0) == 1:
            los[r0 * cols + c0], his[r0 * cols + c0] = lo, hi
            return
        if c1 - c0 >= r1 - r0:
            k = c0 + (c1 - c0) // 2
            first, second = (r0, r1, c0, k), (r0, r1, k, c1)
            nodes = ((k - c0) * (r1 - r0), (c1 - k) * (r1 - r0))
        else:
            k = r0 + (r1 - r0) // 2
            first, second = (r0, k, c0, c1), (k, r1, c0, c1)
            nodes = ((k - r0) * (c1 - c0), (r1 - k) * (c1 - c0))
        olo, ohi = self.lo[idx], self.hi[idx]
        axis, cut = _cut(self.values(idx), self.work, lo, hi, nodes, self.limit)
        mid_hi, mid_lo = hi.copy(), lo.copy()
        mid_hi[axis] = mid_lo[axis] = cut
        self.bisect(idx[olo[:, axis] <= cut], lo, mid_hi, first, cols, los, his)
        self.bisect(idx[ohi[:, axis] >= cut], mid_lo, hi, second, cols, los, his)


def _cut(sorted_, work, lo, hi, nodes: tuple[int, int], limit) -> tuple[int, float]:
    """(axis, position) of one cut of the box (lo, hi) holding the objects whose lower
    bounds, upper bounds and centres are `sorted_` (per axis, sorted: `_Cutter.values`): the
    one whose fuller side per node holds fewest objects (the objects below it, those crossing
    it too, shared by `nodes[0]` nodes, those above by `nodes[1]`: an object crossing the cut
    is held on both sides, so the cut at the count's quantile is not always the best: a
    tree's long branches), tried at CANDIDATES quantiles of the objects' centres on each
    axis; with `work` (a WorkGrid), among the cuts within the objects' limit (those
    quantiles, and CANDIDATES even steps across the box), the one whose busier side per
    node has least work."""
    los, his, centres = sorted_
    count = len(los[0])
    if not count:
        axis = int(np.argmax(hi - lo))
        return axis, float(lo[axis] + nodes[0] / sum(nodes) * (hi[axis] - lo[axis]))
    share = nodes[0] / sum(nodes)
    if work is None:
        q = np.clip(share + np.linspace(-0.5, 0.5, CANDIDATES) * min(share, 1 - share), 0, 1)
    else:
        q = np.linspace(0.0, 1.0, CANDIDATES + 2)[1:-1]
    tries = []  # per axis: (objects score, work score, positions)
    profiles = None if work is None else work.profiles(lo, hi)
    for axis in range(3):
        cuts = sorted_quantile(centres[axis], q)
        if work is not None:
            cuts = np.concatenate([cuts, lo[axis] + q * (hi[axis] - lo[axis])])
        cuts = np.clip(cuts, lo[axis], hi[axis])
        below = np.searchsorted(los[axis], cuts, side="right")
        above = count - np.searchsorted(his[axis], cuts, side="left")
        held = np.maximum(below / nodes[0], above / nodes[1])
        if work is None:
            busier = np.abs(q - share)  # ties: nearest the even share
        else:
            left, total = work.below(lo, hi, axis, cuts, profiles)
            busier = np.maximum(left / nodes[0], (total - left) / nodes[1])
        tries.append((held, busier, cuts))
    held, busier, cuts = (np.concatenate(t) for t in zip(*tries, strict=True))
    if work is None:
        best = np.lexsort((busier, held))[0]  # the first of the least (held, busier)
    else:
        fewest = held.min()
        cap = max(fewest, SLACK * fewest if limit is None else min(limit, SLACK * fewest))
        allowed = np.flatnonzero(held <= cap)
        best = allowed[np.lexsort((held[allowed], busier[allowed]))[0]]
    return int(best) // (len(cuts) // 3), float(cuts[best])


def sorted_quantile(values: np.ndarray, q: np.ndarray) -> np.ndarray:
    """`np.quantile(values, q)` (its "linear" method, to the bit) of values already sorted:
    no partition of them (a tenth of numpy's CPU on 7,382 spheres, 64 quantiles; a quarter of
    a 4x4's cutting)."""
    n = len(values)
    at = (n - 1) * q
    prev = np.floor(at)  # q within 0..1: at most n - 1, whose next is itself
    gamma = at - prev
    i = prev.astype(np.intp)
    a, b = values[i], values[np.minimum(i + 1, n - 1)]
    diff = b - a
    out = a + diff * gamma
    np.subtract(b, diff * (1 - gamma), out=out, where=gamma >= 0.5)  # as numpy's _lerp
    return out
