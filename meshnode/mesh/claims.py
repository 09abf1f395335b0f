"""Which node makes each pinhole eye ray in object space: where it will be traced.

A node used to make the eye rays of its own rectangles and hand on every ray whose work
starts in another cell: a pass of a whole RAY record for a ray made a few nanoseconds
earlier (tetra, balls, teapot, gears and rings 3x3 under a quarter share: 13-53% of all eye
rays, most of tetra's passes). Now the ray through the middle of each block of the eye's map is
walked once a render (`block_cells`), and the block's rays are made by the node that would
be handed the rays of the cell its work starts in. Most of the block's rays start there
too, and the eye's map routes many of those with no walk (`sightlines.EyeMap.first`: a ray
entering the cell it sees nearest before any other cell's voxels starts its work there);
the others are walked and passed as before. Blocks that see no occupied voxel, or whose
middle ray meets none, stay with their rectangle's node, which ends most of their rays.
Simulated 3x3 under a quarter share at 4 spp, one plan each way, rays passed: tetra 41.0k
-> 21.5k, gears 140k -> 104k, teapot 154k -> 135k, balls 315k -> 274k, rings 351k ->
322k (claiming each block for the cell it sees nearest instead passed balls' rays more:
its spheres stand in front of the floor most of their blocks' rays reach).

Where a cell's engine is copied onto other nodes and the plan shares the cell's own work over
them (`MeshPlan.claim_shares`), its blocks are dealt over all its holders in those shares
(`shared_claims`): made by the holder its rectangle's node hands them to, a copy took on only
the rays passed to it, while most of the busiest node's work is its own eye rays' (the full
SPD mountain 3x3 under a quarter share, frame CPU speedup 2.69 -> 5.34).

Every node computes the same claims from the same map, partition and plan, so each sample
is made exactly once; a ray is routed from the same t_min to the same cell wherever it is
made, so images and counts do not change.
"""

import dataclasses
from functools import lru_cache

import numpy as np

from meshnode.engine.camera import eye_rays
from meshnode.engine.locator import cell_locator
from meshnode.engine.routing import start_cells
from meshnode.engine.sightlines import NO_EYE_MAP, SEEN_NONE, EyeMap, eye_map
from meshnode.mesh.adaptive import RectIndex
from protocols.partition import Partition
from protocols.render import ImageSpec, MeshPlan, RenderSpec
from protocols.scene import View


def node_eye_map(engines, engine, spec: RenderSpec, part: Partition, view: View, books):
    """The occupancy map seen from the eye, for routing the eye rays a node makes in object
    space (`meshnode.engine.sightlines`): pinhole rays made by pixel, not a lens's (they
    leave the eye from all over it) nor adaptive sampling's (`books`). Made once for every
    node on the same map (`EngineCache.sightlines`: a simulated mesh's nodes share it), as
    (EyeMap, why)."""
    if spec.plan.mode != "object" or len(part.cell_los) < 2:
        return NO_EYE_MAP, "not used: one cell"
    if spec.camera is not None or books is not None:
        return NO_EYE_MAP, "not used: a lens or adaptive sampling makes the eye rays"
    key = _seen_key("eye map", spec, part, view)
    return engines.sightlines(
        engine, key, lambda: eye_map(engine.occupancy, view, spec.image, part.cells)
    )


def node_claims(engines, engine, spec: RenderSpec, part: Partition, view: View, eye: EyeMap):
    """(which node makes each sample's eye rays, why) under the eye map and static
    rectangles (`eye_claims`; None where not used): a dealt tile, or a stolen chunk without
    copies, is made by whoever takes it (with copies a holder of a claimed chunk's cells
    may take it: `meshnode.mesh.claimfeed`). The blocks' cells are found once for every
    node on the same map."""
    if not eye.near.shape[0]:
        return None, "not used: no eye map"
    if spec.plan.dynamic or (spec.plan.steal and not spec.plan.copies):
        return None, "not used: chunks are stolen or tiles dealt"
    blocks = _blocks(engines, engine, spec, part, view, eye)
    # every node's claims are the same table: made once a mesh too (0.6 ms a node)
    rects = (np.asarray(part.rects, np.int64).tobytes(), np.asarray(part.owner).tobytes())
    return engines.sightlines(
        engine,
        (*_seen_key("claims", spec, part, view), repr(spec.plan), *rects),
        lambda: eye_claims(blocks, eye, part, spec.plan, spec.image.sample_grid()),
    )


def claim_cells(engines, engine, spec: RenderSpec, part: Partition, view: View, eye: EyeMap):
    """Per sample-grid cell (rows by columns), the cell its block's eye rays start their
    work in (`block_cells`), -1 where none: which engines a node must hold to make and
    trace a claimed chunk (`meshnode.mesh.claimfeed`)."""
    columns, rows = spec.image.sample_grid()
    blocks = _blocks(engines, engine, spec, part, view, eye)
    return per_sample(blocks, eye.side, rows, columns)


def per_sample(blocks: np.ndarray, side: int, rows: int, columns: int) -> np.ndarray:
    """A per-block table (blocks of `side` x `side` samples) as one per sample-grid cell."""
    return np.repeat(np.repeat(blocks, side, axis=0), side, axis=1)[:rows, :columns]


def _blocks(engines, engine, spec: RenderSpec, part: Partition, view: View, eye: EyeMap):
    """`block_cells`, once for every node on the same map."""
    return engines.sightlines(
        engine,
        _seen_key("blocks", spec, part, view),
        lambda: block_cells(engine, part.cells, eye, view, spec.image),
    )


