"""A memory budget's copies (`MeshPlan.holds`, `host.planning.replicas`): any node may hold any
other cells' engines, and the image and ray counts stay the single node's; copies are chosen
hottest cell first, never past the budget, and kept only where the simulated mesh's busiest
node carries less."""

from dataclasses import replace

import numpy as np
import pytest

from host.planning.budget import holdings, within
from host.planning.holder_shares import shared
from host.planning.partition import partition
from host.planning.placement import sends
from host.planning.plan import plan_render
from host.planning.prepass import coarse_pass, costs
from host.planning.rectangles import spread
from host.planning.replicas import RULES, _holds, choose_copies, promise_of, with_replicas
from host.planning.request import Auto, Request
from host.scene.nff import read_nff
from host.scene.subset import subset
from protocols.render import ImageSpec, MeshPlan, RenderSpec
from protocols.spec import SpecError
from tests.conftest import spd_scene
from tests.meshsim import render_mesh
from tests.test_budget import ONE, copied_render, planned_render, single


def _random_holds(nodes: int, seed: int) -> tuple:
    """Each node a random set of other cells (far ones too: their rays are traced here,
    and what leaves them is routed on over as many links as it takes)."""
    rng = np.random.default_rng(seed)
    return tuple(
        tuple(sorted(int(c) for c in rng.choice(nodes, 2, replace=False) if c != n))
        for n in range(nodes)
    )


@pytest.mark.parametrize("shape", [(1, 2), (2, 2), (3, 3), (2, 3)])
def test_any_cells_held_give_the_single_node_image(shape):
    scene = read_nff(spd_scene("balls_s2.nff"))
    ref, ref_counts = single(scene)
    nodes = shape[0] * shape[1]
    holds = _random_holds(nodes, nodes)
    img, totals, records, _ = render_mesh(
        scene, *shape, 1.0, 32, 32, balance="objects", copies=True, holds=holds
    )
    assert {k: totals[k] for k in ref_counts} == ref_counts
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    # a node's copies trace what it would have passed to their cells: fewer rays are passed
    # than with no copies at all
    _, _, alone, _ = render_mesh(scene, *shape, 1.0, 32, 32, balance="objects")
    assert sum(r.rays_sent for r in records) < sum(r.rays_sent for r in alone)


@pytest.mark.parametrize("shape", [(3, 3), (2, 3)])
def test_rays_handed_to_the_owner_or_the_nearest_holder_give_the_single_node_image(shape):
    scene = read_nff(spd_scene("balls_s2.nff"))
    nodes = shape[0] * shape[1]
    holds = _random_holds(nodes, nodes)
    got = {}
    for forward in ("owner", "nearest"):
        records = copied_render(scene, shape, holds=holds, forward=forward)
        got[forward] = [dict(r.sent_to) for r in records]
    # handed to the nearest holder, the rays take other routes than to the owners
    assert got["owner"] != got["nearest"]


def test_a_cell_rays_are_handed_to_its_nearest_holder_the_owner_on_a_tie():
    # 3x3 torus (rows 0-2, 3-5, 6-8): node 0 holds cell 8, node 5 holds cells 0 and 7
    plan = MeshPlan(
        3, 3, copies=True, holds=((8,), (), (), (), (), (0, 7), (), (), ()), forward="nearest"
    )
    # from 4: cell 0 to 5 (one hop, 0 two); 7 and 5 both one hop, 8 and 0 both two: owners
    assert plan.takers(4) == [5, 1, 2, 3, 4, 5, 6, 7, 8]
    # from 2: cell 7 to 5 (one hop, 7 two); 0 and 5 both one hop: the owner
    assert plan.takers(2) == [0, 1, 2, 3, 4, 5, 6, 5, 8]
    assert plan.takers(0) == [0, 1, 2, 3, 4, 5, 6, 7, 0]  # its own copy of 8 traces here
    owner = MeshPlan(3, 3, copies=True, holds=plan.holds, forward="owner")
    assert owner.takers(4) == [0, 1, 2, 3, 4, 5, 6, 7, 8]
    assert MeshPlan(3, 3, copies=True, holds=plan.holds).forward == "owner"  # the default
    with pytest.raises(SpecError, match="forward"):
        MeshPlan(3, 3, forward="anyone")


