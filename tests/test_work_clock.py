"""The simulator's work clock (`meshnode.mesh.simulator`, clock="work"): each node's clock moves
by the work it does, so a node with cheap work runs ahead and takes more tiles or chunks,
as on a real mesh. It must still give the single node's image and ray counts on every
shape and mode, and it must show what rounds cannot: dynamic tiles evening out uneven work."""

import numpy as np
import pytest

from host.camera.setup import CameraSetup
from host.scene.nff import read_nff
from protocols.camera import CameraSampling
from protocols.render import ImageSpec
from protocols.topology import Torus
from tests.conftest import spd_scene
from tests.meshsim import render_mesh
from tests.test_image_space import COUNTS, SHAPES, reference
from tests.test_sampling import dof_scene, thin_camera

MODES = [
    dict(mode="image", tiles="dynamic", tile=5, buffer=2),
    dict(mode="object", steal=True, tile=4),
    dict(mode="object", steal=True, copies=True, tile=4),
]


@pytest.mark.parametrize("latency", [0, 10, 30_000])
@pytest.mark.parametrize("plan", MODES, ids=["image-dynamic", "object-steal", "copies"])
def test_every_shape_and_mode_on_the_work_clock_equals_one_node(plan, latency):
    # latency 30,000 units: longer than any batch here, so rays, tiles and termination waves
    # are in flight across several batches and overtake each other
    scene = read_nff(spd_scene("rings_s1.nff"))
    ref, counts = reference(scene, ImageSpec(width=30, height=26, spp=2))
    for rows, cols in SHAPES:
        outs = []
        img, totals, _, _ = render_mesh(
            scene,
            rows,
            cols,
            30,
            30,
            26,
            spp=2,
            clock="work",
            latency=latency,
            outcome=outs,
            **plan,
        )
        assert {k: totals[k] for k in COUNTS} == counts, (rows, cols)
        np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
        # every hop of the last clean wave (down and up the tree) and of DONE's took
        # `latency`: the clock saw them
        assert outs[0].makespan >= 3 * Torus(rows, cols).tree_depth * latency


def test_a_link_delayed_on_the_work_clock_still_gives_the_single_node_image():
    scene = read_nff(spd_scene("rings_s1.nff"))
    ref, counts = reference(scene, ImageSpec(width=30, height=26))
    for delay in [(0, 1, 50), (1, 0, 50)]:
        img, totals, _, _ = render_mesh(
            scene, 2, 2, 30, 30, 26, clock="work", latency=100, delay=delay, **MODES[1]
        )
        assert {k: totals[k] for k in COUNTS} == counts, delay
        np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)


def test_adaptive_camera_with_dynamic_tiles_on_the_work_clock_equals_one_node(monkeypatch):
    monkeypatch.setattr("meshnode.mesh.books.CHUNK_RAYS", 64)  # leave pass-2 chunks to steal
    scene = dof_scene()
    image = ImageSpec(width=30, height=24, spp=9, seed=3)
    setup = CameraSetup(thin_camera(), CameraSampling(sampling="adaptive"))
    ref, counts = reference(scene, image, setup)
    spec, _ = setup.spec(scene, image.sized(scene.view), lambda: None)
    for rows, cols in SHAPES:
        img, totals, _, _ = render_mesh(
            scene, rows, cols, 0, 30, 24, spp=9, seed=3, camera=spec, clock="work", **MODES[0]
        )
        assert {k: totals[k] for k in COUNTS} == counts, (rows, cols)
        np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)


def test_on_the_work_clock_dynamic_tiles_even_out_what_rounds_cannot():
    # Rounds give every node a tile a turn, so each takes as many tiles whatever they cost;
    # on the work clock a node whose tiles are cheap asks for the next one sooner.
    # gears: its tiles' costs differ most (glass teeth beside open background; rounds leave
    # the busiest node 1.34x the mean)
    scene = read_nff(spd_scene("gears_s1.nff"))
    spread = {}
    for clock in ("rounds", "work"):
        outs = []
        *_, nodes, _ = render_mesh(
            scene,
            2,
            2,
            0,
            64,
            64,
            clock=clock,
            outcome=outs,
            mode="image",
            tiles="dynamic",
            tile=8,
            buffer=1,
        )
        costs = np.array([n.cost for n in nodes], float)
        spread[clock] = costs.max() / costs.mean()
        batches = [n.batches for n in nodes]
        if clock == "work":
            assert len(set(batches)) > 1  # nodes took different numbers of tiles
    assert spread["work"] < spread["rounds"]
    assert spread["work"] < 1.05