def _seen_key(what: str, spec: RenderSpec, part: Partition, view: View) -> tuple:
    """What the eye's view of the map depends on beside the map (`EngineCache.sightlines`):
    the view, the image and the cells."""
    cells = tuple(np.ascontiguousarray(c, float).tobytes() for c in part.cells)
    return (what, repr(view), repr(spec.image), *cells)


def block_cells(engine, cells, eye: EyeMap, view: View, image: ImageSpec) -> np.ndarray:
    """Per block of the eye's map (rows by columns of blocks), the cell where the work of
    the eye ray through its middle sample-grid cell starts (`routing.start_cells`, the full
    walk), -1 where that ray meets no occupied voxel or the block sees none: one walk a
    block (at most BLOCKS x BLOCKS), every node the same."""
    columns, rows = image.sample_grid()
    by = -(-rows // eye.side)
    seen = np.isfinite(eye.near).reshape(by, eye.blocks_x)
    keep = np.zeros((rows, columns), bool)
    ys = np.minimum(np.arange(by) * eye.side + eye.side // 2, rows - 1)
    xs = np.minimum(np.arange(eye.blocks_x) * eye.side + eye.side // 2, columns - 1)
    keep[np.ix_(ys, xs)] = seen
    out = np.full((by, eye.blocks_x), -1, np.int64)
    if not keep.any():
        return out
    middle = image if image.corners() else dataclasses.replace(image, spp=1)
    rays = eye_rays(view, middle, keep=keep)
    los, his = cells
    found = start_cells(
        rays, engine.scene_lo, engine.scene_hi, engine.occupancy, los, his, cell_locator(los, his)
    )
    g = rays["pixel"]  # one ray a sample-grid cell: its id is the cell's
    out[g // columns // eye.side, g % columns // eye.side] = found
    return out


def eye_claims(blocks: np.ndarray, eye: EyeMap, part: Partition, plan: MeshPlan, grid):
    """(per sample-grid cell, rows by columns, the node that makes its eye rays, why): a
    block whose middle ray starts its work in a cell (`block_cells`) goes to the node its
    rectangle's node would hand that cell's rays to (`MeshPlan.takers`); any other block to
    its rectangle's node."""
    columns, rows = grid
    rect = RectIndex(part.rects, columns)(np.arange(rows * columns)).reshape(rows, columns)
    if (rect < 0).any():
        raise ValueError("eye_claims: the partition's rectangles leave sample-grid cells out")
    owner = np.asarray(part.owner, np.int64)[rect]
    seen = per_sample(blocks, eye.side, rows, columns)
    takers = taker_table(plan)
    one = seen >= 0
    claims = owner.copy()
    claims[one] = takers[owner[one], seen[one]]
    shared = per_sample(shared_claims(blocks, plan), eye.side, rows, columns)
    claims = np.where(shared >= 0, shared, claims)
    moved = float(np.mean(claims != owner))
    why = f"{np.mean(one):.0%} of the samples start in a cell; {moved:.0%} made there"
    if plan.claim_shares:
        why += f"; {np.mean(shared >= 0):.0%} dealt over their cell's holders"
    return claims, why


def shared_claims(blocks: np.ndarray, plan: MeshPlan) -> np.ndarray:
    """Per block (as `blocks`), the holder of its cell that makes its eye rays where the
    plan shares that cell's own work over its holders (`MeshPlan.claim_shares`), -1 where
    not: the cell's blocks in rows, in runs of SHARED_RUN, each run to the holder furthest
    below its share so far, so every holder's blocks lie all over the cell's part of the
    image (the same work mix) and a batch's rays stay neighbours."""
    out = np.full(blocks.shape, -1, np.int64)
    if not plan.claim_shares:
        return out
    flat = out.reshape(-1)
    cells = blocks.reshape(-1)
    for c, (shares, holders) in enumerate(
        zip(plan.claim_shares, plan.holders_table(), strict=True)
    ):
        if not shares:
            continue
        at = np.flatnonzero(cells == c)
        want = np.asarray(shares, float) / sum(shares)
        given = np.zeros(len(holders))
        for start in range(0, len(at), SHARED_RUN):
            run = at[start : start + SHARED_RUN]
            i = int(np.argmax(want * (start + len(run)) - given))
            flat[run] = holders[i]
            given[i] += len(run)
    return out


SHARED_RUN = 16  # blocks of a shared cell dealt to one holder at a time


@lru_cache(maxsize=4)
def taker_table(plan: MeshPlan) -> np.ndarray:
    """(nodes, cells) the node each node hands a cell's rays to (`MeshPlan.takers`), read-only:
    the same for every node of a mesh, so a simulated 16x16 makes it once, not once a node
    (256 tables of 256 x 256: 0.9 s of its plan)."""
    table = np.array([plan.takers(n) for n in range(plan.nodes)], np.int64)
    table.setflags(write=False)
    return table


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
    """The eye map a node routes with: a block seeing first a cell it traces (its own, or a
    copy it holds) sends its rays into that cell without a walk of the map where they may
    (`routing.routed`); any other block's rays walk as before, so a ray that meets no voxel
    still ends where it was made instead of being passed to the cell it crosses."""
    first = np.where(np.isin(eye.first, traced), eye.first, SEEN_NONE)
    return eye._replace(first=first)
