"""`meshnode warmup`: compile every kernel variant the engine can choose into the disk cache,
so a node (or a container image built with it) never compiles while a render waits.

The engine compiles one variant per set of primitive kinds, smooth triangles, lights,
transmitters and structure (`meshnode.engine.variants.Variant`); which one a node needs depends
on the objects its box holds, so a node of a mesh can need any of them. Each variant is
compiled on a tiny scene that makes the engine choose exactly it.
"""

import time

import numpy as np

from meshnode.engine.variants import KERNELS, STRUCTURES, Variant
from protocols import dtypes
from protocols.scene import OBJECT_KINDS, SceneData, View

ALL_KINDS = Variant(OBJECT_KINDS, True, True, True, "bvh")
# The variants with every kind, one per structure (`meshnode warmup --common`; the tests'):
# what an engine over `variant_scene(ALL_KINDS)` compiles, whichever structure it chooses.
EVERY_KIND = [ALL_KINDS._replace(structure=s) for s in STRUCTURES]


def variant_scene(variant: Variant) -> SceneData:
    """A scene of one object per kind of `variant`, smooth triangles, a light and a
    transmitter as it says, for which the engine chooses `variant` itself."""
    scene = SceneData(view=View((0, 0, -5), (0, 0, 0), (0, 1, 0), 45.0))
    scene.materials = np.array(
        [((1, 1, 1), 0.8, 0.2, 10, 0, 1), ((1, 1, 1), 0.1, 0.1, 10, 0.9, 1.5)], dtypes.MATERIAL
    )
    if variant.shadows:
        scene.lights = np.array([((0, 5, -5), (1, 1, 1))], dtypes.LIGHT)
    mat = 1 if variant.refraction else 0  # the first object transmits, the others do not
    gid = 0
    if "spheres" in variant.kinds:
        scene.spheres = np.array([(gid, mat, (0, 0, 0), 1.0)], dtypes.SPHERE)
        gid, mat = gid + 1, 0
    if "triangles" in variant.kinds:
        v = np.array([(2, 0, 0), (3, 0, 0), (2, 1, 0)], float)
        normals = np.tile((0, 0, -1.0), (3, 1))
        scene.triangles = np.array([(gid, mat, v, normals, int(variant.smooth))], dtypes.TRIANGLE)
        gid, mat = gid + 1, 0
    if "polygons" in variant.kinds:
        # five vertices: an engine traces a convex quad as two triangles (`quads`)
        scene.polygons = np.array([(gid, mat, 0, 5)], dtypes.POLYGON)
        scene.vertices = np.array(
            [(-3, -1, 1), (3, -1, 1), (3, 1, 1), (0, 2, 1), (-3, 1, 1)], float
        )
        gid, mat = gid + 1, 0
    if "cones" in variant.kinds:
        scene.cones = np.array([(gid, mat, (-2, 0, 0), 0.5, (-2, 1, 0), 0.2)], dtypes.CONE)
    return scene


def warmup(
    variants=EVERY_KIND, report=None, common: bool = True, kernels=KERNELS, builds: bool = True
) -> float:
    """Compile (or load) the kernels of `variants` (default: the all-kinds ones; every one:
    `all_variants()`) and, with `common`, the pinhole eye rays, ray routing and the camera;
    returns the seconds. `kernels`: which of each variant's (`Engine.warmup`; a node can
    need any); `builds`: each variant's structure built, its build kernels compiled with it
    (the grid's are typed by the kinds; the hierarchy's, the same for every variant, at
    least once: "auto" builds it whatever it then chooses), else a stand-in of no objects
    (`Engine(stand_in=True)`: only the tracing kernels compile, as beside a first render).
    `report(i, n, name)` is called before each variant."""
    from meshnode.engine import Engine

    start = time.perf_counter()
    variants = list(variants)
    for i, variant in enumerate(variants):
        if report is not None:
            report(i, len(variants), variant.name)
        scene = variant_scene(variant)
        Engine(scene, structure=variant.structure, stand_in=not builds).warmup(kernels)
        if i == 0 and builds and variant.structure == "grid":
            Engine(scene, structure="bvh")
    if common:
        _common_warmup()
    return time.perf_counter() - start


def _common_warmup() -> None:
    """The kernels every variant shares: pinhole eye rays, ray routing between boxes, the
    occupancy map's per-octant table (a mesh node's; one node's full map needs none), the
    check of a neighbour's rays, deposits, and the camera rays (elements, sampling, records)
    on a one-pixel batch."""
    from meshnode.engine.camera import eye_rays
    from meshnode.engine.counters import N_COUNTERS
    from meshnode.engine.deposits import cell_sums, lit
    from meshnode.engine.lenscamera import camera_rays
    from meshnode.engine.lightmaps import light_maps
    from meshnode.engine.locator import cell_locator, owners
    from meshnode.engine.mapwalk import skip_empty
    from meshnode.engine.occupancy import everywhere, occupancy_arrays
    from meshnode.engine.raycheck import first_untraceable
    from meshnode.engine.routing import routed, start_cells
    from meshnode.engine.sightlines import eye_map
    from protocols.camera import CameraSpec
    from protocols.render import ImageSpec

    view = View((0, 0, 0), (0, 0, 1), (0, 1, 0), 45.0)
    rays = eye_rays(view, ImageSpec(width=1, height=1))
    box = (np.zeros(3), np.ones(3))
    owners(rays, box[0][None], box[1][None])
    # a node's map: one voxel of two empty, the other's sub-voxel mask all set (its marked
    # boxes are a kernel's: `mapbounds.marked_box`)
    half = occupancy_arrays(*box, (2, 1, 1), bytes([0x80]), (2**64 - 1).to_bytes(8, "little"))
    occ = everywhere(*box)
    skip_empty(rays.copy(), *box, *occ, np.zeros(N_COUNTERS, np.int64))  # the host's probes
    cells = box[0][None], box[1][None]
    eye, _ = eye_map(half, view, ImageSpec(width=1, height=1), cells)  # ... seen from the eye
    light_maps(half, np.ones((1, 3)))  # ... and from a light: an object-space node's engines
    routed(rays, True, 0, *box, occ, *cells, cell_locator(*cells), eye)  # a node's batches
    start_cells(rays, *box, occ, *cells, cell_locator(*cells))  # ... and where it makes them
    first_untraceable(rays)  # a neighbour's RAYS
    deposits = np.zeros(2, dtypes.DEPOSIT)
    cell_sums(deposits, 1, deposits.copy())
    lit(rays, np.ones((1, 3)), deposits)
    lens = np.zeros(1, dtypes.ELEMENT)
    lens["kind"], lens["focal"], lens["ax"], lens["ay"] = dtypes.THIN_LENS, 0.05, 0.01, 0.01
    spec = CameraSpec(lens, 0.036, 0.024, -0.051)
    camera_rays(spec, 16, view, 1, 1, np.zeros(1, int))
