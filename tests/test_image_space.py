"""Image-space mode (DESIGN.md 6): every node holds the whole scene and traces whole tiles,
no rays passed. On every mesh shape and tiling, pinhole, supersampled, camera and adaptive
renders give the single node's image and exactly its ray counts; adaptive pixels at tile
seams decide as on one node; every pixel is finished exactly once."""

import numpy as np
import pytest

from host.camera.setup import CameraSetup
from host.planning.partition import partition
from host.planning.rectangles import tiles
from host.planning.request import Request
from host.run.connections import Nodes
from host.run.oneprocess import render
from host.scene.nff import read_nff
from meshnode.engine.counters import RAY_COUNTS
from protocols.camera import CameraSampling
from protocols.render import EngineSpec, ImageSpec, MeshPlan, RenderSpec
from tests.conftest import spd_scene
from tests.meshsim import render_mesh
from tests.test_sampling import dof_scene, thin_camera

COUNTS = RAY_COUNTS
SHAPES = [(1, 2), (2, 2), (3, 3), (2, 3)]
TILINGS = [
    dict(tiles="none"),
    dict(tiles="static", tile=7),
    dict(tiles="dynamic", tile=5, buffer=2),
]


def reference(scene, image, camera=None):
    img, stats = render(Request(scene, image, EngineSpec(threads=1), camera))
    return img, {k: stats["rays"][k] for k in COUNTS}


@pytest.mark.parametrize("tiling", TILINGS, ids=["none", "static", "dynamic"])
@pytest.mark.parametrize("spp", [1, 4])
def test_pinhole_and_supersampled_on_every_shape_equal_one_node(tiling, spp):
    scene = read_nff(spd_scene("rings_s1.nff"))
    ref, counts = reference(scene, ImageSpec(width=30, height=26, spp=spp))
    for rows, cols in SHAPES:
        img, totals, nodes, _ = render_mesh(
            scene, rows, cols, 0, 30, 26, spp=spp, mode="image", **tiling
        )
        assert {k: totals[k] for k in COUNTS} == counts, (rows, cols)
        np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
        assert sum(n.rays_sent for n in nodes) == 0  # no ray leaves a node


@pytest.mark.parametrize("sampling", ["jittered", "adaptive"])
def test_camera_and_adaptive_on_every_shape_equal_one_node(sampling, monkeypatch):
    # Chunks of pass 2 start CHUNK_RAYS rays' worth at a time: a small budget leaves
    # some unstarted on this small image, for neighbours to steal.
    monkeypatch.setattr("meshnode.mesh.books.CHUNK_RAYS", 64)
    scene = dof_scene()
    image = ImageSpec(width=30, height=24, spp=9, seed=3)
    setup = CameraSetup(thin_camera(), CameraSampling(sampling=sampling))
    ref, counts = reference(scene, image, setup)
    spec, _ = setup.spec(scene, image.sized(scene.view), lambda: None)
    refined_taken = 0
    for rows, cols in SHAPES:
        for tiling in TILINGS:
            img, totals, nodes, _ = render_mesh(
                scene, rows, cols, 0, 30, 24, spp=9, seed=3, camera=spec, mode="image", **tiling
            )
            assert {k: totals[k] for k in COUNTS} == counts, (rows, cols, tiling)
            np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
            if tiling["tiles"] == "dynamic" and sampling == "adaptive":
                # pass 2 is stolen between neighbours (its books stay with the tile's node)
                given = sum(n.given_in.get("REFINE", 0) for n in nodes)
                assert given == sum(n.chunks_taken for n in nodes)
                assert not any(n.given_in.get("TRACE", 0) for n in nodes)
                refined_taken += given
    assert refined_taken > 0 or sampling != "adaptive"


def test_dynamic_adaptive_with_fewer_tiles_than_nodes_equals_one_node(monkeypatch):
    # Six tiles on nine nodes: nodes 6-8 are dealt none and keep no books, but steal pass-2
    # rows from their neighbours (a small batch budget leaves some unstarted) and send the
    # deposits on to the tiles' nodes.
    monkeypatch.setattr("meshnode.mesh.books.CHUNK_RAYS", 64)
    scene = dof_scene()
    image = ImageSpec(width=30, height=24, spp=9, seed=3)
    setup = CameraSetup(thin_camera(), CameraSampling(sampling="adaptive"))
    ref, counts = reference(scene, image, setup)
    spec, _ = setup.spec(scene, image.sized(scene.view), lambda: None)
    img, totals, nodes, _ = render_mesh(
        scene,
        3,
        3,
        0,
        30,
        24,
        spp=9,
        seed=3,
        camera=spec,
        mode="image",
        tiles="dynamic",
        tile=12,
        buffer=1,
    )
    assert {k: totals[k] for k in COUNTS} == counts
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
    assert sum(n.chunks_taken for n in nodes[6:]) > 0


