"""The scene's occupancy map as the host makes it for object-space nodes: every node gets the
same map with its partition and ends a segment whose path ahead crosses only empty voxels,
instead of passing it through every cell ahead (`meshnode.engine.occupancy`).
"""

import numpy as np

from host.scene.derived import kept, scene_tables
from meshnode.engine.occupancy import FINE_BYTES, OCTANTS, SUB
from meshnode.engine.voxelize import touched_map
from protocols.partition import MAX_OCC_SIDE
from protocols.scene import SceneData

OCC_VOXELS = 64**3  # voxels in the occupancy map (32^3 skipped less: teapot 3x3 5.78 vs 5.91)
MAP_SHARE = 0.25  # of a node's byte budget (`MeshPlan.node_bytes`) its map may take at most
# Each voxel is grown by this share of the map's box before an object's surface is tested
# against it: a walk's round-off (about 1e-16 of the distance from the ray's origin) never
# steps past a surface, for origins up to 1e8 boxes away. A millionth (as the grid pads its
# box) marked the voxels across every face the tetra's vertices lie near (its box grown by a
# millionth leaves its dyadic vertices that near the faces): tetra's map 10.9% against 7.1%.
PAD = 1e-7
# Sub-voxel tests the map's marking may spend; past them a voxel an object reaches is marked
# whole. The SPD scenes take 0.48-1.65 M (the map 8-114 ms on one core), a 65,536-triangle
# tetra 0.69 M; shells' nested spheres take 41.6 M (0.6 s), 60 of 64 sub-voxels deep in
# every voxel, and stop at these (82 ms).
SUB_TESTS = 2_000_000
# An inner map (`inner_map`) where the objects smaller than a quarter of the scene's box lie in
# a box holding at most a sixteenth of the scene's: balls' floor (24 x 24) left its sphereflake
# 13 x 13 x 9 of the map's 168 x 168 x 9 voxels (its box 0.65% of the scene's: simulated 3x3,
# rays passed 45% fewer, the busiest node's work 16% less). Gears' (21% of its box: its gears
# are polygons filling the voxels they cross) passed 2% fewer and walked 23% more steps.
BIG_SHARE = 0.25
INNER_SHARE = 1 / 16


def map_voxels(plan) -> int:
    """Voxels in the plan's occupancy map: OCC_VOXELS, fewer where a byte budget is tight (a
    node keeps OCTANTS + FINE_BYTES bytes a voxel, `meshnode.engine.occupancy`), so the map
    takes at most MAP_SHARE of it (64^3 voxels were 2 MB: twice a 1 MB budget)."""
    if not plan.node_bytes:
        return OCC_VOXELS
    per = OCTANTS + FINE_BYTES
    return int(max(1, min(OCC_VOXELS, MAP_SHARE * plan.node_bytes // per)))


def occupancy_map(
    scene: SceneData, box, voxels: int = OCC_VOXELS, sub_voxels: bool = True
) -> tuple[tuple, bytes, bytes]:
    """(voxels per axis, packed bits, sub-voxel masks) of the scene's occupancy map over `box`
    (`Partition.occ_res`, `occ_bits`, `occ_fine`; no masks without `sub_voxels`: the sky,
    which reads the voxels alone, spares their tests): about
    `voxels` near-cubic voxels (a flat scene gets layers too), a voxel set where some
    object's surface reaches it, the voxel padded (`meshnode.engine.occupancy`:
    conservative, so a node that skips what the map calls empty misses nothing). Made once
    while the scene lives: a plan's first guess, its simulations and its partition each
    asked for it (the 65,536-triangle tetra: 19 ms a map, three of a 0.3 s plan)."""
    lo, hi = (np.asarray(b, float) for b in box)
    key = ("occupancy map", lo.tobytes(), hi.tobytes(), int(voxels), sub_voxels)
    return kept(scene, key, lambda: _mapped(scene, lo, hi, voxels, sub_voxels))


def _mapped(scene: SceneData, lo, hi, voxels: int, sub_voxels=True) -> tuple[tuple, bytes, bytes]:
    """`occupancy_map`, made: each object marks the voxels of its bounds that its surface
    reaches (`voxelize.touched_map`, the tests the grid's references are kept by), every
    voxel grown by the padding. A voxel an object's bounds reach but its surface does not
    stays empty: a ray crossing it meets nothing there, and passing it on to the node whose
    cell it is in was a pass to end it (`python -m bench.occupancy_map`, the same cells under
    both maps, 3x3 under a quarter share: rays passed 0.61 of before on tetra, 0.73 on teapot
    and the mountain, 0.85 on rings)."""
    tb = scene_tables(scene)
    ext = hi - lo
    thick = np.maximum(ext, 1e-3 * ext.max())
    res = np.clip(np.round(thick * (voxels / thick.prod()) ** (1 / 3)), 1, MAX_OCC_SIDE)
    res = res.astype(np.int64)
    full = np.zeros(int(res.prod()), bool)  # x fastest
    fine = np.zeros(int(res.prod()), np.uint64)  # an occupied voxel's sub-voxels
    if tb.n:
        reach = max(float(np.abs(tb.lo).max()), float(np.abs(tb.hi).max()))
        pad = PAD * float(ext.max()) + 1e-12 * reach
        touched_map(
            lo,
            ext / res,
            res,
            tb.lo,
            tb.hi,
            pad,
            tb.geometry(),
            full,
            fine,
            SUB,
            SUB_TESTS if sub_voxels else 0,
        )  # (with no tests to spend, the voxels alone)
    masks = fine[full].astype("<u8").tobytes() if sub_voxels else b""  # in voxel order
    return tuple(res.tolist()), np.packbits(full).tobytes(), masks


def inner_map(scene: SceneData, box, voxels: int = OCC_VOXELS) -> tuple | None:
    """(lo, hi, voxels per axis, bits, sub-voxel masks) of a second occupancy map over the box
    of the scene's small objects (none larger than BIG_SHARE of the scene's box), where that
    box holds at most INNER_SHARE of the scene's (a few large objects, a floor, make the
    scene's box the larger); None where there is no such box. It is marked with every object
    reaching it (the floor beneath them too), as the scene's is, so a walk there misses
    nothing (`meshnode.engine.mapwalk.first_occupied`). Made once while the scene lives (a
    plan's every simulation partitions: 1.2 ms of balls 3x3's 16 ms each); not to be
    changed."""
    lo, hi = (np.asarray(b, float) for b in box)
    key = ("inner map", lo.tobytes(), hi.tobytes(), int(voxels))
    return kept(scene, key, lambda: _inner(scene, lo, hi, voxels))


def _inner(scene: SceneData, lo, hi, voxels: int) -> tuple | None:
    """`inner_map`, made."""
    tb = scene_tables(scene)
    if not tb.n:
        return None
    ext = hi - lo
    small = (tb.hi - tb.lo).max(axis=1) <= BIG_SHARE * ext.max()
    if small.all() or not small.any():
        return None
    grow = 0.01 * (tb.hi[small].max(axis=0) - tb.lo[small].min(axis=0)) + PAD * ext.max()
    i_lo = np.maximum(tb.lo[small].min(axis=0) - grow, lo)
    i_hi = np.minimum(tb.hi[small].max(axis=0) + grow, hi)
    floor = 1e-3 * ext.max()  # as `occupancy_map` thickens a flat box
    if np.prod(np.maximum(i_hi - i_lo, floor)) > INNER_SHARE * np.prod(np.maximum(ext, floor)):
        return None
    return (i_lo, i_hi, *occupancy_map(scene, (i_lo, i_hi), voxels))
