"""The scene's occupancy map as the host makes it for object-space nodes: every node gets the
same map with its partition and ends a segment whose path ahead crosses only empty voxels,
instead of passing it through every cell ahead (`meshnode.engine.occupancy`).
"""

import numpy as np

from host.scene.derived import kept, scene_tables
from meshnode.engine.occupancy import OCTANTS
from protocols.partition import MAX_OCC_SIDE
from protocols.scene import SceneData

OCC_VOXELS = 64**3  # voxels in the occupancy map (32^3 skipped less: teapot 3x3 5.78 vs 5.91)
MAP_SHARE = 0.25  # of a node's byte budget (`MeshPlan.node_bytes`) its map may take at most


def map_voxels(plan) -> int:
    """Voxels in the plan's occupancy map: OCC_VOXELS, fewer where a byte budget is tight (a
    node keeps OCTANTS bytes a voxel, `meshnode.engine.occupancy`), so the map takes at most
    MAP_SHARE of it (64^3 voxels were 2 MB: twice a 1 MB budget)."""
    if not plan.node_bytes:
        return OCC_VOXELS
    return int(max(1, min(OCC_VOXELS, MAP_SHARE * plan.node_bytes // OCTANTS)))


def occupancy_map(scene: SceneData, box, voxels: int = OCC_VOXELS) -> tuple[tuple, bytes]:
    """(voxels per axis, packed bits) of the scene's occupancy map over `box`: about
    `voxels` near-cubic voxels (a flat scene gets layers too), a voxel set where some
    object's bounds, padded as the grid pads a box, reach it (`meshnode.engine.occupancy`:
    conservative, so a node that skips what the map calls empty misses nothing). Made once
    while the scene lives: a plan's first guess, its simulations and its partition each
    asked for it (the 65,536-triangle tetra: 19 ms a map, three of a 0.3 s plan)."""
    lo, hi = (np.asarray(b, float) for b in box)
    key = ("occupancy map", lo.tobytes(), hi.tobytes(), int(voxels))
    return kept(scene, key, lambda: _mapped(scene, lo, hi, voxels))


def _mapped(scene: SceneData, lo, hi, voxels: int) -> tuple[tuple, bytes]:
    """`occupancy_map`, made: every object's range of voxels is marked at its eight corners
    and summed along the three axes, no loop per object."""
    tb = scene_tables(scene)
    ext = hi - lo
    thick = np.maximum(ext, 1e-3 * ext.max())
    res = np.clip(np.round(thick * (voxels / thick.prod()) ** (1 / 3)), 1, MAX_OCC_SIDE)
    res = res.astype(np.int64)
    diff = np.zeros(tuple((res + 1)[::-1]), np.int64)  # z, y, x: x fastest once flattened
    if tb.n:
        pad = 1e-6 * float(ext.max()) + 1e-12 * np.maximum(np.abs(tb.lo), np.abs(tb.hi))
        cell = ext / res
        first = np.clip(np.floor((tb.lo - pad - lo) / cell), 0, res - 1).astype(np.int64)
        last = np.clip(np.floor((tb.hi + pad - lo) / cell), 0, res - 1).astype(np.int64) + 1
        nx, ny = res[0] + 1, res[1] + 1
        for corner in range(8):  # counted with bincount: numpy's add.at is 5x slower
            at = [np.where(corner >> a & 1, last[:, a], first[:, a]) for a in range(3)]
            marks = np.bincount(at[0] + nx * (at[1] + ny * at[2]), minlength=diff.size)
            diff.reshape(-1)[:] += (-1) ** bin(corner).count("1") * marks
    full = diff.cumsum(0).cumsum(1).cumsum(2)[:-1, :-1, :-1] > 0
    return tuple(res.tolist()), np.packbits(full.ravel()).tobytes()
