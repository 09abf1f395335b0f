"""Which node makes each pinhole eye ray in object space: where it will be traced.

A node used to make the eye rays of its own rectangles and hand on every ray whose work
starts in another cell: a pass of a whole RAY record for a ray made a few nanoseconds
earlier (tetra, balls, teapot, gears and rings 3x3 under a quarter share: 13-53% of all eye
rays, most of tetra's passes). The eye's map (`sightlines.EyeMap.only`) says, for each
block of the sample grid, whether its rays can meet occupied voxels of one cell only: then
each of them starts its work in that cell or nowhere (a miss, which any node ends), so the
node that would be handed the cell's rays makes them itself. Blocks that see no cell or
several stay with their rectangle's node, which routes and passes them as before.

Every node computes the same claims from the same map, partition and plan, so each sample
is made exactly once; a ray is routed from the same t_min to the same cell wherever it is
made, so images and counts do not change.
"""

import numpy as np

from meshnode.engine.sightlines import SEEN_SEVERAL, EyeMap
from protocols.partition import Partition
from protocols.render import MeshPlan


def eye_claims(eye: EyeMap, part: Partition, plan: MeshPlan, grid: tuple[int, int]):
    """(per sample-grid cell, rows by columns, the node that makes its eye rays, why): a
    block seeing one cell's voxels goes to the node its rectangle's node would hand that
    cell's rays to (`MeshPlan.takers`); any other block to its rectangle's node."""
    columns, rows = grid
    owner = np.full((rows, columns), -1, np.int64)
    for (x0, x1, y0, y1), node in zip(part.rects, part.owner, strict=True):
        owner[y0:y1, x0:x1] = node
    if (owner < 0).any():
        raise ValueError("eye_claims: the partition's rectangles leave sample-grid cells out")
    seen = eye.only.reshape(-1, eye.blocks_x)
    seen = np.repeat(np.repeat(seen, eye.side, axis=0), eye.side, axis=1)[:rows, :columns]
    takers = np.array([plan.takers(n) for n in range(plan.nodes)], np.int64)
    one = seen >= 0
    claims = owner.copy()
    claims[one] = takers[owner[one], seen[one]]
    moved = float(np.mean(claims != owner))
    return claims, f"{np.mean(one):.0%} of the samples see one cell; {moved:.0%} made there"


def claimed_bands(mine: np.ndarray, per_cell: int, batch: int):
    """(y0, y1, x0, x1) bands of whole rows of `mine` (a flag per sample-grid cell) holding
    about `batch` samples of flagged cells each, cropped to their flagged columns."""
    per_row = mine.sum(axis=1) * per_cell
    rows = np.flatnonzero(per_row)
    if not len(rows):
        return
    band = np.cumsum(per_row[rows]) // max(batch, 1)
    cuts = np.flatnonzero(np.diff(band)) + 1
    for group in np.split(rows, cuts):
        y0, y1 = int(group[0]), int(group[-1]) + 1
        cols = np.flatnonzero(mine[y0:y1].any(axis=0))
        yield y0, y1, int(cols[0]), int(cols[-1]) + 1


def routing_map(eye: EyeMap, traced: list[int]) -> EyeMap:
    """The eye map a node routes with: a block seeing one cell it traces (its own, or a copy
    it holds) sends its rays into that cell without a walk of the map (`routing.routed`);
    any other block's rays walk as before, so a ray that meets no voxel still ends where it
    was made instead of being passed to the cell it crosses."""
    only = np.where(np.isin(eye.only, traced), eye.only, SEEN_SEVERAL)
    return eye._replace(only=only)
