"""The first guess of where in object space a render's work lies, before any cell is measured.

Work gathers where the eye rays' work starts: a ray's walk, its hits, its shadow rays and its
reflections begin at the first surface it meets. Objects alone say little of that (a teapot's
floor is one object holding most of the eye rays; rings' back rows hold as many objects as
the front, where the work is). So the guess is mostly where the coarse image's eye rays first
meet an occupied voxel of the scene's occupancy map, and the rest where the objects are (the
rays that pass among them: shadow rays, reflections). Walking the map uses the routing
kernel the cost pre-pass compiles anyway (`meshnode.engine.routing.routed`).
"""

import numpy as np

from host.planning.occupancy import map_voxels, occupancy_map
from host.planning.prepass import coarse_spec
from host.scene.derived import scene_tables
from meshnode.engine.camera import eye_rays
from meshnode.engine.locator import cell_locator
from meshnode.engine.occupancy import occupancy_arrays
from meshnode.engine.routing import routed
from meshnode.engine.sightlines import NO_EYE_MAP
from protocols.render import ImageSpec, RenderSpec
from protocols.scene import SceneData

# Share of the guess on where the eye rays' work starts (the rest on the objects' centres):
# simulated 3x3 under a quarter share, the plan's busiest node at 4 spp against the objects
# alone was 0.55-0.93 at 0.5, 0.8 and 0.95 alike on five SPD scenes
SEEN = 0.8


def first_guess(scene: SceneData, spec: RenderSpec, box, bins: int) -> np.ndarray:
    """Work per voxel of a bins^3 grid over `box`, summing to 1: SEEN of it where the coarse
    image's eye rays' work starts (`seen_starts`), the rest on the objects (`objects_density`)."""
    seen, objects = seen_starts(scene, spec, box, bins), objects_density(scene, box, bins)
    if seen.sum() == 0:  # no eye ray meets the scene: nothing seen to go by
        return objects / objects.sum()
    return SEEN * seen / seen.sum() + (1 - SEEN) * objects / objects.sum()


def seen_starts(scene: SceneData, spec: RenderSpec, box, bins: int) -> np.ndarray:
    """Per voxel of a bins^3 grid over `box`, the coarse image's pinhole eye rays (the
    view's, whatever the camera) whose walk of the scene's occupancy map first meets an
    occupied voxel there."""
    lo, hi = (np.asarray(b, float) for b in box)
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, box, map_voxels(spec.plan)))
    width, height = coarse_spec(spec).image.size
    rays = eye_rays(scene.view, ImageSpec(width=width, height=height))
    los, his = lo[None], hi[None]
    out, _, _ = routed(rays, True, 0, lo, hi, occ, los, his, cell_locator(los, his), NO_EYE_MAP)
    t = out["t_min"]
    # a ray meeting only empty voxels resumes where it leaves the box: no start there
    started = np.isfinite(t) & (t < _exits(out["o"], out["d"], lo, hi) * (1 - 1e-9))
    at = out["o"][started] + out["d"][started] * t[started, None]
    edges = list(zip(lo, hi, strict=True))
    count, _ = np.histogramdd(np.clip(at, lo, hi), bins=bins, range=edges)
    return count


def _exits(o, d, lo, hi) -> np.ndarray:
    """Where each ray (o, d) leaves the box lo..hi (-inf where it misses the box)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - o) / d, (hi - o) / d
    near = np.nanmax(np.minimum(t0, t1), axis=1)
    far = np.nanmin(np.maximum(t0, t1), axis=1)
    return np.where(near <= far, far, -np.inf)


def objects_density(scene: SceneData, box, bins: int) -> np.ndarray:
    """The objects' centres per voxel of a bins^3 grid over `box`, and a little everywhere
    (rays cross empty space too)."""
    tb = scene_tables(scene)
    lo, hi = box
    centres = 0.5 * (tb.lo + tb.hi) if tb.n else np.zeros((0, 3))
    count, _ = np.histogramdd(centres, bins=bins, range=list(zip(lo, hi, strict=True)))
    return count + 0.05 * max(count.mean(), 1e-9)