def test_tiles_cover_every_pixel_exactly_once_and_are_dealt_round_robin():
    for w, h, tile, n in ((30, 26, 7, 4), (64, 64, 32, 9), (5, 3, 8, 4)):
        plan = MeshPlan(1, n, mode="image", tile=tile)
        rects, owner = tiles(w, h, plan)
        cover = np.zeros((h, w), int)
        for x0, x1, y0, y1 in rects:
            cover[y0:y1, x0:x1] += 1
            assert x1 - x0 <= tile and y1 - y0 <= tile
        assert (cover == 1).all()
        assert owner == [i % n for i in range(len(rects))]
        bands, band_owner = tiles(w, h, MeshPlan(1, n, mode="image", tiles="none"))
        assert band_owner == list(range(n)) and sum(y1 - y0 for *_, y0, y1 in bands) == h


def test_dynamic_tiles_dealt_last_are_half_size_and_cover_the_image_once():
    # The tiles dealt last decide how evenly the nodes finish: in the last rows (at least
    # nodes x buffer tiles) they are half the side; the rest stay whole; every sample once.
    for w, h, tile, rows, cols, buffer in ((512, 512, 32, 4, 4, 2), (100, 70, 16, 2, 2, 1)):
        plan = MeshPlan(rows, cols, mode="image", tiles="dynamic", tile=tile, buffer=buffer)
        rects, _ = tiles(w, h, plan)
        cover = np.zeros((h, w), int)
        for x0, x1, y0, y1 in rects:
            cover[y0:y1, x0:x1] += 1
        assert (cover == 1).all()
        sides = np.array([max(x1 - x0, y1 - y0) for x0, x1, y0, y1 in rects])
        small = np.flatnonzero(sides <= tile // 2)
        assert len(small) >= plan.nodes * buffer and small.min() > 0
        assert (np.diff(small) == 1).all() and small[-1] == len(rects) - 1  # dealt last
        assert (sides[: small.min()] > tile // 2).all()


def test_static_tiles_spread_each_node_over_the_columns_and_rows():
    # Plain round-robin where the tile columns divide the nodes gave each node one column
    # of the image; every node must take tiles of many columns, as many as any other +- 1.
    for columns, rows, n in ((8, 8, 8), (8, 8, 16), (4, 6, 8), (3, 5, 9), (24, 24, 48)):
        plan = MeshPlan(1, n, mode="image", tile=1)
        rects, owner = tiles(columns, rows, plan)
        owner = np.array(owner)
        counts = np.bincount(owner, minlength=n)
        assert counts.max() - counts.min() <= 1, (columns, n)
        xs = np.array([r[0] for r in rects])
        spread = [len(set(xs[owner == k].tolist())) for k in range(n)]
        assert min(spread) >= min(columns, rows * columns // n) // 2, (columns, n, spread)
    # where they do not divide the nodes, plain round-robin stays (each node keeps several)
    _, owner = tiles(24, 24, MeshPlan(1, 16, mode="image", tile=1))
    assert owner == [i % 16 for i in range(24 * 24)]


def test_every_node_holds_the_whole_scene_and_box():
    scene = read_nff(spd_scene("balls_s1.nff"))
    spec = RenderSpec(ImageSpec(width=16, height=16), plan=MeshPlan(2, 2, mode="image"))
    part, keep = partition(scene, spec)
    assert keep.all()
    los, his = part.boxes
    lo, hi = part.scene_box
    assert (los == lo).all() and (his == hi).all()


@pytest.mark.parametrize(
    "sampling,tiling", [(None, "static"), ("adaptive", "static"), ("adaptive", "dynamic")]
)
def test_image_space_over_tcp_equals_one_node(sampling, tiling):
    # Real node processes: the whole scene downloaded to each, tiles dealt, no rays passed;
    # adaptive seams travel as pixel packets between the tiles' owners (under dynamic tiles
    # once the host has said who those are).
    import asyncio

    from host.run.localmesh import LocalMesh
    from host.run.meshclient import render_on_mesh

    if sampling is None:
        scene, image, setup = read_nff(spd_scene("gears_s1.nff")), ImageSpec(40, 40), None
    else:
        scene, image = dof_scene(), ImageSpec(width=30, height=24, spp=9, seed=3)
        setup = CameraSetup(thin_camera(), CameraSampling(sampling=sampling))
    ref, counts = reference(scene, image, setup)
    plan = MeshPlan(2, 2, mode="image", tiles=tiling, tile=8 if tiling == "static" else 5)
    with LocalMesh(plan.nodes) as addresses:
        coro = render_on_mesh(
            Request(scene, image, EngineSpec(threads=1), setup, plan), Nodes(addresses)
        )
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    assert {k: stats["rays"][k] for k in COUNTS} == counts
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
    assert stats["rays_passed"] == 0 and stats["lost_nodes"] == []  # no node failed
    if sampling == "adaptive":  # seams crossed between nodes
        assert sum(n["pixel_packets"] for n in stats["nodes"]) > 0
    # under dynamic tiles pass 2's rows may be stolen: every chunk given was taken
    given = sum(n["chunks_given"] for n in stats["nodes"])
    assert given == sum(n["chunks_taken"] for n in stats["nodes"])
    assert given == 0 or tiling == "dynamic"  # static tiles: nothing to steal
    assert stats["objects_per_node"] == [stats["objects_per_node"][0]] * 4


def test_dynamic_tiles_over_tcp_finish_every_tile_once_and_equal_one_node():
    import asyncio

    from host.run.localmesh import LocalMesh
    from host.run.meshclient import render_on_mesh

    scene, image = read_nff(spd_scene("balls_s1.nff")), ImageSpec(48, 40, spp=2)
    ref, counts = reference(scene, image)
    plan = MeshPlan(2, 2, mode="image", tiles="dynamic", tile=6, buffer=2)
    with LocalMesh(plan.nodes) as addresses:
        coro = render_on_mesh(
            Request(scene, image, EngineSpec(threads=1), plan=plan), Nodes(addresses)
        )
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    assert {k: stats["rays"][k] for k in COUNTS} == counts  # every pixel traced exactly once
    assert np.array_equal(img, ref)  # a pixel's samples summed on its node, in the same order
    dealt = len(tiles(48, 40, plan)[0])
    assert sum(stats["tiles_per_node"]) == dealt and min(stats["tiles_per_node"]) > 0
    # Each node sent its pixels straight to the host, a pixel's two samples as one deposit:
    # none went over the torus.
    assert stats["deposits_received"] <= 48 * 40 < counts["eye_rays"]
    assert all(n["pixel_packets"] == 0 for n in stats["nodes"])


def test_the_dealer_deals_every_tile_once_and_closes_every_node():
    from meshnode.mesh.dealer import TileDealer

    for count, nodes, buffer in ((20, 3, 2), (2, 4, 3), (0, 2, 1)):
        dealer = TileDealer(range(count), nodes, buffer)
        given, closed, told = [], set(), 0
        pending = []
        for n, (first, last) in dealer.first().items():
            given += first
            pending += [n] * len(first)
            if last:
                closed.add(n)
                told += 1
        while pending:  # nodes report their tiles finished, in turn
            n = pending.pop(0)
            more, last = dealer.finished(n)
            given += more
            pending += [n] * len(more)
            if last:
                closed.add(n)
                told += 1
        assert sorted(given) == list(range(count)) and closed == set(range(nodes))
        assert told == nodes  # each node told once that it gets no more
        owners = dealer.owners()
        assert sorted(np.flatnonzero(owners >= 0).tolist()) == list(range(count))
        assert dealer.tiles_per_node() == np.bincount(owners, minlength=nodes).tolist()


def test_dynamic_tiles_are_dealt_from_the_centre_out_and_each_once():
    # MeshPlan.order "centre": the first tile dealt holds the image's middle, each tile is
    # no nearer the middle (in rings of tiles) than the one before, and the last are on the
    # border; "rows" deals them as the partition lists them
    from host.planning.rectangles import tile_grid
    from meshnode.mesh.dealer import deal_order

    for w, h, t in ((256, 256, 32), (300, 170, 32), (64, 40, 16), (32, 32, 32)):
        rects = tile_grid(w, h, t)
        order = deal_order(rects, "centre")
        assert sorted(order) == list(range(len(rects)))
        assert deal_order(rects, "rows") == list(range(len(rects)))
        cols, rows = -(-w // t), -(-h // t)
        ring = [max(abs(i % cols - (cols - 1) / 2), abs(i // cols - (rows - 1) / 2)) for i in order]
        assert ring == sorted(ring)
        x0, x1, y0, y1 = rects[order[0]]
        assert abs((x0 + x1) / 2 - w / 2) <= t and abs((y0 + y1) / 2 - h / 2) <= t
        x0, x1, y0, y1 = rects[order[-1]]
        assert x0 == 0 or y0 == 0 or x1 == w or y1 == h


def dynamic_adaptive_node():
    """Node 1 of a 1x2 image-space mesh, adaptive through a thin lens, 12x10 pixels in
    5-pixel tiles (row by row: 0-2 across the top); its `CameraSpec` and the partition."""
    from host.planning.partition import partition
    from meshnode.mesh.node import NodeCore

    scene = dof_scene()
    setup = CameraSetup(thin_camera(), CameraSampling(sampling="adaptive"))
    image = ImageSpec(width=12, height=10, spp=9).sized(scene.view)
    camera, _ = setup.spec(scene, image, lambda: None)
    spec = RenderSpec(
        image, plan=MeshPlan(1, 2, mode="image", tiles="dynamic", tile=5), camera=camera
    )
    part, _ = partition(scene, spec)
    return NodeCore(1, scene, spec, part), camera, part


def pass1_deposit(camera, pixel: int, n: int = 1):
    """`n` deposits of a pixel's first pass-1 corner ray."""
    from meshnode.mesh.adaptive import pass_samples
    from protocols.dtypes import DEPOSIT

    d = np.zeros(n, DEPOSIT)
    d["pixel"] = pixel * camera.per_pixel(9) + pass_samples(camera, 9)[0][0]  # at spp 9
    return d


def test_a_seam_deposit_held_for_a_tile_dealt_here_later_is_kept_once_in_each_film():
    # Pixel (4, 2) of tile 0 is in the halo of tile 1, whose node is not known when the
    # pixel is traced here; tile 1 is dealt here next: the deposit goes into both films once,
    # and nothing is sent on.
    core, camera, part = dynamic_adaptive_node()
    core.add_tiles([0], False, np.zeros(0, np.int64))
    d = pass1_deposit(camera, 28)
    d["rgb"] = (1.0, 2.0, 3.0)
    assert core.keep(d, traced_here=True) == {}  # tile 1's node is not known: held
    owners = np.zeros(len(part.rects), np.int64)
    owners[[0, 1]] = 1
    assert core.add_tiles([1], True, owners) == {}  # tile 1 is this node's: kept here
    film0, film1 = (core.books.films[core.books.film_at[t]] for t in (0, 1))
    assert film0.corner[2, 4, 0].tolist() == [1.0, 2.0, 3.0]  # halo from (0, 0): once
    assert film1.corner[2, 0, 0].tolist() == [1.0, 2.0, 3.0]  # halo from (4, 0)
    assert film1.corner.sum() == film0.corner.sum() == 6.0


def test_a_dynamic_adaptive_node_refuses_owners_that_do_not_fit_its_tiles():
    # The host's last TILES names every tile's node; a node checks it against the tiles it
    # was dealt before it sends any pass-1 deposit on by it.
    core, camera, part = dynamic_adaptive_node()
    n = len(part.rects)
    core.add_tiles([0, 2], False, np.zeros(0, np.int64))
    wrong = np.zeros(n, np.int64)  # tiles 0 and 2 were dealt to node 1, not 0
    with pytest.raises(ValueError, match="TILES.owners disagrees .* node 1"):
        core.add_tiles([], True, wrong)
    with pytest.raises(ValueError, match=f"each of the {n} tiles a node of the 2"):
        core.add_tiles([], True, np.full(n, 5, np.int64))
    with pytest.raises(ValueError, match="was dealt here before"):
        core.add_tiles([2], False, np.zeros(0, np.int64))
    # A neighbour cannot make it hold more deposits for unknown tiles than pass 1 makes.
    flood = pass1_deposit(camera, 31, core.books.held_bound + 1)  # pixel (7, 2): tile 1
    with pytest.raises(ValueError, match="holds more deposits for tiles of nodes not known"):
        core.keep(flood)
    right = np.zeros(n, np.int64)
    right[[0, 2]] = 1
    assert core.add_tiles([], True, right) == {}  # nothing traced yet: nothing to send on
