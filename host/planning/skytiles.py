"""Dynamic image space: the tiles whose every eye ray meets nothing (`meshnode.engine.sky`)
are deposited by the host and dealt to no node.

A tile costs the node dealt it two messages, a film and a pixel packet, whatever it traces;
the sky's cost nothing else. Dealt, they were the cheapest work a node could get, so the
dealer, which evens the nodes' time, gave the nodes that drew them fewer of the tiles that
trace. The host reads the map the nodes read and writes the records they would have sent (a
cell's background summed from zero), so the image is the same to the bit; their eye rays
are counted as made and escaped, as a node counts them.
"""

from dataclasses import dataclass, field

import numpy as np

from meshnode.engine.sky import Sky, filled, sky_of
from protocols.dtypes import DEPOSIT
from protocols.render import EVERYWHERE, RenderSpec
from protocols.scene import SceneData


@dataclass(frozen=True)
class SkyTiles:
    """The tiles the host deposits itself, their DEPOSIT records (one a sample-grid cell),
    the eye rays they stand for, counted, and what the statistics say of them."""

    tiles: frozenset = frozenset()
    records: np.ndarray = field(default_factory=lambda: np.zeros(0, DEPOSIT))
    counts: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)


def dealt_sky(scene: SceneData, spec: RenderSpec, box, occupancy) -> tuple[Sky | None, str]:
    """The sky of a dynamic image-space render over the scene's occupancy map (its voxels and
    bits over `box`), where the host may keep its tiles from the nodes; None, and why not,
    elsewhere (static tiles keep their nodes; a camera's or adaptive sampling's rays are the
    nodes' to make)."""
    if spec.plan.mode != "image" or not spec.plan.dynamic:
        return None, "tiles are not dealt"
    if spec.camera is not None:
        return None, "a camera makes the eye rays"
    if spec.adaptive:
        return None, "adaptive sampling: a tile's books live on its node"
    if tuple(occupancy) == EVERYWHERE:
        return None, "no occupancy map: the sky is not looked for"
    return sky_of(box, occupancy, scene.view, spec.image, scene.background)


def sky_tiles(sky: Sky | None, why: str, rects) -> SkyTiles:
    """The tiles of `rects` every eye ray of which meets nothing under `sky` (`why`: what
    finding it said), with their records and counts."""
    tiles, records, counts = filled(sky, rects)
    if len(tiles) == 0:
        return SkyTiles(stats={"tiles": 0, "why": why if sky is None else f"{why}; no tile"})
    rays = counts["eye_rays"]
    stats = {"tiles": len(tiles), "of": len(rects), "eye_rays": rays, "why": why}
    return SkyTiles(frozenset(tiles.tolist()), records, counts, stats)
