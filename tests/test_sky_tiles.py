"""The sky's tiles (no probe ray enters a cell) dealt against the nodes' estimated loads
(`host.planning.rectangles.taker_tiles`): each to the least loaded so far, and whoever makes
them, the image and counts are one node's."""

import numpy as np
import pytest

from host.planning import rectangles
from host.planning.partition import partition
from host.planning.rectangles import EYE_NS, SKY_NS, _eye_seconds, _sky_tiles
from host.scene.nff import read_nff
from protocols.render import ImageSpec, MeshPlan, RenderSpec
from tests.conftest import spd_scene
from tests.meshsim import render_mesh
from tests.test_mesh_algorithm import SIZE, SPD_COUNTS, single


@pytest.mark.parametrize("loads", [[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [0.0, 5.0, 5.0, 5.0]])
def test_sky_tiles_go_to_the_least_loaded_until_the_loads_even_out(loads):
    # 40 tiles of 8x8 samples at 4 rays a pixel: each costs SKY_NS a ray to make; a node
    # starts with its load, and the tiles fill the lightest up first, so the loaded nodes
    # end within a tile of each other and a node loaded past that level gets none.
    rects = [(0, 8, 0, 8)] * 40
    tile = 8 * 8 * 4 * SKY_NS * 1e-9
    got = _sky_tiles(rects, np.array(loads) * 40 * tile / 4, 4)
    start = np.array(loads) * 40 * tile / 4
    end = start + np.bincount(got, minlength=len(loads)) * tile
    took = end > start
    assert len(got) == 40 and took.any()
    assert end[took].max() - end[took].min() <= tile * (1 + 1e-9)
    assert (start[~took] >= end[took].min() - tile).all()


def test_a_mesh_whose_sky_goes_to_its_lightest_nodes_renders_as_one():
    # A tetrahedron under a wide sky on 2x2 object cells, node 0 told it is loaded: the sky's
    # tiles go to the others, and the image and counts are still one node's.
    scene = read_nff(spd_scene("tetra_s3.nff"))
    ref_img, ref_counts = single(scene)
    loads = [1.0, 0.0, 0.0, 0.0]
    img, totals, nodes, _ = render_mesh(
        scene, 2, 2, 1.0, SIZE, SIZE, balance="objects", loads=loads, tile=4
    )
    np.testing.assert_allclose(img, ref_img, rtol=0, atol=1e-5)
    assert {k: totals[k] for k in SPD_COUNTS} == ref_counts
    spec = RenderSpec(
        ImageSpec(width=SIZE, height=SIZE).sized(scene.view),
        plan=MeshPlan(2, 2, 1.0, balance="objects", tile=4),
    )
    told, left = (np.array(partition(scene, spec, loads=w)[0].owner) for w in (loads, None))
    moved = told != left
    assert moved.any() and (told[moved] != 0).all()


def test_each_node_is_charged_the_eye_rays_of_the_tiles_it_takes_on():
    # Three tiles: node 1 takes on a 4x2 and a 2x2, node 0 a 3x3 no probe ray enters (the
    # sky's, charged when dealt, not here); at 5 rays a pixel, EYE_NS each.
    rects = [(0, 4, 0, 2), (4, 6, 0, 2), (0, 3, 2, 5)]
    got = _eye_seconds(rects, np.array([1, 1, 0]), np.array([True, True, False]), 3, 5)
    assert got == pytest.approx(np.array([0.0, 12 * 5, 0.0]) * EYE_NS * 1e-9, rel=1e-12)


def test_the_sky_goes_first_to_the_nodes_making_fewest_eye_rays(monkeypatch):
    # Equal pre-pass loads on 2x2 object cells over a tetrahedron under a wide sky: each
    # node's own tiles' eye rays are its load when the sky is dealt, so the nodes given the
    # sky end within a tile of each other, own eye rays and sky counted, and a node left
    # without it makes more than that already (the sky dealt evenly would leave them apart
    # by the difference of their own eye rays, more than two tiles here).
    scene = read_nff(spd_scene("tetra_s3.nff"))
    spec = RenderSpec(
        ImageSpec(width=SIZE, height=SIZE).sized(scene.view),
        plan=MeshPlan(2, 2, 1.0, balance="objects", tile=4),
    )
    seen, deal = [], rectangles._sky_tiles

    def watched(rects, load, rpp):
        seen.append(load.copy())
        return deal(rects, load, rpp)

    monkeypatch.setattr(rectangles, "_sky_tiles", watched)
    part, _ = partition(scene, spec, loads=[0.0] * 4)
    made = seen[0]  # each node's own tiles' eye rays, in seconds
    r = np.asarray(part.rects).reshape(-1, 4)
    rpp = spec.rays_per_pixel
    rays = np.bincount(part.owner, (r[:, 1] - r[:, 0]) * (r[:, 3] - r[:, 2]), 4) * rpp
    sky = rays - made / (EYE_NS * 1e-9)  # the sky's rays each node makes
    end = made + sky * SKY_NS * 1e-9
    tile = 16 * rpp * SKY_NS * 1e-9
    took = sky > 0.5
    assert took.any() and made.max() - made.min() > 2 * tile, made
    assert end[took].max() - end[took].min() <= tile * (1 + 1e-9), (made, sky)
    assert (made[~took] >= end[took].min() - tile).all(), (made, sky)
