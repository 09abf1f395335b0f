"""Eye rays that meet nothing (`meshnode.engine.sky`): the cells the eye's view of the
occupancy map calls sky hold only rays that miss every object (a brute-force test of each
against every triangle), and a render that deposits the background for them instead of
tracing them gives the image and ray counts of one that traces every ray, to the bit."""

from dataclasses import replace

import numpy as np
import pytest

from host.planning.occupancy import occupancy_map
from host.planning.rectangles import guided_tiles, tile_grid
from host.planning.request import Request
from host.run import oneprocess
from host.run.summary import summary_line
from host.scene.nff import read_nff
from meshnode.engine import Engine, sky
from meshnode.engine.camera import eye_rays
from meshnode.engine.counters import RAY_COUNTS
from meshnode.mesh import node, simulator
from protocols.render import EngineSpec, ImageSpec, MeshPlan
from tests.conftest import spd_scene
from tests.meshsim import render_mesh


def _triangles_hit(o, d, tri):
    """Whether each ray (o, d) meets any triangle of `tri` (n, 3, 3) at t > 0: Moller-Trumbore
    in NumPy, every ray against every triangle, with a tolerance that only ever says hit."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d[:, None], e2[None])
    det = np.einsum("nk,rnk->rn", e1, p)
    inv = 1.0 / np.where(np.abs(det) < 1e-300, 1e-300, det)
    s = o[:, None] - tri[None, :, 0]
    u = np.einsum("rnk,rnk->rn", s, p) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("rk,rnk->rn", d, q) * inv
    t = np.einsum("nk,rnk->rn", e2, q) * inv
    eps = 1e-6
    return ((u > -eps) & (v > -eps) & (u + v < 1 + eps) & (t > -eps)).any(axis=1)


def _sky(scene, image, engine):
    box = (engine.scene_lo, engine.scene_hi)
    found, why = sky.sky_of(
        box, occupancy_map(scene, box), scene.view, image, engine.shading.background
    )
    assert why
    return found


def test_the_sky_holds_only_eye_rays_that_meet_no_object():
    scene = read_nff(spd_scene("tetra_s2.nff"))
    image = ImageSpec(width=48, height=40, spp=2)
    engine = Engine.from_spec(scene, EngineSpec(threads=1, structure="bvh"), max_depth=1)
    found = _sky(scene, image, engine)
    assert found is not None and 0.2 < found.cells.mean() < 0.95  # tetra leaves sky
    rays = eye_rays(scene.view, image, keep=found.cells)
    assert len(scene.triangles) == 16 and len(scene.spheres) == len(scene.polygons) == 0
    assert not _triangles_hit(rays["o"], rays["d"], scene.triangles["v"]).any()
    # the sky's rays are those that miss, not all of them: the brute force finds the rest
    rest = eye_rays(scene.view, image, keep=~found.cells)
    assert _triangles_hit(rest["o"], rest["d"], scene.triangles["v"]).mean() > 0.3
    ids, rgb = sky.deposits(found, (0, 40), (0, 48))
    assert np.array_equal(np.sort(ids), np.sort(rays["pixel"]))
    assert (rgb == np.asarray(scene.background)).all()


@pytest.mark.parametrize(
    "name, image",
    [
        ("tetra_s2.nff", ImageSpec(width=40, height=32, spp=3)),
        ("tetra_s2.nff", ImageSpec(width=40, height=32, spd=True)),  # rays at pixel corners
        ("balls_s1.nff", ImageSpec(width=32, height=32, spp=2)),  # no sky: nothing changes
        ("black", ImageSpec(width=40, height=32, spp=2)),  # tetra on a black background
    ],
)
def test_a_render_with_the_sky_equals_one_tracing_every_eye_ray(monkeypatch, name, image):
    if name == "black":  # the sky brings no colour, and its rays are still counted
        scene = replace(read_nff(spd_scene("tetra_s2.nff")), background=(0.0, 0.0, 0.0))
    else:
        scene = read_nff(spd_scene(name))
    request = Request(scene, image, EngineSpec(threads=1))
    monkeypatch.setattr(sky, "SKY_MIN_RAYS", 1 << 62)
    ref, ref_stats = oneprocess.render(request)
    assert ref_stats["sky"]["eye_rays"].startswith("not looked for")
    monkeypatch.setattr(sky, "SKY_MIN_RAYS", 0)
    img, stats = oneprocess.render(request)
    assert np.array_equal(img, ref)
    assert {k: stats["rays"][k] for k in RAY_COUNTS} == {
        k: ref_stats["rays"][k] for k in RAY_COUNTS
    }
    assert stats["rays"]["escaped"] == ref_stats["rays"]["escaped"]
    untraced = stats["sky"]["eye_rays_untraced"]  # made or not, escaped, but not traced
    assert stats["rays"]["ray_segments"] == ref_stats["rays"]["ray_segments"] - untraced
    said = f"{untraced} eye rays meet nothing: not traced"
    assert (said in summary_line("out.png", stats)) == (untraced > 0)  # beside the rays/s
    said = stats["sky"]["eye_rays"]
    assert ("meet nothing: the background deposited" in said) == ("balls" not in name), said


def _traced_alone(scene, image):
    """One process's image and counts with every eye ray traced (the sky not looked for)."""
    saved = sky.SKY_MIN_RAYS
    sky.SKY_MIN_RAYS = 1 << 62
    try:
        img, stats = oneprocess.render(Request(scene, image, EngineSpec(threads=1)))
    finally:
        sky.SKY_MIN_RAYS = saved
    return img, {k: stats["rays"][k] for k in (*RAY_COUNTS, "escaped", "ray_segments")}


