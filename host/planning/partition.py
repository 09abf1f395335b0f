"""Cutting the work over a rows x cols mesh: the plan made concrete as every node's
rectangles (`host.planning.rectangles`), its cell and box (`host.planning.cells`), the scene's
occupancy map (`host.planning.occupancy`) and the objects it holds (`host.planning.clip`)
(DESIGN.md 5).

The cost pre-pass may cut the cells in object space instead, where its work map puts the work
(`host.planning.workmap`); the rectangles then only say who makes which eye rays. Correctness
never depends on the cut: a ray is always handed to a box that holds it (see
`meshnode.engine.locator.owners`); the cut only decides how often.
"""

import numpy as np

from host.planning.cells import grown, node_cells, scene_box, traced
from host.planning.clip import holders
from host.planning.objectcells import object_cells
from host.planning.occupancy import inner_map, map_voxels, occupancy_map
from host.planning.rectangles import rectangles, spread, taker_tiles, tiles
from host.planning.skytiles import SkyTiles, dealt_sky, sky_tiles
from host.scene.derived import kept, scene_tables
from meshnode.engine.occupancy import occupancy_arrays
from meshnode.engine.sky import looked_for
from protocols.partition import Partition
from protocols.render import EVERYWHERE, RenderSpec
from protocols.scene import SceneData


def image_partition(scene: SceneData, spec: RenderSpec) -> tuple[Partition, np.ndarray, SkyTiles]:
    """Image space's partition, holders (every object on every node) and the tiles the host
    deposits itself, for every eye ray of theirs meets nothing (`host.planning.skytiles`):
    the scene's occupancy map goes to the nodes where the sky is looked for, and the dealt
    tiles are cut around the sky's."""
    plan, box = spec.plan, scene_box(scene)
    los, his = np.tile(box[0], (plan.nodes, 1)), np.tile(box[1], (plan.nodes, 1))
    keep = np.ones((plan.nodes, scene_tables(scene).n), bool)
    occ = EVERYWHERE  # ... or the map the nodes see the sky from (`meshnode.engine.sky`)
    if spec.camera is None and not looked_for(spec.image):
        occ = occupancy_map(scene, box, sub_voxels=False)  # the sky reads the voxels alone
    sky, why = dealt_sky(scene, spec, box, occ)
    rects, owner = tiles(*spec.sample_grid, plan, sky)
    part = Partition.make(rects, los, his, box, owner, occupancy=occ)
    return part, keep, sky_tiles(sky, why, rects)


def scene_maps(scene: SceneData, box, plan) -> tuple:
    """(inner map or None, occupancy map) an object-space plan's nodes get (kept with the
    scene: the plan's every simulation and its partition read the same)."""
    voxels = map_voxels(plan)  # under a byte budget an inner map takes half the map's bytes
    inner = inner_map(scene, box, voxels // 2 if plan.node_bytes else voxels)
    outer = voxels - voxels // 2 if inner is not None and plan.node_bytes else voxels
    occ = occupancy_map(scene, box, outer)
    return (None if occ == EVERYWHERE else inner), occ  # a map of one voxel skips nothing


def partition(
    scene: SceneData,
    spec: RenderSpec,
    xs=None,
    ys=None,
    cells=None,
    occupancy: bool = True,
    loads=None,
) -> tuple[Partition, np.ndarray]:
    """The plan made concrete: every node's rectangles of the sample grid and its box, and
    which objects each node holds (nodes x objects, bool). Object space: one rectangle a
    node, cut at `xs`, `ys` (default even); cells (los, his) as given (cut where the work
    lies: `host.planning.workmap`), else cut by the objects under balance "objects"
    (`host.planning.objectcells`), else cut to match the rectangles; the scene's occupancy map
    unless `occupancy` is False (where walking it costs more than the passes it saves:
    `host.planning.holding`); `loads` (each node's estimated CPU seconds, from the pre-pass)
    deals the tiles no eye ray enters to the least loaded (`rectangles.taker_tiles`). Image
    space: tiles, every box the scene's, every object on every node."""
    plan, (width, height) = spec.plan, spec.image.size
    gw, gh = spec.sample_grid
    box = scene_box(scene)
    if plan.mode == "image":
        return image_partition(scene, spec)[:2]
    if cells is None and plan.balance == "objects":
        cells = object_cells(scene, box, plan.rows, plan.cols)
    elif cells is None:
        cells = node_cells(scene, box, width, height, plan.rows, plan.cols, xs, ys)
    los, his = grown(*cells, plan.overlap)
    mapped = plan.nodes > 1 and occupancy
    inner, occ = scene_maps(scene, box, plan) if mapped else (None, EVERYWHERE)
    rects, owner, takers = rectangles(gw, gh, plan.rows, plan.cols, xs, ys), None, ()
    if plan.nodes > 1 and not spec.adaptive:
        key = ("occupancy arrays", *(np.asarray(b, float).tobytes() for b in box), *occ)
        occ_arrays = kept(scene, key, lambda: occupancy_arrays(*box, *occ))  # not changed
        rects, owner = taker_tiles(scene, spec, cells, rects, box, occ_arrays, loads)
        if plan.copies:
            takers, owner = owner, spread(owner, plan)
    return (
        Partition.make(rects, los, his, box, owner, cells, occ, takers, inner),
        holders(scene, *traced(los, his)),
    )