def test_holds_are_checked_as_a_peer_sends_them():
    MeshPlan(2, 2, copies=True, holds=((1,), (), (0, 3), ())).check()
    bad = [
        {"holds": ((1,), (), ())},  # a node missing
        {"holds": ((0,), (), (), ())},  # a node holding itself
        {"holds": ((1, 1), (), (), ())},
        {"holds": ((4,), (), (), ())},
        {"holds": ((True,), (), (), ())},
    ]
    for fields in bad:
        with pytest.raises(SpecError, match="holds"):
            MeshPlan(2, 2, copies=True, **fields)
    with pytest.raises(SpecError, match="holds"):
        MeshPlan(2, 2, holds=((1,), (), (), ()))  # copies are what holds name
    assert MeshPlan.decode({"holds": [[1], [], [0, 3], []]})["holds"] == ((1,), (), (0, 3), ())


@pytest.mark.parametrize("rule", RULES)
@pytest.mark.parametrize(
    "name,shape,share", [("teapot.nff", (3, 3), 0.25), ("tetra.nff", (2, 2), 0.5)]
)
def test_copies_go_hottest_first_and_never_past_the_budget(name, shape, share, rule):
    scene = read_nff(spd_scene(name))
    plan = MeshPlan(*shape, balance="objects", max_share=share, overlap=0.0)
    spec = RenderSpec(ImageSpec(width=64, height=64).sized(scene.view), ONE, plan)
    part, keep = partition(scene, spec)
    outcome = coarse_pass(
        scene, spec, None, None, (np.array(part.cell_los), np.array(part.cell_his))
    )
    load = costs(outcome)
    passes = sends(outcome) if rule == "traffic" else None
    added = choose_copies(scene, spec, part, keep, load, passes)
    assert added, "the budget leaves room for some copy"
    total = keep.shape[1]

    def room(n, c):
        return np.count_nonzero(keep[n] | keep[c]) <= share * total

    # the first copy is of the hottest cell some other node has room for
    fitting = [c for c in range(plan.nodes) if any(room(n, c) for n in range(plan.nodes) if n != c)]
    assert added[0][1] == max(fitting, key=lambda c: load[c])
    for k in range(1, len(added) + 1):  # every prefix (as `with_replicas` tries them) fits
        at = RenderSpec(
            spec.image,
            ONE,
            MeshPlan(
                *shape,
                balance="objects",
                max_share=share,
                overlap=0.0,
                copies=True,
                holds=_holds(plan.nodes, added[:k]),
            ),
        )
        assert within(at.plan, holdings(scene, at, part, keep))
    # no node could take one more cell: each cell it lacks would break the share
    full = _holds(plan.nodes, added)
    for n in range(plan.nodes):
        mine = keep[[n, *full[n]]].any(axis=0)
        for c in set(range(plan.nodes)) - {n, *full[n]}:
            assert np.count_nonzero(mine | keep[c]) > share * total


def test_a_copy_promises_the_busiest_node_its_cells_primary_work_shared_over_its_holders():
    # 2x2 without copies: cell 0 carries 10 (8 in its primary batches, its claimed eye rays
    # and all they spawn there), the others 1. A copy of cell 0 on node 1 or 3 shares those
    # 8 with its holder: 2 + x and 1 + (8 - x) even at 5.5. A copy of cell 1 on node 0
    # leaves node 0 its 10 (and more).
    plan = MeshPlan(2, 2, balance="objects", max_share=0.5)
    work, primary = np.array([10.0, 1, 1, 1]), np.array([8.0, 1, 1, 1])
    assert promise_of(plan, ((), (0,), (), ()), work, primary) == pytest.approx(5.5)
    assert promise_of(plan, ((), (), (), (0,)), work, primary) == pytest.approx(5.5)
    assert promise_of(plan, ((1,), (), (), ()), work, primary) >= 10.0
    # the rays passed into cell 0 (its work outside primary batches) stay with its owner
    assert promise_of(plan, ((), (0,), (), ()), work, np.array([0.0, 1, 1, 1])) == 10.0


