"""`--overlap auto`: the cost pre-pass simulates its cuts at every candidate overlap (with and
without the occupancy map) and keeps the one whose busiest node carries least, among those
whose largest node's engine fits the nodes' memory; the render it plans is still the single
node's image with the same counts."""

import math

import numpy as np
import pytest

from host.planning import allowance
from host.planning.holding import FITS, OVERLAPS, engine_bytes, largest_engine
from host.planning.plan import plan_render
from host.planning.prepass import node_costs
from host.planning.request import Auto, Request
from host.run.framebuffer import Framebuffer
from host.run.oneprocess import render
from host.scene.nff import read_nff
from host.scene.subset import subset
from meshnode.engine.counters import RAY_COUNTS
from meshnode.mesh.simulator import simulate
from protocols.render import EngineSpec, ImageSpec, MeshPlan, RenderSpec
from tests.conftest import spd_scene

COUNTS = RAY_COUNTS


@pytest.fixture(autouse=True)
def every_stage(monkeypatch):
    """Every candidate simulated: renders this small afford none past the first
    (`host.planning.allowance`), and these tests are about the choice among them."""
    monkeypatch.setattr(allowance, "PREPASS_SHARE", math.inf)


def planned(scene, image, memory=0, balance="cost"):
    plan = MeshPlan(2, 2, OVERLAPS[0], balance=balance, steal=True)
    return plan_render(
        Request(scene, image, EngineSpec(threads=1), plan=plan, auto=Auto(overlaps=OVERLAPS)),
        memory=memory,
    )


@pytest.mark.parametrize("balance", ["cost", "even"])
def test_the_chosen_overlap_simulates_least_of_the_candidates(balance):
    # Cost cuts are searched at every overlap, even cuts simulated at every overlap; either
    # way the report's figures are the simulation's own and the least of them wins.
    scene = read_nff(spd_scene("teapot_s1.nff"))
    image = ImageSpec(width=48, height=48)
    got = planned(scene, image, balance=balance)
    report = got.balance["overlap"]
    chosen = got.spec.plan.overlap
    assert report["chosen"] == chosen and chosen in OVERLAPS
    assert report["too_big_for_memory"] == []  # no memory bound given
    ratios, busiest = report["simulated_busiest_vs_chosen"], report["simulated_busiest"]
    assert set(ratios) == set(busiest) == {f"{o:g}" for o in OVERLAPS}
    assert ratios[f"{chosen:g}"] == 1.0 and min(ratios.values()) == 1.0
    xs, ys = got.balance.get("columns"), got.balance.get("rows")
    spec = RenderSpec(image.sized(scene.view), plan=got.spec.plan)
    with_map = got.balance["occupancy_map"] or balance == "cost"  # cost compares with the map
    again = node_costs(scene, spec, xs, ys, _cells(got), with_map).max()
    assert again == pytest.approx(busiest[f"{chosen:g}"])
    if balance == "even":  # one set of cuts: a loser re-simulates to its figure too
        other = next(o for o in OVERLAPS if o != chosen)
        at = RenderSpec(spec.image, plan=MeshPlan(2, 2, other, steal=True))
        theirs = node_costs(scene, at, None, None, None, with_map).max()
        assert theirs == pytest.approx(busiest[f"{other:g}"])


def _cells(got):
    """The cells the plan used when the pre-pass cut them in object space (on its work map,
    or by the objects), else None (cut from the image's)."""
    return got.partition.cells if got.balance.get("family") in ("work map", "objects") else None


def test_overlaps_whose_largest_node_would_not_fit_are_not_taken():
    scene = read_nff(spd_scene("tetra_s3.nff"))
    image = ImageSpec(width=48, height=48)
    spec = RenderSpec(image.sized(scene.view), plan=MeshPlan(2, 2, OVERLAPS[0]))
    smallest = largest_engine(scene, spec, None, None)
    widest = largest_engine(
        scene, RenderSpec(spec.image, plan=MeshPlan(2, 2, OVERLAPS[-1])), None, None
    )
    assert smallest < widest <= engine_bytes(scene)  # a wider overlap holds more
    memory = int(smallest / FITS) + 1  # room for the smallest overlap's nodes alone
    got = planned(scene, image, memory=memory, balance="even")
    report = got.balance["overlap"]
    assert got.spec.plan.overlap == OVERLAPS[0]
    refused = {r["overlap"] for r in report["too_big_for_memory"]}
    assert OVERLAPS[-1] in refused and OVERLAPS[0] not in refused
    assert all(r["largest_node_bytes"] > FITS * memory for r in report["too_big_for_memory"])
    assert max(engine_bytes(subset(scene, k)) for k in got.holders) <= FITS * memory


@pytest.mark.parametrize("balance", ["cost", "even"])
def test_a_render_at_the_chosen_overlap_equals_one_node(balance):
    # The teapot on its floor: each node's rays stay longer on it with a wider overlap, and
    # the pre-pass takes one (30 on its cuts, 100 on even ones), so a wide box is exercised.
    scene = read_nff(spd_scene("teapot_s1.nff"))
    image = ImageSpec(width=48, height=48, spp=2)
    ref, stats = render(Request(scene, image, EngineSpec(threads=1)))
    got = planned(scene, image, balance=balance)
    assert got.spec.plan.overlap > OVERLAPS[0]
    out = simulate([subset(scene, k) for k in got.holders], got.spec, got.partition)
    fb = Framebuffer(*got.spec.image.size, got.spec.corners, got.spec.image.spp)
    for d in out.deposits:
        fb.add(d["pixel"], d["rgb"])
    totals = out.totals()
    assert {k: totals[k] for k in COUNTS} == {k: stats["rays"][k] for k in COUNTS}
    np.testing.assert_allclose(fb.image(), ref, rtol=0, atol=1e-5)  # as every mesh test
