"""The scene's occupancy map on an object-space node: which coarse voxels of the whole scene
any object touches (the host rasterises every object's padded bounds, `host.planning.occupancy.
occupancy_map`; each node gets the same map with its partition).

A segment leaving a node's box goes on to the node whose cell holds it; when the rest of its
path crosses only empty voxels there is nothing left to hit, and passing it on would only
send it through every cell ahead to escape or reach its light. With the map the node that
has it ends it at once (the same colour, the same count: an escaped ray or a lit shadow ray),
and a segment that does meet an occupied voxel resumes at that voxel, so the nodes whose
cells it crosses empty never see it.

Exact because the map is conservative: an object's bounds are padded before they are
rasterised, so any point of any object lies inside occupied voxels by at least the padding,
and a segment resumed at the first occupied voxel it enters misses nothing before it.

An occupied voxel also carries which of its 4x4x4 sub-voxels a surface reaches
(`Occupancy.fine`, marked as the voxels are): a walk reaching it looks at the sub-voxels its
path through the voxel may cross, and goes on past it where none is marked. A 64^3 voxel
holding a few small spheres, or a slanted triangle's edge, is mostly empty, and every ray
crossing it was passed on to meet nothing there.

This module is the map; a ray's walk along it is `meshnode.engine.mapwalk`'s.
"""

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from meshnode.engine.jit import kernel
from protocols.render import EVERYWHERE

OCTANTS = 8  # rows of `Occupancy.clear`: one a ray octant
SUB = 4  # sub-voxels along each axis of a voxel (`Occupancy.fine`: 64 bits a voxel)
FINE_BYTES = 8  # a voxel's sub-voxel mask


