"""The host's side of dynamic image space: which tiles each node gets, and when (DESIGN.md 6).

Pure, no sockets: the host's mesh client and the simulated mesh both deal with it.
"""

from collections import deque

import numpy as np

from meshnode.mesh.spiral import spiral_order


def deal_order(rects, order: str) -> list[int]:
    """The order dynamic tiles are dealt in (MeshPlan.order): "rows" as the partition lists
    them (row by row), "centre" spiralling out from the image's middle tile, so the last
    tiles dealt, whose costs decide how evenly the nodes finish, are the border's."""
    if order == "rows" or len(rects) == 0:
        return list(range(len(rects)))
    x0 = np.array([r[0] for r in rects])
    y0 = np.array([r[2] for r in rects])
    return spiral_order(
        np.unique(x0, return_inverse=True)[1], np.unique(y0, return_inverse=True)[1]
    )


class TileDealer:
    """The host's side of dynamic image space: `buffer` tiles to every node at first, then
    one more whenever a node reports one finished, until none are left; then each node that
    reports is told it gets no more. `tiles`: the tile indices in the order they are dealt.
    Pure: the host and the simulated mesh both drive it."""

    def __init__(
        self, tiles, nodes: int, buffer: int, share_owners: bool = False, count: int | None = None
    ):
        self.left = deque(tiles)
        self.nodes, self.buffer = nodes, max(1, buffer)
        self.share_owners = share_owners  # adaptive sampling: `last` comes with `owners()`
        # tile -> node dealt it; -1: not yet (or never: `count` tiles, `tiles` those to deal)
        self.owner = np.full(len(self.left) if count is None else count, -1, np.int64)
        self.told: set[int] = set()  # nodes told they get no more

    def first(self) -> dict[int, tuple[list[int], bool]]:
        """Each node's first tiles, dealt round-robin, and whether that is all it gets (a
        node dealt none when there are fewer tiles than nodes)."""
        out: dict[int, list[int]] = {n: [] for n in range(self.nodes)}
        for _ in range(self.buffer):
            for n in range(self.nodes):
                if self.left:
                    out[n].append(self._deal(n))
        return {n: (tiles, self._last(n) if not tiles else False) for n, tiles in out.items()}

    def finished(self, node: int) -> tuple[list[int], bool]:
        """A node finished a tile: (its next tiles, whether it gets no more after them);
        a node is told it gets no more once: ([], False) after that."""
        if self.left:
            return [self._deal(node)], False
        return [], self._last(node)

    def _last(self, node: int) -> bool:
        told = node in self.told
        self.told.add(node)
        return not told

    def _deal(self, node: int) -> int:
        tile = self.left.popleft()
        self.owner[tile] = node
        return tile

    def owners(self) -> np.ndarray:
        """Every tile's node, once all are dealt (when a node is told it gets no more):
        under adaptive sampling a node sends each pass-1 deposit on to the nodes whose tiles
        have its pixel in their halo, and learns who they are from this."""
        if self.left:
            raise RuntimeError("tiles are still to be dealt: their nodes are not known")
        return self.owner.copy()

    def owners_with(self, last: bool) -> np.ndarray:
        """What a TILES message carries as every tile's node: `owners()` with a node's last
        tiles under adaptive sampling, else nothing."""
        return self.owners() if last and self.share_owners else np.zeros(0, np.int64)

    def tiles_per_node(self) -> list[int]:
        return np.bincount(self.owner[self.owner >= 0], minlength=self.nodes).tolist()