@pytest.mark.parametrize(
    "plan",
    [
        dict(mode="image", tiles="static", tile=6),
        dict(mode="image", tiles="dynamic", tile=6),
        dict(mode="object", balance="objects"),
    ],
    ids=["image-static", "image-dynamic", "object"],
)
def test_mesh_nodes_leave_the_sky_untraced_and_give_the_one_node_image(monkeypatch, plan):
    # In image space the host sends the occupancy map where the sky is looked for, and each
    # node makes none of the eye rays it shows meet nothing, a batch of their deposits
    # standing for them; in object space every node does so from its eye map.
    scene = read_nff(spd_scene("tetra_s2.nff"))
    ref, counts = _traced_alone(scene, ImageSpec(width=40, height=32, spp=3))
    monkeypatch.setattr(sky, "SKY_MIN_RAYS", 0)
    made, stood, eye, batch, whole = [], [], node.eye_rays, node.sky_batch, simulator.filled
    monkeypatch.setattr(node, "eye_rays", lambda *a, **k: made.append(eye(*a, **k)) or made[-1])
    monkeypatch.setattr(node, "sky_batch", lambda *a: stood.append(batch(*a)) or stood[-1])
    filled = []  # dynamic tiles: those all sky the host deposits, dealt to no node
    monkeypatch.setattr(simulator, "filled", lambda *a: (r := whole(*a), filled.append(r[1]))[0])
    img, totals, _, _ = render_mesh(scene, 2, 2, 1, 40, 32, spp=3, **plan)
    assert (len(filled) > 0) == (plan.get("tiles") == "dynamic")
    made_ids = np.concatenate([r["pixel"] for r in made])
    cells = np.concatenate(stood + filled)  # a record a cell of 3 samples, its first id
    sky_ids = (cells["pixel"][:, None] + np.arange(3)).ravel()
    kept = (*RAY_COUNTS, "escaped")
    assert {k: totals[k] for k in kept} == {k: counts[k] for k in kept}
    if plan["mode"] == "image":  # a pixel's samples summed on one node, in the same order
        assert np.array_equal(img, ref)
        assert totals["ray_segments"] == counts["ray_segments"] - len(sky_ids)
    else:  # ... or where its rays' trees end: the same sums in another order
        np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
    assert len(np.intersect1d(made_ids, sky_ids)) == 0  # every eye ray made or stood for once
    assert len(made_ids) + len(sky_ids) == counts["eye_rays"]
    assert 0 < len(sky_ids) < counts["escaped"]  # tetra's sky, of the rays that escape
    np.testing.assert_allclose(
        cells["rgb"], np.tile(3 * np.asarray(scene.background), (len(cells), 1))
    )


