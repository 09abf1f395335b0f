"""Eye rays that meet nothing, not traced: the sample-grid cells whose every pinhole eye ray
the scene's occupancy map, seen from the eye (`meshnode.engine.sightlines`), shows meets no
occupied voxel take the background as those rays would have brought it, with their counts.
Neither one process (`keep`, `deposits`) nor a mesh node makes them: a node's primary batch
of DEPOSIT records (`sky_batch`) stands for them, deposited and counted with no routing and
no kernel call; in object space the node's eye map shows them, in image space the map the
host sends.

Such rays are 68% of tetra's at 256x256; made and traced, each cost one process about 55 ns
of its frame (7 to make, 29 for its packet to find nothing, the rest its deposit). Exact:
the map is conservative, so each of those rays would have escaped; an eye ray weighs 1, so
it deposits the background itself (0.0 + 1.0 * background), and a pixel's samples are all
in one cell, so its sum is the same fold of the same values, to the bit. Each is counted
as made and escaped; no segment is traced for it, so `ray_segments` is less by one each.
"""

from typing import NamedTuple

import numpy as np

from meshnode.engine.occupancy import Occupancy
from meshnode.engine.sightlines import INF, EyeMap, eye_map
from protocols.dtypes import DEPOSIT
from protocols.render import EVERYWHERE, ImageSpec, RenderSpec
from protocols.scene import View

# Eye rays a render must make for the sky to be looked for: the map and its view cost 10-50 ms
# (tetra, jacks, shells, mount_s1, gears), a ray that meets nothing 40-65 ns of the frame's CPU
# (tetra, jacks), so where no ray is sky a render of this many loses at most about 1%.
SKY_MIN_RAYS = 1 << 22


class Sky(NamedTuple):
    """`cells` (rows by columns of the sample grid): True where every eye ray meets nothing;
    `rgb`: the deposit each of them brings; `per_cell`: samples per cell (spp, 1 at pixel
    corners); `columns`: the sample grid's; `cell_rgb`: a cell's deposits summed from zero
    in order, as `deposits.cell_sums` sums a batch's."""

    cells: np.ndarray
    rgb: np.ndarray
    per_cell: int
    columns: int
    cell_rgb: np.ndarray


def looked_for(image: ImageSpec) -> str:
    """Why the sky is not looked for in a pinhole render of `image` ("": it is): one rule
    for one process and image space, so their segments and work units agree (object-space
    nodes read it from the eye map they make anyway, at any size)."""
    columns, rows = image.sample_grid()
    rays = columns * rows * (1 if image.corners() else image.spp)
    if rays < SKY_MIN_RAYS:
        return f"not looked for: {rays} eye rays, under {SKY_MIN_RAYS}"
    return ""


def sky_of(box, occupancy, view: View, image: ImageSpec, background) -> tuple[Sky | None, str]:
    """The `Sky` of pinhole eye rays of `image` from `view` over the scene's occupancy map
    (`occupancy`: its voxels per axis and packed bits over `box`, lo and hi), None where no
    cell is sky, and why, for the stats."""
    eye, why = eye_map(_occupied(box, *occupancy), view, image)
    return seen(eye, why, image, background)


def node_sky(spec: RenderSpec, part, view: View, eye: EyeMap, why: str, background):
    """A mesh node's (`Sky` or None, why) (`part`: its Partition): in object space the one
    its eye map (`eye`, made as `why` says) shows, in image space from the map the host
    sends where the sky is looked for; None under a camera."""
    if spec.plan.mode == "object":
        return seen(eye, why, spec.image, background)
    if spec.camera is not None:
        return None, "not looked for: a camera makes the eye rays"
    if (part.occ_res, part.occ_bits) == EVERYWHERE:
        return None, looked_for(spec.image) or "no occupancy map sent"
    occupancy = (part.occ_res, part.occ_bits)
    return sky_of(part.scene_box, occupancy, view, spec.image, background)


def seen(eye: EyeMap, why: str, image: ImageSpec, background) -> tuple[Sky | None, str]:
    """The `Sky` an `EyeMap` of `image`'s pinhole eye rays shows (its blocks that see no
    occupied voxel; `why`: what the map's making said), None where there is none."""
    if eye.near.shape[0] == 0:
        return None, why
    columns, rows = image.sample_grid()
    open_blocks = (eye.near == INF).reshape(-1, eye.blocks_x)
    cells = np.repeat(np.repeat(open_blocks, eye.side, 0), eye.side, 1)[:rows, :columns]
    share = float(cells.mean())
    if share == 0.0:
        return None, f"{why}: no eye ray is sure to meet nothing"
    rgb = np.asarray(background, float) * 1.0
    per_cell, cell_rgb = 1 if image.corners() else image.spp, np.zeros(3)
    for _ in range(per_cell):
        cell_rgb = cell_rgb + rgb
    sky = Sky(np.ascontiguousarray(cells), rgb, per_cell, columns, cell_rgb)
    return sky, f"{share:.1%} of the eye rays meet nothing: the background deposited, not traced"