def _budgeted(name: str, share: float):
    """(scene, plan, spec, partition, holders) of a 3x3 under `share`, 64x64, overlap 0."""
    scene = read_nff(spd_scene(name))
    plan = MeshPlan(3, 3, balance="objects", max_share=share, overlap=0.0)
    spec = RenderSpec(ImageSpec(width=64, height=64).sized(scene.view), ONE, plan)
    return scene, plan, spec, *partition(scene, spec)


def test_the_copies_promising_the_lightest_busiest_node_are_simulated_first():
    # balls under a budget on 3x3: every rule's sets tried (the allowance unbounded), in
    # the order of their estimated busiest node, and each estimate is the one its holds
    # and the copies-free mesh's cells give
    scene, plan, spec, part, keep = _budgeted("balls_s2.nff", 0.4)
    _, _, report = with_replicas(scene, spec, part, keep)
    tried = report["tried"]
    assert len(tried) > 1, report["why"]
    estimates = [t["estimated_busiest_vs_none"] for t in tried]
    assert estimates == sorted(estimates)
    work = np.array(report["simulated_load"])
    primary = np.array(report["simulated_primary_load"])
    for t in tried:
        holds = tuple(tuple(h) for h in t["holds"])
        got = promise_of(plan, holds, work, primary) / work.max()
        assert t["estimated_busiest_vs_none"] == pytest.approx(got)


def test_copies_are_weighed_with_their_cells_work_shared_as_the_plan_will_share_it():
    # teapot 3x3 under a quarter: its copies' sets simulated with each copied cell's own
    # work shared over its holders (the claims' shares the plan then keeps) carry its
    # busiest node lighter than the same sets with each cell's eye rays on its owner
    scene, _, spec, part, keep = _budgeted("teapot.nff", 0.25)
    at, _, report = with_replicas(scene, spec, part, keep)
    _, _, alone = with_replicas(scene, spec, part, keep, shares=False)
    assert report["chosen"], report["why"]
    work = report["simulated_load"]
    bare = replace(at, plan=replace(at.plan, claim_shares=()))
    assert (
        at.plan.claim_shares
        == shared(bare, work, report["simulated_primary_load"])[0].plan.claim_shares
    )
    assert at.plan.claim_shares
    by_holds = {str(t["holds"]): t["simulated_busiest_vs_none"] for t in alone["tried"]}
    first = report["tried"][0]
    assert first["simulated_busiest_vs_none"] < by_holds[str(first["holds"])]