def test_image_space_over_tcp_with_the_sky_equals_one_node(monkeypatch):
    import asyncio

    from host.run.connections import Nodes
    from host.run.localmesh import LocalMesh
    from host.run.meshclient import render_on_mesh

    scene, image = read_nff(spd_scene("tetra_s2.nff")), ImageSpec(width=40, height=32, spp=2)
    ref, counts = _traced_alone(scene, image)
    monkeypatch.setattr(sky, "SKY_MIN_RAYS", 0)  # the host's choice: the nodes follow its map
    plan = MeshPlan(1, 2, mode="image", tiles="dynamic", tile=8)
    with LocalMesh(plan.nodes) as addresses:
        coro = render_on_mesh(
            Request(scene, image, EngineSpec(threads=1), plan=plan), Nodes(addresses)
        )
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    assert np.array_equal(img, ref)
    kept = (*RAY_COUNTS, "escaped")
    assert {k: stats["rays"][k] for k in kept} == {k: counts[k] for k in kept}
    assert stats["rays"]["ray_segments"] < counts["ray_segments"]  # the sky's are not traced
    assert all("meet nothing: the background deposited" in n["sky"] for n in stats["nodes"])
    # the tiles all sky were deposited by the host and dealt to no node
    tiles = stats["sky_tiles"]
    assert 0 < tiles["tiles"] < tiles["of"]
    assert sum(stats["tiles_per_node"]) == tiles["of"] - tiles["tiles"]
    assert f"{tiles['tiles']} of {tiles['of']} tiles all sky" in summary_line("out", stats)


def test_the_tiles_all_sky_are_those_every_cell_of_which_is_sky():
    # A summed table of the cells that are not sky, against each tile's cells looked at.
    rng = np.random.default_rng(5)
    cells = rng.random((23, 31)) < 0.93
    found = sky.Sky(cells, np.ones(3), 2, 31, np.full(3, 2.0))
    rects = tile_grid(31, 23, 3)
    want = [i for i, (x0, x1, y0, y1) in enumerate(rects) if cells[y0:y1, x0:x1].all()]
    assert want and sky.whole_tiles(found, rects).tolist() == want
    records = sky.filled(found, rects)[1]  # a record a cell of those tiles
    assert len(records) == sum((x1 - x0) * (y1 - y0) for x0, x1, y0, y1 in (rects[i] for i in want))


def test_the_last_tiles_dealt_are_small_though_the_last_rows_are_sky():
    # The host deals no tile all sky, so the small tiles go where the last dealt tiles are.
    width, height, t, last = 64, 64, 8, 6
    cells = np.zeros((height, width), bool)
    cells[40:] = True  # the bottom three tile rows: sky
    found = sky.Sky(cells, np.ones(3), 1, width, np.ones(3))
    rects = guided_tiles(width, height, t, last, found)
    dealt = np.setdiff1d(np.arange(len(rects)), sky.whole_tiles(found, rects))
    sides = [rects[i][1] - rects[i][0] for i in dealt]
    assert set(sides[-last:]) == {t // 2} and sides[0] == t
    assert guided_tiles(width, height, t, last) == guided_tiles(width, height, t, last, None)
    plain = guided_tiles(width, height, t, last)  # no sky: the last row of eight, halved
    assert [r[1] - r[0] for r in plain].count(t // 2) == 32


def test_a_frame_all_sky_is_deposited_by_the_host_and_every_node_ends(monkeypatch):
    # No object in view: every tile is the sky's, no node is dealt one, and each is told
    # at once it gets none; the image is the background, the counts one node's.
    import asyncio

    from host.run.connections import Nodes
    from host.run.localmesh import LocalMesh
    from host.run.meshclient import render_on_mesh
    from tests.conftest import make_scene

    scene = make_scene(spheres=[((0, 0, -20), 1.0, 0)], lights=[(5, 5, -5)])  # behind the eye
    scene = replace(scene, background=(0.25, 0.5, 0.75))
    image = ImageSpec(width=24, height=16, spp=2)
    ref, counts = _traced_alone(scene, image)
    monkeypatch.setattr(sky, "SKY_MIN_RAYS", 0)
    plan = MeshPlan(1, 2, mode="image", tiles="dynamic", tile=8)
    with LocalMesh(plan.nodes) as addresses:
        coro = render_on_mesh(
            Request(scene, image, EngineSpec(threads=1), plan=plan), Nodes(addresses)
        )
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    assert stats["sky_tiles"]["tiles"] == stats["sky_tiles"]["of"] > 0
    assert stats["tiles_per_node"] == [0, 0]
    assert np.array_equal(img, ref)
    kept = (*RAY_COUNTS, "escaped")
    assert {k: stats["rays"][k] for k in kept} == {k: counts[k] for k in kept}
