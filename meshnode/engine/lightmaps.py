"""What each light sees of the occupancy map: per block of the six faces of a cube around it,
how near a ray from the light can meet a marked sub-voxel (the box of each occupied voxel's,
`mapbounds.marked_box`).

Shadow rays all end at their light: seen from each light through the six faces of a cube
around it (`light_maps`), a shadow ray leaving a node's box nearer its light than the bound
of its direction's block has no marked sub-voxel left to cross, and ends lit without the walk
of the map from its exit that would find so (`light_clear`). The eye's side, and the padding
that keeps the bounds exact, are `meshnode.engine.sightlines`'.
"""

import math

import numpy as np

from meshnode.engine.jit import kernel, leaf
from meshnode.engine.mapbounds import bound_maps, padded_voxel, per_map
from meshnode.engine.occupancy import Occupancy
from meshnode.engine.sightlines import INF, MARGIN

FACE_BLOCKS = 256  # blocks along a side of each face of a light's cube map, at most ...
LIGHT_MAP_BYTES = 16 << 20  # ... within this for all the lights (float32 bounds)
# no lights' maps: of the maps' type, so the tracing kernel is compiled for one
NO_LIGHT_MAPS = np.zeros((0, 0), np.float32)


def face_blocks(lights: int) -> int:
    """Blocks along a face's side for a scene's `lights`: the finest within LIGHT_MAP_BYTES,
    at least 16. A block must be narrow beside the map's voxels to tell a shadow ray
    through a gap from the voxels beside it: at 64 a face's block covered 4-6 voxels of
    balls' map as its lights see it, and half of the shadow rays walked for nothing more
    than at 256 (simulated balls 3x3 under a quarter: 128 k walks ending lit -> 64 k)."""
    fit = math.isqrt(LIGHT_MAP_BYTES // (4 * 6 * max(lights, 1)))
    return max(16, min(FACE_BLOCKS, fit))


def light_maps(occ: Occupancy, lights: np.ndarray | None) -> np.ndarray:
    """Per light (rows of `lights`, position first) and face of a cube around it (`_faces`),
    per block of `face_blocks` a side, the least distance from the light to an occupied
    voxel seen through that block, rounded down to float32: (lights, 6 * blocks**2); (0, 0)
    without lights. A shadow ray leaving a node's box nearer its light than its block's
    bound crosses only empty voxels to it (`light_clear`), so the walk of the map from its
    exit is not made. Made once a map and lights (`mapbounds.per_map`): every engine built
    on the map reads the same (the cost pre-pass builds hundreds)."""
    if lights is None or not len(lights):
        return NO_LIGHT_MAPS
    points = np.ascontiguousarray(lights[:, :3], float)
    blocks = face_blocks(len(points))

    def make():
        maps = bound_maps(occ)  # the map, or its outer and inner maps
        near = np.stack([np.minimum.reduce([_faces(*m, p, blocks) for m in maps]) for p in points])
        return _rounded_down(near)

    return per_map(occ, ("lights", points.tobytes()), make)


def _rounded_down(near: np.ndarray) -> np.ndarray:
    """`near` as float32, each value at most its own: a bound may only shrink."""
    out = near.astype(np.float32)
    return np.where(out > near, np.nextafter(out, np.float32(-np.inf)), out)


@kernel
def _faces(occupied, marked, lo, cell, res, point, s):
    """The six faces' blocks (`light_maps`) of one point. A voxel at distance r from the
    point is seen through a face (axis a, facing +a or -a) only where it lies at least
    r / sqrt(3) out along that axis (inside the face's pyramid a point's distance is at
    most sqrt(3) times its depth), so each face projects the voxel clipped there: a voxel
    across the face's plane bounds only the blocks it reaches, not the whole face."""
    near = np.full(6 * s * s, INF)
    b_lo, b_hi = np.empty(3), np.empty(3)
    for v in range(occupied.shape[0]):
        if occupied[v] != 0:
            continue
        r = padded_voxel(v, lo, cell, res, point, b_lo, b_hi, marked)
        bound = r * (1.0 - 1e-12)
        for face in range(6):
            a = face // 2
            b, c = (a + 1) % 3, (a + 2) % 3
            d0, d1 = (b_lo[a], b_hi[a]) if face % 2 == 0 else (-b_hi[a], -b_lo[a])
            d0 = max(d0, r * (1.0 - 1e-9) / math.sqrt(3.0))
            if not d0 > 0.0 or d1 < d0:
                if not d0 > 0.0 and d1 > 0.0:  # the point inside the padded voxel
                    for k in range(face * s * s, (face + 1) * s * s):
                        near[k] = min(near[k], bound)
                continue
            x0 = min(b_lo[b] / d0, b_lo[b] / d1)
            x1 = max(b_hi[b] / d0, b_hi[b] / d1)
            y0 = min(b_lo[c] / d0, b_lo[c] / d1)
            y1 = max(b_hi[c] / d0, b_hi[c] / d1)
            # as `light_clear` maps a direction: fx = u * s / 2 + s / 2, fy = s / 2 - w * s / 2
            fx0, fx1 = x0 * (0.5 * s) + 0.5 * s, x1 * (0.5 * s) + 0.5 * s
            fy0, fy1 = 0.5 * s - y1 * (0.5 * s), 0.5 * s - y0 * (0.5 * s)
            if fx1 + MARGIN < 0.0 or fy1 + MARGIN < 0.0 or fx0 - MARGIN >= s or fy0 - MARGIN >= s:
                continue
            i0 = max(int(math.floor(fx0 - MARGIN)), 0)
            i1 = min(int(math.floor(fx1 + MARGIN)), s - 1)
            j0 = max(int(math.floor(fy0 - MARGIN)), 0)
            j1 = min(int(math.floor(fy1 + MARGIN)), s - 1)
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    k = face * s * s + j * s + i
                    near[k] = min(near[k], bound)
    return near


@leaf
def light_clear(maps, light, lx, ly, lz, x, y, z):
    """Whether the segment from the light `light` at (lx, ly, lz) to (x, y, z) crosses only
    empty voxels by `light_maps` (False: it may not; walk the map)."""
    vx, vy, vz = x - lx, y - ly, z - lz
    ax, ay, az = abs(vx), abs(vy), abs(vz)
    if ax >= ay and ax >= az:
        face, depth, a, b = (0 if vx >= 0.0 else 1), ax, vy, vz
    elif ay >= az:
        face, depth, a, b = (2 if vy >= 0.0 else 3), ay, vz, vx
    else:
        face, depth, a, b = (4 if vz >= 0.0 else 5), az, vx, vy
    if not depth > 0.0:
        return False
    s = int(math.sqrt(maps.shape[1] // 6) + 0.5)  # `face_blocks` of the scene's lights
    fx = a / depth * (0.5 * s) + 0.5 * s  # as `_faces` projects with step 2 / s
    fy = 0.5 * s - b / depth * (0.5 * s)
    i = min(max(int(math.floor(fx)), 0), s - 1)
    j = min(max(int(math.floor(fy)), 0), s - 1)
    return maps[light, face * s * s + j * s + i] > math.sqrt(vx * vx + vy * vy + vz * vz)
