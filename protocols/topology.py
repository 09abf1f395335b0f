"""The torus of mesh nodes: coordinates, neighbours, the spanning tree of termination waves, and
shortest routes that alternate between equally short ones. Pure; no sockets.

Node n sits at row n // cols, column n % cols; rows and columns wrap around. With two columns
the east and west neighbour are the same node; with one row the north and south neighbour are
the node itself (no link).
"""

from dataclasses import dataclass

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

    def parent(self, node: int) -> int | None:
        """The termination waves' spanning tree (DESIGN.md 5): node 0 is the root, its
        column the spine, and each row branches both ways from the spine; every edge is a
        torus link and no node is more than `tree_depth` hops from the root. None for
        the root."""
        r, c = self.coords(node)
        if c:
            return self.node(r, c - 1 if c <= self.cols // 2 else c + 1)
        if r:
            return self.node(r - 1 if r <= self.rows // 2 else r + 1, 0)
        return None

    def children(self, node: int) -> tuple[int, ...]:
        """The nodes whose parent is `node` (among its links, since tree edges are links)."""
        return tuple(m for m in self.links(node) if self.parent(m) == node)

    @property
    def tree_depth(self) -> int:
        """Hops from the root to the farthest node of the tree: a wave down and back up
        takes twice this many message flights, against the size of the mesh for a ring."""
        return self.rows // 2 + self.cols // 2

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