def _sub_ranges() -> np.ndarray:
    """(3, SUB, SUB) uint64: per axis and range a..b of sub-voxel coordinates, the bits of
    every sub-voxel whose coordinate on that axis lies in a..b (bit x + SUB y + SUB^2 z)."""
    out = np.zeros((3, SUB, SUB), np.uint64)
    idx = np.arange(SUB**3)
    coord = (idx % SUB, idx // SUB % SUB, idx // SUB**2)
    for axis in range(3):
        for a in range(SUB):
            for b in range(a, SUB):
                bits = idx[(coord[axis] >= a) & (coord[axis] <= b)]
                out[axis, a, b] = np.bitwise_or.reduce(np.uint64(1) << bits.astype(np.uint64))
    return out


SUB_RANGES = _sub_ranges()


class Occupancy(NamedTuple):
    """The map as the kernels take it: box corner, voxel size, voxels per axis, and per ray
    octant (row: 1 for x, 2 for y, 4 for z where the direction is negative) and voxel (x
    fastest) the side in voxels of the largest empty cube with that voxel at its corner and
    reaching the way a ray of that octant goes (0: occupied, capped at 255): a walk through
    empty space jumps out of it in one step, as the grid's walk does through empty macro
    cells. A cube centred on the voxel (one Chebyshev distance for all rays) stops at the
    nearest object whatever side it lies on: a ray leaving a floor or a cluster upwards took
    3.4-8.2 steps to find nothing ahead (simulated 3x3, rings and teapot).

    With an inner map (a second map over the box where the scene's small objects lie, when a
    few large ones, a floor, make the scene's box far larger: `host.planning.occupancy.
    inner_map`) lo, cell and res hold the outer map's three values, then the inner's, and
    clear and fine the inner map's voxels after the outer's; `outer` and `inner` are each
    map alone."""

    lo: np.ndarray
    cell: np.ndarray
    res: np.ndarray
    clear: np.ndarray  # (8, voxels) uint8
    fine: np.ndarray  # (voxels,) uint64: an occupied voxel's marked sub-voxels; empty: none

    @property
    def outer(self) -> "Occupancy":
        return self if len(self.res) == 3 else self._alone(0)

    @property
    def inner(self) -> "Occupancy | None":
        """The inner map alone (None without one)."""
        return None if len(self.res) == 3 else self._alone(3)

    def _alone(self, at: int) -> "Occupancy":
        """The outer (at 0) or inner (at 3) map alone: views of the joined arrays."""
        n = int(np.prod(self.res[:3]))
        voxels = slice(0, n) if at == 0 else slice(n, None)
        fine = self.fine[voxels] if len(self.fine) else self.fine
        three = slice(at, at + 3)
        return Occupancy(
            self.lo[three], self.cell[three], self.res[three], self.clear[:, voxels], fine
        )

    def inside_inner(self) -> np.ndarray:
        """Per outer voxel (x fastest), whether it lies wholly inside the inner map's box:
        every surface there is marked on the inner map too."""
        lo, hi = self.lo[3:], self.lo[3:] + self.res[3:] * self.cell[3:]
        axes = []
        for a in range(3):
            walls = self.lo[a] + np.arange(self.res[a] + 1) * self.cell[a]
            axes.append((walls[:-1] >= lo[a]) & (walls[1:] <= hi[a]))
        return (axes[2][:, None, None] & axes[1][None, :, None] & axes[0][None, None, :]).ravel()


def map_stats(occ: Occupancy) -> dict:
    """A map in an engine's stats: voxels per axis and the share occupied, the inner map's
    voxels too where it has one, and why the map is used."""
    outer = occ.outer
    out = {
        "voxels": outer.res.tolist(),
        "occupied": float(np.mean(outer.clear[0] == 0)),  # 0 in every row
        "reason": "segments leaving this node's box with only empty voxels of the scene "
        "ahead end here; others resume at the first occupied voxel"
        if outer.res.prod() > 1
        else "one node or whole scene: nothing leaves the box to be skipped",
    }
    if len(occ.res) > 3:
        out["inner_voxels"] = occ.res[3:].tolist()
        out["inner_reason"] = (
            "the scene's small objects lie in a box far smaller than the scene's: a second "
            "map there walks them finer"
        )
    return out


def occupancy_arrays(lo, hi, res, bits: bytes, fine: bytes = b"", inner=None) -> Occupancy:
    """The kernels' form of a map over the box lo..hi of res voxels (x, y, z), packed `bits`
    (numpy's packbits order, x fastest) and `fine`, the occupied voxels' sub-voxel masks in
    voxel order (FINE_BYTES each, little-endian; empty: none); with `inner` (lo, hi, res,
    bits, fine: a map as these, its masks given as the outer's are) the inner map appended
    (`Occupancy`). The caller has checked the sizes."""
    maps = [(lo, hi, res, bits, fine), *([] if inner is None else [inner])]
    keys = [(tuple(int(v) for v in m[2]), bytes(m[3]), bytes(m[4])) for m in maps]
    if inner is None:
        clear, masks = _clear(*keys[0][:2]), _fine(*keys[0])
    else:
        clear, masks = _joined(*keys)
    corner = [np.asarray(m[0], float) for m in maps]
    voxels = [np.asarray(m[2], np.int64) for m in maps]
    cell = [
        np.maximum((np.asarray(m[1], float) - c) / r, 1e-300)
        for m, c, r in zip(maps, corner, voxels, strict=True)
    ]
    return Occupancy(*map(np.concatenate, (corner, cell, voxels)), clear, masks)


@lru_cache(maxsize=4)
def _joined(outer: tuple, inner: tuple) -> tuple:
    """(clear, fine) of an outer and an inner map, each given as (res, bits, fine), the
    inner's voxels after the outer's: made once, so the engines on the map share them as
    they share a single map's."""
    clear = np.concatenate([_clear(*outer[:2]), _clear(*inner[:2])], axis=1)
    return clear, np.concatenate([_fine(*outer), _fine(*inner)])


@lru_cache(maxsize=8)
def _fine(res: tuple, bits: bytes, fine: bytes) -> np.ndarray:
    """`Occupancy.fine` of a packed map: every voxel's mask, the occupied ones' from `fine`
    (shared, read only, by every engine built on the map, as `_clear` is)."""
    if not fine:
        return np.zeros(0, np.uint64)
    full = np.unpackbits(np.frombuffer(bits, np.uint8), count=int(np.prod(res))).astype(bool)
    out = np.zeros(full.size, np.uint64)
    out[full] = np.frombuffer(fine, "<u8")
    return out


@lru_cache(maxsize=8)
def _clear(res: tuple, bits: bytes) -> np.ndarray:
    """`reaches` of a packed map; one array shared by every engine built on the same map
    (the kernels only read it): a node builds an engine per box it holds and the cost
    pre-pass hundreds, all on the partition's one map (tetra 3x3's pre-pass: 328 builds,
    6.2 s of its 20 s in this function when it was a Chebyshev distance in NumPy)."""
    full = np.unpackbits(np.frombuffer(bits, np.uint8), count=int(np.prod(res))).astype(bool)
    if full.all():  # one node's map (`everywhere`): nothing to skip, no kernel to load
        return np.zeros((OCTANTS, full.size), np.uint8)
    return reaches(full.reshape(res[::-1]))


@kernel
def reaches(full):
    """(8, voxels) uint8: for each ray octant (see `Occupancy`) and voxel of the (z, y, x)
    map `full`, the side of the largest empty cube with the voxel at its corner reaching
    that octant's way, capped at 255; space past the map counts as empty. Each octant is
    one sweep against its rays' way: a side is one more than the least of the seven
    neighbours' the cube's other voxels lie in (the largest-square recurrence in 3-D)."""
    nz, ny, nx = full.shape
    out = np.empty((OCTANTS, nz * ny * nx), np.uint8)
    for octant in range(OCTANTS):
        sx = -1 if octant & 1 else 1
        sy = -1 if octant & 2 else 1
        sz = -1 if octant & 4 else 1
        side = out[octant]
        for kz in range(nz):
            z = nz - 1 - kz if sz > 0 else kz
            for ky in range(ny):
                y = ny - 1 - ky if sy > 0 else ky
                for kx in range(nx):
                    x = nx - 1 - kx if sx > 0 else kx
                    at = x + nx * (y + ny * z)
                    if full[z, y, x]:
                        side[at] = 0
                        continue
                    least = 255
                    for e in range(1, 8):
                        x2 = x + sx * (e & 1)
                        y2 = y + sy * ((e >> 1) & 1)
                        z2 = z + sz * ((e >> 2) & 1)
                        if 0 <= x2 < nx and 0 <= y2 < ny and 0 <= z2 < nz:
                            least = min(least, np.int64(side[x2 + nx * (y2 + ny * z2)]))
                    side[at] = min(least + 1, 255)
    return out


def everywhere(lo, hi) -> Occupancy:
    """A map of one occupied voxel: nothing is skipped (one node, image space)."""
    return occupancy_arrays(lo, hi, *EVERYWHERE)
