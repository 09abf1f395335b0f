"""Stealing the eye's claims (`MeshPlan.steal` with copies): a node's claimed eye rays in
chunks a holder of their cells may take.

Under the eye's claims (`meshnode.mesh.claims`) each block's eye rays are made by a node that
traces the cell their work starts in: its owner, or a holder of its copy, in the plan's
shares. The shares are weighed before the render from a coarse simulation, and what they
leave uneven stays so. Here a node's claimed samples are cut into chunks (the plan's tiles,
only the samples it claims in each), traced in turn, and a neighbour that has run out takes
unstarted ones whose every claimed block starts in a cell it holds: it makes those eye rays
itself and traces them with the same engine as the claimant would (a ray's segments do not
depend on who made it), so the image and counts stay the single node's and no ray is passed
for it. A chunk is given only by the node that claims it: a thief makes it as its giver
claimed it, and keeps it (`ClaimFeed.add`).
"""

import numpy as np

from meshnode.mesh.feeds import ChunkFeed, stealable_last
from protocols.records import joined

# Samples along a chunk's side at most (the plan's tile, if smaller). Smaller chunks are
# taken more often, each claimed block in one wholly held by the thief (simulated 256 x 256
# at 16 spp, the same plans, the busiest node stealing against none at 32 / 8 samples:
# teapot 3x3 under a quarter share 0.963 / 0.939, the mountain 3x3 1.009 / 0.976, 4x4
# 0.988 / 0.958), but on real nodes their smaller batches cost more than that gained: at 8,
# the nodes' frames outside their batches rose from 0.24 to 0.41 of one process's on the
# mountain 3x3 and 0.19 to 0.29 on teapot, their frame at once 3.91 -> 3.46 and 4.52 ->
# 4.05 (one run each).
SIDE = 32


class ClaimFeed(ChunkFeed):
    """A `ChunkFeed` of claimed samples: own chunks are (x0, x1, y0, y1) tiles of the sample
    grid, a given chunk carries its claimant as a fifth item; `make(flags, y, x)` makes the
    batches of a rectangle's flagged cells (`NodeCore._made`), `per_cell` rays a flagged
    cell; chunks from the front are made together up to `batch` rays."""

    def __init__(self, node: int, claims, cells, plan, side: int, make, per_cell: int, batch: int):
        self.node, self.claims, self.plan, self.per_cell = node, claims, plan, per_cell
        self.need = _needs(claims == node, cells, min(side, SIDE), plan.nodes)
        self._make = make
        chunks = stealable_last(list(self.need), self.usable, node, plan)
        super().__init__(chunks, self._batches, usable=self.usable, rays=self._rays, budget=batch)

    def usable(self, thief: int, chunks: list) -> np.ndarray:
        """Which of `chunks` `thief` can make and trace itself: this node's own, every
        claimed block's cell held there."""
        held = frozenset(self.plan.held(thief))
        return np.array([len(c) == 4 and self.need[c] <= held for c in chunks], bool)

    def _flags(self, chunk: tuple) -> np.ndarray:
        """The chunk's samples its claimant claims (this node, or the giver of a given one)."""
        x0, x1, y0, y1, *given = chunk
        return self.claims[y0:y1, x0:x1] == (given[0] if given else self.node)

    def _rays(self, chunk: tuple) -> int:
        return int(np.count_nonzero(self._flags(chunk))) * self.per_cell

    def _batches(self, group: list):
        """The batches of a group of chunks' claimed samples: one of their eye rays (a
        chunk of many: its bands), and any other kind `make` yields (the sky's deposits) as
        it comes."""
        if len(group) < 2:  # made as they are traced: a chunk may hold millions of rays
            return self._make(self._flags(group[0]), group[0][2], group[0][0])
        made = [b for c in group for b in self._make(self._flags(c), c[2], c[0]) if len(b)]
        kinds: dict = {}
        for b in made:
            kinds.setdefault(b.dtype, []).append(b)
        # joined as bytes: numpy copies a record array of RAY's nested fields at 55-60 ns
        # a record, its bytes at 5
        return iter(joined(parts) for parts in kinds.values())

    def add(self, chunks, giver: int = -1) -> None:
        """Chunks `giver` gave: each made as `giver` claimed it."""
        super().add([(*c, giver) for c in chunks])


def _needs(mine: np.ndarray, cells: np.ndarray, side: int, nodes: int) -> dict:
    """Per chunk (x0, x1, y0, y1: a side x side tile of the grid holding any `mine` sample),
    in grid order, the cells its `mine` samples start in (`cells`, -1: none)."""
    rows, cols = mine.shape
    across = -(-cols // side)
    tile = (np.arange(rows) // side)[:, None] * across + (np.arange(cols) // side)[None, :]
    seen = mine & (cells >= 0)
    pairs = np.unique(tile[seen] * nodes + cells[seen])
    need: dict[int, set] = {int(t): set() for t in np.unique(tile[mine])}
    for t, c in zip((pairs // nodes).tolist(), (pairs % nodes).tolist(), strict=True):
        need[t].add(c)
    out = {}
    for t, held in need.items():
        y0, x0 = t // across * side, t % across * side
        out[(x0, min(x0 + side, cols), y0, min(y0 + side, rows))] = frozenset(held)
    return out