def test_copies_that_lighten_the_busiest_node_are_kept_and_the_image_holds():
    # Cells cut by the objects leave the teapot's work under it, in a few cells: copies of
    # those on the nodes with room spread their tiles (measured 384 x 384 at 4 spp on a
    # local 3x3: busiest node's frame CPU 0.32-0.35 s without, 0.19 with).
    scene = read_nff(spd_scene("teapot.nff"))
    plan = MeshPlan(3, 3, balance="objects", max_share=0.25, overlap=0.0)
    spec = RenderSpec(ImageSpec(width=64, height=64).sized(scene.view), ONE, plan)
    part, keep = partition(scene, spec)
    assert within(plan, holdings(scene, spec, part, keep))  # as the budget leaves it
    at, dealt, report = with_replicas(scene, spec, part, keep)
    assert report["chosen"] and at.plan.holds, report["why"]
    # of every rule's copies and share tried (a set two rules both choose, once), the lightest
    # simulated mesh is kept
    tried = report["tried"]
    assert RULES[0] in {t["rule"] for t in tried} and {t["rule"] for t in tried} <= set(RULES)
    assert len({str(t["holds"]) for t in tried}) == len(tried)
    lightest = min(
        tried, key=lambda t: (t["simulated_busiest_vs_none"], t["simulated_rays_passed"])
    )
    assert lightest["simulated_busiest_vs_none"] < 1.0
    assert report["rule"] == lightest["rule"] and report["chosen"] == lightest["holds"]
    assert within(at.plan, holdings(scene, at, dealt, keep))
    # rays handed to the nearest holders only where the simulated mesh said it lightens
    forward = report["forward"]
    assert at.plan.forward == forward["chosen"] and forward["why"]
    if "simulated_busiest_nearest_vs_owner" in forward:
        lighter = forward["simulated_busiest_nearest_vs_owner"] < 1.0
        assert (forward["chosen"] == "nearest") == lighter
    # tiles of a copied cell are dealt over its holders
    takers, owners = np.array(dealt.takers), np.array(dealt.owner)
    assert any(o != t and t in at.plan.held(o) for o, t in zip(owners, takers, strict=True))
    assert all(t in at.plan.held(o) for o, t in zip(owners, takers, strict=True))
    # ... by their simulated work only where the simulated mesh said it lightens
    dealing = report["dealing"]
    lighter = dealing["simulated_busiest_by_work_vs_count"] < 1.0
    assert (dealing["chosen"] == "work") == lighter and dealing["why"]


def test_tiles_dealt_by_work_share_a_hot_cells_work_among_its_holders():
    # 2x2, node 1 holds a copy of cell 0: cell 1's two tiles can go to node 1 only, cell 0's
    # six to node 0 or 1, one of them ten times as dear as the others. Dealt by count, node 0
    # takes the dear one and two more; dealt by work each holder ends as even as the tiles
    # allow (the dear tile alone on node 0).
    plan = MeshPlan(2, 2, copies=True, holds=((), (0,), (), ()))
    takers = [1, 1, 0, 0, 0, 0, 0, 0]
    weights = np.array([2, 2, 10, 1, 1, 1, 1, 1], float)

    def loads(owner):
        return np.bincount(owner, weights, minlength=4)

    by_count, by_work = spread(takers, plan), spread(takers, plan, weights)
    for owner in (by_count, by_work):
        assert all(t in plan.held(o) for o, t in zip(owner, takers, strict=True))
    assert loads(by_count).max() == 13 and loads(by_work).max() == 10
    assert by_work[2] == 0 and set(by_work[3:]) == {1}


def test_a_tiles_work_is_the_same_whichever_node_traces_it():
    # `Outcome.tile_work`, what tiles are dealt by: in image space no ray is passed, so all
    # the work is primary batches' and each tile's is what tracing it costs, the same on a
    # 1x2 as on a 2x2 where other nodes trace it.
    scene = read_nff(spd_scene("teapot_s1.nff"))
    got = []
    for shape in ((1, 2), (2, 2)):
        render_mesh(scene, *shape, 1.0, 32, 32, mode="image", tiles="static", tile=8, outcome=got)
    for outcome in got:
        assert outcome.tile_work.sum() == pytest.approx(costs(outcome).sum())
        assert (outcome.tile_work > 0).all()
    np.testing.assert_allclose(got[0].tile_work, got[1].tile_work, rtol=1e-12)


@pytest.mark.parametrize("shape,share", [((1, 2), 0.9), ((2, 2), 0.6), ((2, 3), 0.5)])
def test_a_planned_budget_with_copies_gives_the_single_node_image(shape, share):
    scene = read_nff(spd_scene("teapot_s1.nff"))
    ref, ref_counts = single(scene)
    img, counts, nodes, planned = planned_render(scene, MeshPlan(*shape, max_share=share))
    assert counts == ref_counts
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    budget = planned.balance["budget"]
    assert max(budget["share_held"]) <= share
    assert "why" in budget["copies"] and budget["copies"]["why"]