def _occupied(box, res, bits: bytes, fine: bytes = b"") -> Occupancy:
    """The map as `eye_map` reads it (row 0 of `clear`: 0 where a voxel is occupied), without
    the empty cubes a walk jumps by (`occupancy.reaches`: eight sweeps the sky has no use
    for, nor the sub-voxels: the voxels alone are conservative); voxels sized as
    `occupancy.occupancy_arrays` sizes them."""
    lo, hi = (np.asarray(b, float) for b in box)
    res = np.asarray(res, np.int64)
    full = np.unpackbits(np.frombuffer(bits, np.uint8), count=int(np.prod(res)))
    return Occupancy(
        lo, np.maximum((hi - lo) / res, 1e-300), res, (1 - full)[None, :], np.zeros(0, np.uint64)
    )


def cells_of(sky: Sky | None, rows, cols) -> np.ndarray:
    """Per sample-grid cell of the rectangle (rows by columns), whether its eye rays meet
    nothing."""
    if sky is None:
        return np.zeros((rows[1] - rows[0], cols[1] - cols[0]), bool)
    return sky.cells[rows[0] : rows[1], cols[0] : cols[1]]


def keep(sky: Sky | None, rows, cols) -> np.ndarray | None:
    """Per sample-grid cell of the rectangle, whether its eye rays are made (`camera.eye_rays`'
    keep); None: all of them."""
    return None if sky is None else ~cells_of(sky, rows, cols)


def _first_ids(flags: np.ndarray, y: int, x: int, sky: Sky) -> np.ndarray:
    """The first sample id of each flagged cell of a rectangle whose first cell is (`y`,
    `x`), in id order."""
    j, i = np.nonzero(flags)
    return ((j + y) * sky.columns + i + x) * sky.per_cell


def _ids(flags: np.ndarray, y: int, x: int, sky: Sky) -> np.ndarray:
    """Sample ids of the flagged cells of a rectangle whose first cell is (`y`, `x`), in id
    order."""
    first = _first_ids(flags, y, x, sky)
    return (first[:, None] + np.arange(sky.per_cell)).ravel()


def deposits(sky: Sky | None, rows, cols) -> tuple[np.ndarray, np.ndarray]:
    """(sample ids, colours) of the rectangle's eye rays that meet nothing, in id order: what
    each would have deposited."""
    if sky is None:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    ids = _ids(cells_of(sky, rows, cols), rows[0], cols[0], sky)
    return ids, np.broadcast_to(sky.rgb, (len(ids), 3))


def sky_batch(sky: Sky | None, flags: np.ndarray, y: int, x: int) -> np.ndarray:
    """A mesh node's primary batch standing for the eye rays that meet nothing of the flagged
    cells of a rectangle whose first cell is (`y`, `x`): a DEPOSIT record a cell, under its
    first sample's id, the background summed over its samples (`Sky.cell_rgb`: what the
    node's `per_cell` makes of their deposits), in id order; `Sky.per_cell` eye rays each
    (none: no cell flagged, or no sky). A cell's record, not a sample's: tetra 3x3 at 573
    spp made 130 MB of them a node at once, 0.2-0.3 s of system CPU in page faults."""
    if sky is None or not flags.any():
        return np.zeros(0, DEPOSIT)
    first = _first_ids(flags, y, x, sky)
    out = np.empty(len(first), DEPOSIT)
    out["pixel"], out["rgb"] = first, sky.cell_rgb
    return out


def counted(counts: dict, escaped: int) -> dict:
    """`counts` of the rays traced with those of `escaped` eye rays that met nothing: made
    (or stood for) and escaped, but no segment traced (the work units count only what is
    traced: a segment's 10 units for a ray that costs next to nothing made the work units of
    tetra's 4x4 image space spread 13.40 of 16 where its CPU spread 15.82)."""
    if escaped:
        for k in ("eye_rays", "escaped"):
            counts[k] = counts.get(k, 0) + escaped
    return counts


def whole_tiles(sky: Sky | None, rects) -> np.ndarray:
    """Indices of the tiles (x0, x1, y0, y1 of the sample grid) every eye ray of which meets
    nothing: under dynamic image space the host deposits them itself and deals them to no
    node (a tile costs a node its messages and film whatever it traces: dealt them, tetra
    4x4's nodes did 0.92-1.09 of the mean work units in the same frame CPU). Counted from a
    summed table of the cells that are not sky, so no loop over cells."""
    if sky is None or len(rects) == 0:
        return np.zeros(0, np.int64)
    table = np.zeros((sky.cells.shape[0] + 1, sky.cells.shape[1] + 1), np.int64)
    table[1:, 1:] = (~sky.cells).cumsum(0).cumsum(1)
    x0, x1, y0, y1 = np.asarray(rects, np.int64).T
    seen = table[y1, x1] - table[y0, x1] - table[y1, x0] + table[y0, x0]
    return np.flatnonzero(seen == 0)


def filled(sky: Sky | None, rects) -> tuple[np.ndarray, np.ndarray, dict]:
    """(indices, DEPOSIT records, counts) of the tiles of `rects` whose every cell is sky
    (`whole_tiles`): what the host deposits and counts for them, a record a cell
    (`sky_batch`) in id order, their eye rays made and escaped (`counted`)."""
    tiles = whole_tiles(sky, rects)
    if len(tiles) == 0:
        return tiles, np.zeros(0, DEPOSIT), {}
    flags = np.zeros_like(sky.cells)
    for t in tiles.tolist():  # once per tile, not per cell
        x0, x1, y0, y1 = rects[t]
        flags[y0:y1, x0:x1] = True
    records = sky_batch(sky, flags, 0, 0)
    return tiles, records, counted({}, len(records) * sky.per_cell)
