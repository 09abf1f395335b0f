"""Eye rays made where they are traced (`meshnode.mesh.claims`): a block of the sample grid
that the eye's map says sees one cell sends every eye ray to that cell or to none (against the
map's full walk from the scene's box), and a mesh whose nodes make the rays they claim renders
the same image (to round-off: deposits come in another order) and counts as one whose nodes
make their rectangles', with fewer passes."""

import numpy as np
import pytest

import meshnode.mesh.node
from host.planning.cells import scene_box
from host.planning.occupancy import occupancy_map
from host.scene.nff import read_nff
from meshnode.engine.camera import eye_rays
from meshnode.engine.occupancy import occupancy_arrays
from meshnode.engine.routing import cell_locator, routed
from meshnode.engine.sightlines import NO_EYE_MAP, SEEN_NONE, SEEN_SEVERAL, eye_map
from meshnode.mesh.claims import claimed_bands
from protocols.render import ImageSpec
from tests.conftest import spd_scene
from tests.meshsim import render_mesh
from tests.test_mesh_algorithm import SPD_COUNTS
from tests.test_sightlines import _cells, _views


def _cell_of_each(rays, box, occ, cells, loc):
    """Per ray the cell its work starts in by the map's full walk, -1 where it meets no
    occupied voxel (routed once to fallback 0 and once to 1: only those rays move)."""
    index = np.arange(len(rays))
    rays = rays.copy()
    rays["w"][:, 0] = index
    dest = []
    for fallback in (0, 1):
        out, starts, _ = routed(rays, True, fallback, *box, occ, *cells, loc, NO_EYE_MAP)
        d = np.empty(len(rays), np.int64)
        for b in range(len(starts) - 1):
            d[out["w"][starts[b] : starts[b + 1], 0].astype(np.int64)] = b
        dest.append(d)
    return np.where(dest[0] == dest[1], dest[0], -1)


@pytest.mark.parametrize(
    "name", ["tetra_s3.nff", "balls_s1.nff", "mount_s1.nff", "teapot_s1.nff", "gears_s1.nff"]
)
def test_a_block_seeing_one_cell_sends_its_eye_rays_there_or_nowhere(name):
    scene = read_nff(spd_scene(name))
    lo, hi = scene_box(scene)
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, (lo, hi)))
    cells = _cells(lo, hi)
    box = (np.asarray(lo, float), np.asarray(hi, float))
    loc = cell_locator(*cells)
    tested = {"one": 0, "none": 0, "several": 0}
    for view in _views(scene, lo, hi):
        for image in (ImageSpec(width=48, height=40, spp=4), ImageSpec(width=47, height=31)):
            eye, _ = eye_map(occ, view, image, cells)
            rays = eye_rays(view, image)
            g = rays["pixel"] // eye.per_cell
            block = (g // eye.columns) // eye.side * eye.blocks_x + g % eye.columns // eye.side
            only = eye.only[block]
            cell = _cell_of_each(rays, box, occ, cells, loc)
            one = only >= 0
            assert ((cell == only) | (cell == -1))[one].all(), (name, view)
            assert (cell[only == SEEN_NONE] == -1).all(), (name, view)
            tested["one"] += int((one & (cell >= 0)).sum())
            tested["none"] += int((only == SEEN_NONE).sum())
            tested["several"] += int((only == SEEN_SEVERAL).sum())
    assert tested["one"] > 100 and tested["several"] > 0, tested  # not vacuous


def test_bands_cover_every_claimed_cell_once_in_batches():
    rng = np.random.default_rng(1)
    mine = rng.random((37, 23)) < 0.3
    mine[5:9] = False
    covered = np.zeros(mine.shape, int)
    for y0, y1, x0, x1 in claimed_bands(mine, 4, 64):
        assert mine[y0:y1, x0:x1].any() and mine[y0:y1, x0:x1].sum() * 4 < 64 + 4 * 23
        covered[y0:y1, x0:x1] += mine[y0:y1, x0:x1]
    assert np.array_equal(covered, mine.astype(int))
    assert list(claimed_bands(np.zeros((3, 3), bool), 1, 8)) == []


@pytest.mark.parametrize("name", ["tetra_s3.nff", "gears_s1.nff"])
def test_a_mesh_making_the_eye_rays_it_claims_renders_as_one_making_its_rectangles(
    name, monkeypatch
):
    scene = read_nff(spd_scene(name))
    core, used = meshnode.mesh.node.NodeCore, []
    own = core._claims
    runs = {}
    for claim in (True, False):
        claims_here = (lambda self: used.append(own(self)) or used[-1]) if claim else None
        monkeypatch.setattr(core, "_claims", claims_here or (lambda self: (None, "off")))
        runs[claim] = render_mesh(scene, 2, 2, 1, 32, 32, spp=4, mode="object")
    (img, totals, nodes, _), (ref, ref_totals, ref_nodes, _) = runs[True], runs[False]
    # deposits arrive in another order: sums within round-off, as a mesh's against one node
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    for k in (*SPD_COUNTS, "hits", "escaped", "shadow_rays_lit"):
        assert totals[k] == ref_totals[k], k
    assert used and all(c is not None for c, _ in used), "the mesh made no claims"
    fewer = ref_totals["rays_forwarded"] - totals["rays_forwarded"]
    assert fewer > 0, (totals["rays_forwarded"], ref_totals["rays_forwarded"])
    sent = sum(n.rays_sent for n in nodes)
    assert sent <= sum(n.rays_sent for n in ref_nodes) - fewer
