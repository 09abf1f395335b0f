"""The torus of mesh nodes: coordinates, neighbours, the ring of the state packet, and
shortest routes that alternate between equally short ones. Pure; no sockets.

Node n sits at row n // cols, column n % cols; rows and columns wrap around. With two columns
the east and west neighbour are the same node; with one row the north and south neighbour are
the node itself (no link).
"""

from dataclasses import dataclass
from functools import cached_property

DIRECTIONS = ("north", "south", "west", "east")


@dataclass(frozen=True)
class Torus:
    rows: int
    cols: int

    def __post_init__(self):
        if self.rows < 1 or self.cols < 1:
            raise ValueError(f"a mesh needs at least 1x1 nodes, not {self.rows}x{self.cols}")

    @property
    def size(self) -> int:
        return self.rows * self.cols

    def node(self, row: int, col: int) -> int:
        """Node index at (row, col), wrapping around."""
        return (row % self.rows) * self.cols + (col % self.cols)

    def coords(self, node: int) -> tuple[int, int]:
        if not 0 <= node < self.size:
            raise ValueError(f"node {node} is not in a {self.rows}x{self.cols} mesh")
        return divmod(node, self.cols)

    def neighbours(self, node: int) -> dict[str, int]:
        """The node in each direction (possibly the same node twice, or the node itself)."""
        r, c = self.coords(node)
        return {
            "north": self.node(r - 1, c),
            "south": self.node(r + 1, c),
            "west": self.node(r, c - 1),
            "east": self.node(r, c + 1),
        }

    def links(self, node: int) -> list[int]:
        """Distinct other nodes this node has a TCP link to."""
        return sorted(set(self.neighbours(node).values()) - {node})

    @cached_property
    def ring(self) -> tuple[int, ...]:
        """The state packet's ring: rows in snake order, so consecutive nodes are neighbours
        (the closing step back to node 0 may take more than one hop)."""
        order = []
        for r in range(self.rows):
            cols = range(self.cols) if r % 2 == 0 else range(self.cols - 1, -1, -1)
            order.extend(self.node(r, c) for c in cols)
        return tuple(order)

    def ring_next(self, node: int) -> int:
        i = self.ring.index(node)
        return self.ring[(i + 1) % self.size]

    def distance(self, a: int, b: int) -> int:
        """Hops on a shortest route from a to b."""
        (ra, ca), (rb, cb) = self.coords(a), self.coords(b)
        dr, dc = (rb - ra) % self.rows, (cb - ca) % self.cols
        return min(dr, self.rows - dr) + min(dc, self.cols - dc)

    def next_hops(self, a: int, b: int) -> tuple[int, ...]:
        """Every neighbour of a that lies on some shortest route to b (empty when a == b)."""
        (ra, ca), (rb, cb) = self.coords(a), self.coords(b)
        hops = set()
        for delta, size, back, fwd in (
            ((rb - ra) % self.rows, self.rows, self.node(ra - 1, ca), self.node(ra + 1, ca)),
            ((cb - ca) % self.cols, self.cols, self.node(ra, ca - 1), self.node(ra, ca + 1)),
        ):
            if delta == 0:
                continue
            if delta <= size - delta:
                hops.add(fwd)
            if size - delta <= delta:
                hops.add(back)
        return tuple(sorted(hops))


class Router:
    """Next hops from one node, alternating round-robin between equally short routes so that
    traffic to one destination (pixel packets to node 0) spreads over the links."""

    def __init__(self, torus: Torus, node: int):
        self.torus, self.node = torus, node
        self._table = {b: torus.next_hops(node, b) for b in range(torus.size)}
        self._turn = dict.fromkeys(range(torus.size), 0)

    def next_hop(self, destination: int) -> int:
        hops = self._table[destination]
        if not hops:
            raise ValueError(f"node {self.node} routes to itself")
        turn = self._turn[destination]
        self._turn[destination] = turn + 1
        return hops[turn % len(hops)]
