"""Eye rays made where they are traced (`meshnode.mesh.claims`): a ray entering the cell its
block sees first before any other cell's marked sub-voxels meets none before that entry
(brute force over every sub-voxel), and a mesh whose nodes make the rays
they claim renders the same image (to round-off: deposits come in another order) and
counts as one whose nodes make their rectangles', with fewer passes."""

import numpy as np
import pytest

import meshnode.mesh.node
from host.planning.cells import scene_box
from host.planning.occupancy import occupancy_map
from host.scene.nff import read_nff
from meshnode.engine.camera import eye_rays
from meshnode.engine.locator import cell_locator
from meshnode.engine.occupancy import occupancy_arrays
from meshnode.engine.routing import routed, start_cells
from meshnode.engine.sightlines import NO_EYE_MAP, SEEN_NONE, eye_map
from meshnode.mesh.claims import claimed_bands
from protocols.render import ImageSpec
from tests.conftest import spd_scene
from tests.meshsim import render_mesh
from tests.test_mesh_algorithm import SPD_COUNTS
from tests.test_sightlines import _cells, _entry, _first_marked_brute, _views


def _start_of_each(rays, box, occ, cells, loc):
    """Per ray the cell its work starts in by the map's full walk (-1 where it meets no
    occupied voxel: routed once to fallback 0 and once to 1, only those rays move) and the t
    it starts from there."""
    index = np.arange(len(rays))
    rays = rays.copy()
    rays["w"][:, 0] = index
    dest, t = [], np.empty(len(rays))
    for fallback in (0, 1):
        out, starts, _ = routed(rays, True, fallback, *box, occ, *cells, loc, NO_EYE_MAP)
        d = np.empty(len(rays), np.int64)
        for b in range(len(starts) - 1):
            d[out["w"][starts[b] : starts[b + 1], 0].astype(np.int64)] = b
        t[out["w"][:, 0].astype(np.int64)] = out["t_min"]
        dest.append(d)
    return np.where(dest[0] == dest[1], dest[0], -1), t


@pytest.mark.parametrize(
    "name", ["tetra_s3.nff", "balls_s1.nff", "mount_s1.nff", "teapot_s1.nff", "gears_s1.nff"]
)
def test_an_eye_ray_entering_its_first_cell_before_the_others_starts_there(name):
    scene = read_nff(spd_scene(name))
    lo, hi = scene_box(scene)
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, (lo, hi), voxels=24**3))
    cells = _cells(lo, hi)
    box = (np.asarray(lo, float), np.asarray(hi, float))
    loc = cell_locator(*cells)
    tested = {"first": 0, "none": 0, "others": 0}
    rng = np.random.default_rng(11)
    for view in _views(scene, lo, hi):
        for image in (ImageSpec(width=48, height=40, spp=4), ImageSpec(width=47, height=31)):
            eye, _ = eye_map(occ, view, image, cells)
            rays = eye_rays(view, image)
            g = rays["pixel"] // eye.per_cell
            block = (g // eye.columns) // eye.side * eye.blocks_x + g % eye.columns // eye.side
            first, others = eye.first[block], eye.others[block]
            cell, start = _start_of_each(rays, box, occ, cells, loc)
            # where `block_cells` samples a block: the same cell, -1 for meeting no voxel
            assert np.array_equal(start_cells(rays, *box, occ, *cells, loc), cell)
            seen = first >= 0
            entry = np.full(len(rays), np.inf)
            entry[seen] = _entry(rays[seen], *(c[first[seen]] for c in cells))
            early = seen & (entry < others)  # routed into `first` from its entry, no walk
            # no marked sub-voxel lies before that entry (its own cell's work may start later,
            # in another cell, where the ray goes on from `first` by the walk from its exit;
            # the entry here by numpy's slabs, to round-off: a sub-voxel wall on the cell's
            # face), on a sample of the rays (brute force over every sub-voxel)
            some = rng.choice(len(rays), min(len(rays), 150), replace=False)
            marked = _first_marked_brute(rays[some], occ)
            assert np.isinf(marked[(first == SEEN_NONE)[some]]).all(), (name, view)
            slack = 1e-12 * np.abs(np.where(np.isfinite(entry[some]), entry[some], 0.0))
            assert not (marked < entry[some] - slack)[early[some]].any(), (name, view)
            # a block seeing no other cell: each ray's first marked sub-voxel there or none
            alone = (seen & np.isinf(others))[some]
            hit = alone & np.isfinite(marked)
            at = rays["o"][some][hit] + rays["d"][some][hit] * marked[hit, None]
            c = first[some][hit]
            reach = 1e-9 * (np.abs(at) + 1.0)
            assert ((at >= cells[0][c] - reach) & (at <= cells[1][c] + reach)).all(), (name, view)
            tested["first"] += int((early & (cell >= 0)).sum())
            tested["none"] += int((first == SEEN_NONE).sum())
            tested["others"] += int((seen & ~early).sum())
    assert tested["first"] > 100 and tested["others"] > 0, tested  # not vacuous


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
    node, used = meshnode.mesh.node, []
    own = node.node_claims
    runs = {}
    for claim in (True, False):
        claims_here = (lambda *a: used.append(own(*a)) or used[-1]) if claim else None
        monkeypatch.setattr(node, "node_claims", claims_here or (lambda *a: (None, "off")))
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
