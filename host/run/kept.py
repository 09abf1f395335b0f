"""What a try at a frame that lost a node leaves for the next (issue 41: a lost node costs only
the work that was not done).

Under dynamic image space without adaptive sampling every node reports the tiles it traced
whole, after their last deposit (`Kind.TILES_TRACED`): the sums of those samples are final.
When a node is lost, the host keeps them, with their ray counts, and the next try on the nodes
left keeps the same tiles and is dealt only the others. Elsewhere (object space, static tiles,
adaptive sampling, whose books live on the nodes) the frame starts over, and the statistics
say so.
"""

from dataclasses import dataclass, replace

import numpy as np

from host.planning.plan import Planned
from host.planning.skytiles import SkyTiles
from host.run.framebuffer import Framebuffer


@dataclass(frozen=True)
class Kept:
    """The tiles of the first try (`rects`, which every later try keeps), those traced whole
    so far, the framebuffer's sums over their samples (0 elsewhere) and their ray counts;
    `sky`: the first try's tiles the host deposits itself (`host.planning.skytiles`)."""

    rects: tuple
    tiles: frozenset
    sums: np.ndarray
    counts: dict
    sky: SkyTiles


def keeps_tiles(planned: Planned) -> bool:
    """Whether a lost try of this plan leaves whole tiles to keep."""
    spec = planned.spec
    return spec.plan.mode == "image" and spec.plan.dynamic and not spec.adaptive


def kept_after(kept: Kept | None, planned: Planned, fb: Framebuffer, collector) -> Kept | None:
    """What stays after a lost try: the tiles kept before and those traced whole in this try,
    with the sums of their samples (None where this plan keeps nothing)."""
    if not keeps_tiles(planned):
        return None
    rects = planned.partition.rects
    tiles = (kept.tiles if kept else frozenset()) | frozenset(collector.tiles_traced)
    counts = dict(kept.counts) if kept else {}
    for k, v in collector.traced_counts.items():
        counts[k] = counts.get(k, 0) + v
    grid = np.zeros((len(fb.sums) // _columns(fb), _columns(fb)), bool)
    for t in tiles:
        x0, x1, y0, y1 = rects[t]
        grid[y0:y1, x0:x1] = True
    sums = np.where(grid.reshape(-1, 1), fb.sums, 0.0)
    return Kept(rects, tiles, sums, counts, planned.sky)  # a retry's: the first try's


def _columns(fb: Framebuffer) -> int:
    """Samples (corners) or pixels in a row of the framebuffer's sums."""
    return fb.width + 1 if fb.corners else fb.width


def with_kept_tiles(planned: Planned, kept: Kept) -> Planned:
    """The plan on the nodes left, cut into the first try's tiles (a plan for fewer nodes
    would cut its last rows otherwise), so the kept tiles are tiles of this one too."""
    nodes = planned.spec.plan.nodes
    part = replace(
        planned.partition,
        rects=kept.rects,
        owner=tuple(i % nodes for i in range(len(kept.rects))),
    )
    return replace(planned, partition=part, sky=kept.sky)


def recovery(kept: Kept | None, lost: bool) -> dict:
    """What the statistics say of a frame that lost nodes: what was kept, what redone."""
    if not lost:
        return {}
    if kept is None:
        return {"redone": "the whole frame (nothing of a lost try is kept in this mode)"}
    return {
        "redone": "the tiles not traced whole when a node was lost",
        "tiles_kept": len(kept.tiles),
        "tiles": len(kept.rects),
        "eye_rays_kept": kept.counts.get("eye_rays", 0),
    }