def test_no_copies_when_asked_for_none():
    scene = read_nff(spd_scene("teapot.nff"))
    request = Request(
        scene,
        ImageSpec(width=32, height=32),
        ONE,
        plan=MeshPlan(3, 3, balance="objects", max_share=0.25),
        auto=Auto(budget_copies=False),
    )
    planned = plan_render(request)
    assert planned.spec.plan.holds == () and planned.balance["budget"]["copies"] == "none asked"


def test_boxes_grown_into_the_room_left_keep_the_budget_and_the_image():
    # After the copies, nodes whose cells hold fewer objects than the budget allows grow
    # their boxes (rays stay on them longer): every node stays within the share, fewer rays
    # are passed, and the image and counts are the single node's; growth is kept only where
    # the simulated busiest node carries less.
    from host.planning.growth import _grown, grown_within
    from host.planning.prepass import partition_pass, rays_passed
    from host.run.framebuffer import Framebuffer
    from meshnode.mesh.simulator import simulate

    scene = read_nff(spd_scene("teapot.nff"))
    ref, ref_counts = single(scene, 64)
    plan = MeshPlan(3, 3, balance="objects", max_share=0.25, overlap=0.0)
    spec = RenderSpec(ImageSpec(width=64, height=64).sized(scene.view), ONE, plan)
    part, keep = partition(scene, spec)
    spec, part, _ = with_replicas(scene, spec, part, keep)
    wider, kept, growth = _grown(scene, spec, part, keep, range(9))
    assert any(growth)
    assert within(spec.plan, holdings(scene, spec, wider, kept))
    assert all(kept[n].sum() > keep[n].sum() for n, g in enumerate(growth) if g)
    assert rays_passed(partition_pass(scene, spec, wider, kept)) < rays_passed(
        partition_pass(scene, spec, part, keep)
    )
    out = simulate([subset(scene, kept[n]) for n in range(9)], spec, wider)
    w, h = spec.image.size
    fb = Framebuffer(w, h, spec.corners, spec.ids_per_cell)
    for d in out.deposits:
        fb.add(d["pixel"], d["rgb"])
    totals = out.totals()
    assert {k: totals[k] for k in ref_counts} == ref_counts
    np.testing.assert_allclose(fb.image(), ref, rtol=0, atol=1e-5)
    _, _, report = grown_within(scene, spec, part, keep)
    ratios = [t["simulated_busiest_vs_plan"] for t in report["tried"]]
    if any(report["chosen"]):
        assert min(ratios) <= 1
    else:
        assert all(r >= 1 for r in ratios)


@pytest.mark.parametrize(
    "name,share", [("teapot_s1", 0.6), ("balls_s2", 0.5), ("gears_s1", 0.5)]
)  # kept: either, evened on the work, the fewest objects
def test_cells_cut_for_the_fewest_objects_are_kept_only_where_they_simulate_lighter(
    monkeypatch, name, share
):
    # Cells evened on the work may leave no room for copies of the hottest cell (the
    # mountain's glass spheres): where the busiest node still carries UNEVEN times the mean,
    # the plan is simulated again on cells cut for the fewest objects and the lighter kept.
    # Tried here on every plan: whichever is kept, the budget and the image hold.
    from host.planning import plan as planning

    monkeypatch.setattr(planning, "UNEVEN", 0.0)
    scene = read_nff(spd_scene(f"{name}.nff"))
    ref, ref_counts = single(scene)
    plan = MeshPlan(2, 2, balance="objects", max_share=share)
    img, counts, _, planned = planned_render(scene, plan)
    cells = planned.balance["budget"]["copies"]["cells"]
    busiest = cells["simulated_busiest"]
    assert cells["chosen"] == min(busiest, key=busiest.get)
    assert len(set(busiest.values())) == 2  # two cuts, simulated apart
    assert counts == ref_counts
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    assert max(planned.balance["budget"]["share_held"]) <= share
