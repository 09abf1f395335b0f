"""Dynamic image space: which dealt tiles a node has wholly traced, with their ray counts.

A tile is traced once every batch of it was handed out (the feed's `finished`) and each has
been traced and delivered. The node reports such tiles to the host after their deposits
(`Session.flush`), so the host knows the sums of those samples are whole: when another node
is lost, it keeps them and deals only the rest again (issue 41: a lost node costs only the
work that was not done).
"""

from collections import defaultdict

from meshnode.mesh.stats import add_counts


class TracedTiles:
    """Batches in flight per tile, and the tiles (and ray counts) traced since `take`."""

    def __init__(self):
        self.open: dict[int, int] = defaultdict(int)  # tile -> batches started, not traced
        self.started: set[int] = set()  # tiles whose every batch was handed out
        self.counts: dict[int, dict] = defaultdict(lambda: defaultdict(int))
        self.done: list[int] = []  # traced, not yet taken
        self.done_counts: dict[str, int] = defaultdict(int)

    def batch_started(self, tile: int) -> None:
        self.open[tile] += 1

    def all_started(self, tiles) -> None:
        """The feed handed out the last batch of each of `tiles` (a tile of no rays is
        traced at once)."""
        for t in tiles:
            self.started.add(t)
            self._check(t)

    def batch_traced(self, tile: int, counts: dict, primaries: int) -> None:
        """A batch of `tile` was traced and its deposits handed on."""
        add_counts(self.counts[tile], counts, primaries)
        self.open[tile] -= 1
        self._check(tile)

    def _check(self, tile: int) -> None:
        if tile in self.started and not self.open.get(tile):
            self.started.discard(tile)
            self.open.pop(tile, None)
            self.done.append(tile)
            for k, v in self.counts.pop(tile, {}).items():
                self.done_counts[k] += v

    def take(self) -> tuple[list[int], dict[str, int]]:
        """The tiles traced since the last take, and their ray counts summed."""
        out = self.done, dict(self.done_counts)
        self.done, self.done_counts = [], defaultdict(int)
        return out
