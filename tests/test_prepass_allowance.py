"""The cost pre-pass's allowance (`host.planning.allowance`): simulations only within a tenth of
one node's tracing, stages refused named with why, and the copies a short render cannot afford
to simulate chosen anyway where one cell carries most of the work (`replicas._unsimulated`)."""

import numpy as np
import pytest

from host.planning import allowance
from host.planning.budget import holdings, within
from host.planning.partition import partition
from host.planning.prepass import planning
from host.planning.replicas import with_replicas
from host.scene.nff import read_nff
from protocols.render import ImageSpec, MeshPlan, RenderSpec
from tests.conftest import spd_scene
from tests.meshsim import render_mesh
from tests.test_budget import single


def test_the_allowance_affords_simulations_within_a_tenth_of_the_tracing(monkeypatch):
    from host.planning.allowance import Allowance

    now = [10.0]
    monkeypatch.setattr(allowance.time, "process_time", lambda: now[0])
    allowed = Allowance(began=10.0)
    assert allowed.affords("first cut", 5)  # nothing learnt yet: the first cut always runs
    now[0] += 0.2
    allowed.ran(0.1)
    allowed.ran(0.1)
    allowed.learn(5.2)  # one node traces about 5.2 s: the pre-pass may take 0.52 s
    assert allowed.seconds == pytest.approx(0.52)
    assert allowed.affords("rounds", 1, reserve=2)  # 0.2 spent + 3 x 0.1 = 0.5
    now[0] += 0.1
    allowed.ran(0.1)
    assert not allowed.affords("rounds", 1, reserve=2)  # 0.3 + 0.3 > 0.52
    assert allowed.affords("copies", 2)
    report = allowed.report()
    assert report["simulations"] == 3 and report["allowed_cpu_seconds"] == pytest.approx(0.52)
    assert [s["stage"] for s in report["skipped"]] == ["rounds"]
    assert "0.52 s" in report["skipped"][0]["why"] and "2 kept" in report["skipped"][0]["why"]
    nothing = Allowance(began=now[0])
    nothing.learn(0.0)  # a render with no work affords no simulation
    nothing.ran(0.01)
    assert not nothing.affords("rounds")


@pytest.mark.parametrize("name", ["balls_s1.nff", "rings_s1.nff", "teapot_s1.nff"])
def test_the_tracing_estimate_counts_one_node_s_work_on_any_mesh(name):
    """The allowance is a tenth of one node's tracing, estimated from the first coarse
    simulation (`prepass.tracing_seconds`): its units (`walked_units`: the rays' own
    walks, no map steps, sends or packet steps for rays that had not entered) must be one
    node's, whatever the mesh. Reference: one node simulated at the render's full
    resolution. Raw work units put the coarse 3x3 at 1.27-1.39 times one node's (so the
    allowance grew with the mesh and passed a tenth of the tracing: tetra_s8 1.43-1.49)."""
    from host.planning.plan import plan_render
    from host.planning.prepass import coarse_pass, coarse_spec, walked_units
    from host.planning.request import Request
    from host.scene.subset import subset
    from meshnode.mesh.simulator import simulate
    from meshnode.mesh.stats import work_units
    from protocols.render import EngineSpec

    scene = read_nff(spd_scene(name))
    image = ImageSpec(width=128, height=128, spp=1)
    one = plan_render(Request(scene, image, EngineSpec(), plan=MeshPlan(1, 1, 0)))
    alone = simulate([subset(scene, one.holders[0])], one.spec, one.partition).totals()
    per_one = work_units(alone) / (128 * 128)
    for rows, cols in ((1, 2), (2, 2), (3, 3)):
        plan = MeshPlan(rows, cols, 1.0, "objects", "object")
        spec = plan_render(Request(scene, image, EngineSpec(), plan=plan)).spec
        counts = coarse_pass(scene, spec, None, None).totals()
        width, height = coarse_spec(spec).sample_grid
        assert width < 128  # the coarse image's rays lie further apart than the render's
        ratio = walked_units(counts) / (width * height) / per_one
        assert 0.8 <= ratio <= 1.1, (rows, cols, ratio)


def test_the_allowance_estimates_a_stage_by_the_engines_it_builds_kernel_loads_apart(
    monkeypatch,
):
    from host.planning.allowance import Allowance

    now, loads = [10.0], [1.0]
    monkeypatch.setattr(allowance.time, "process_time", lambda: now[0])
    monkeypatch.setattr(allowance, "load_seconds", lambda: loads[0])
    allowed = Allowance(began=10.0)
    now[0] += 0.2  # the first cut: 0.05 s loading kernels, 0.1 s simulating, 9 engines built
    loads[0] += 0.05
    allowed.ran(0.1, built=9, build_seconds=0.09)
    allowed.learn(4.0)  # the pre-pass may take 0.4 s
    assert allowed.spent == pytest.approx(0.15)  # the process's kernel loads are not its own
    assert allowed.per_pass == pytest.approx(0.01) and allowed.per_build == pytest.approx(0.01)
    assert allowed.cost(1) == pytest.approx(0.1)  # new cells: every node's engine built
    assert allowed.cost(2, builds=0) == pytest.approx(0.02)  # the copies: on the cells' engines
    for _ in range(2):  # 0.15 + 0.1 (and 0.02 kept for the copies), then 0.25 + 0.12: rounds
        assert allowed.affords("re-cut rounds", 1, reserve=2)
        now[0] += 0.1
        allowed.ran(0.1, built=9, build_seconds=0.09)
    assert not allowed.affords("re-cut rounds", 1, reserve=2)  # 0.35 + 0.12 > 0.4
    assert "about 0.100 s CPU" in allowed.why
    assert allowed.affords("copies", 2, builds=0)  # 0.35 + 0.02: two simulations of new
    assert not allowed.affords("growth", 2)  # cells would not have fitted
    report = allowed.report()
    assert report["engines_built"] == 27 and report["kernel_load_cpu_seconds"] == pytest.approx(
        0.05
    )
    assert report["cpu_seconds"] == pytest.approx(0.35)


def test_the_map_s_tables_made_once_a_plan_are_spent_but_not_expected_again(monkeypatch):
    from host.planning.allowance import Allowance

    now = [10.0]
    monkeypatch.setattr(allowance.time, "process_time", lambda: now[0])
    allowed = Allowance(began=10.0)
    now[0] += 0.1  # the first cut: 0.04 s of its 0.1 making the map's tables, 0.03 building
    allowed.ran(0.1, built=9, build_seconds=0.03, once=0.04)
    assert allowed.spent == pytest.approx(0.1)  # spent all the same
    assert allowed.per_pass == pytest.approx(0.03) and allowed.per_build == pytest.approx(0.03 / 9)
    assert allowed.cost(1) == pytest.approx(0.06)  # a round on new cells: no tables again
    assert allowed.report()["map_tables_cpu_seconds"] == pytest.approx(0.04)


def test_simulations_on_one_map_make_its_tables_once():
    from host.planning.plan import plan_render
    from host.planning.prepass import coarse_pass, costs
    from host.planning.request import Request
    from meshnode.engine.mapbounds import per_map_seconds
    from protocols.render import EngineSpec

    scene = read_nff(spd_scene("balls_s1.nff"))
    plan = MeshPlan(2, 2, 1.0, "objects", "object", max_share=0.5)
    request = Request(scene, ImageSpec(width=64, height=64, spp=64), EngineSpec(), plan=plan)
    spec = plan_render(request).spec
    with planning(plan.nodes) as allowed:
        before = per_map_seconds()
        first = costs(coarse_pass(scene, spec, None, None))
        made = per_map_seconds()
        again = costs(coarse_pass(scene, spec, None, None))  # the same map: its tables kept
        assert per_map_seconds() == made
        assert allowed.passes == 2 and allowed.once_seconds == pytest.approx(made - before)
    np.testing.assert_array_equal(first, again)


@pytest.mark.parametrize("uneven", [True, False])
def test_copies_the_allowance_refuses_are_chosen_unsimulated_only_where_the_load_is_uneven(
    uneven,
):
    scene = read_nff(spd_scene("balls_s2.nff"))
    plan = MeshPlan(3, 3, balance="objects", max_share=0.4)
    spec = RenderSpec(ImageSpec(width=32, height=32).sized(scene.view), plan=plan)
    part, keep = partition(scene, spec)  # cut for the fewest objects: room for copies
    load = np.ones(9)
    load[4] = 6.0 if uneven else 1.2  # the first cut's simulated work, node by node
    with planning(9) as allowed:
        allowed.learn(0.0)  # a render that affords no simulation
        at, dealt, report = with_replicas(scene, spec, part, keep, load)
    assert allowed.passes == 0 and report["why"].startswith("skipped: ")
    if not uneven:
        assert report["chosen"] == [] and not at.plan.copies
        return
    assert report["simulated"] is False and "unsimulated" in report["why"]
    # every copy is of the busiest node's cell first, on nodes with room; the budget holds
    assert at.plan.copies and any(4 in h for h in at.plan.holds)
    assert within(at.plan, holdings(scene, at, dealt, keep))
    ref, ref_counts = single(scene)
    img, totals, _, _ = render_mesh(
        scene, 3, 3, 1.0, 32, 32, balance="objects", copies=True, holds=at.plan.holds
    )
    assert {k: totals[k] for k in ref_counts} == ref_counts
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)


def test_cost_cuts_and_overlaps_keep_within_the_allowance_too():
    from host.planning.holding import OVERLAPS
    from host.planning.plan import plan_render
    from host.planning.request import Auto, Request
    from protocols.render import EngineSpec

    scene = read_nff(spd_scene("teapot_s1.nff"))
    plan = MeshPlan(2, 2, OVERLAPS[0], balance="cost")
    auto = Auto(overlaps=OVERLAPS)

    def planned(size: int, spp: int):
        image = ImageSpec(width=size, height=size, spp=spp)
        request = Request(scene, image, EngineSpec(threads=1), plan=plan, auto=auto)
        return plan_render(request).balance["prepass"]

    small = planned(256, 1)  # 16 coarse passes' samples: the even cuts' simulation only
    stages = {s["stage"] for s in small["skipped"]}
    assert {"cuts: shared rows", "cuts: work map"} <= stages, stages
    assert any(s.startswith("overlap ") for s in stages), stages
    assert all("one node's tracing" in s["why"] for s in small["skipped"])
    big = planned(2048, 256)  # many minutes on one node: every family at every overlap
    assert big["skipped"] == [] and big["simulations"] > small["simulations"]
    tiny = planned(32, 1)  # fewer samples than ten coarse passes: not even the even cuts
    assert tiny["simulations"] == 0
    assert tiny["skipped"][0]["stage"] == "the even cuts' simulation"
    assert "no simulation fits" in tiny["skipped"][0]["why"]


def test_a_budget_s_retreat_simulates_its_cut_only_within_the_allowance():
    from host.planning.plan import plan_render
    from host.planning.request import Auto, Request
    from protocols.render import EngineSpec

    scene = read_nff(spd_scene("balls_s2.nff"))
    plan = MeshPlan(3, 3, balance="objects", max_share=0.22)  # overlap 1 breaks it: 0 instead

    def planned(size: int, spp: int):
        image = ImageSpec(width=size, height=size, spp=spp)
        request = Request(scene, image, EngineSpec(threads=1), plan=plan, auto=Auto())
        return plan_render(request)

    tiny, small, big = planned(16, 1), planned(256, 1), planned(1024, 64)
    for p in (tiny, small, big):
        assert p.spec.plan.overlap == 0 and within(
            p.spec.plan, holdings(scene, p.spec, p.partition, p.holders)
        )
        assert any(g.startswith("--overlap 1") for g in p.balance["budget"]["gave_up"])
    retreat = "the retreat's cells evened on work"
    skipped = {s["stage"]: s["why"] for s in small.balance["prepass"]["skipped"]}
    assert "one node's tracing" in skipped[retreat]  # cut for the fewest objects instead
    # a render too small for any simulation: neither the first cut's nor the retreat's ran
    skipped = {s["stage"]: s["why"] for s in tiny.balance["prepass"]["skipped"]}
    assert "no simulation fits" in skipped[retreat] and "the first cut" in skipped
    assert tiny.balance["prepass"]["simulations"] == 0
    assert retreat not in {s["stage"] for s in big.balance["prepass"]["skipped"]}
    assert big.balance["prepass"]["simulations"] > small.balance["prepass"]["simulations"]


def test_a_stage_of_new_cells_is_estimated_with_what_the_eye_sees_of_them(monkeypatch):
    from host.planning.allowance import Allowance

    now = [10.0]
    monkeypatch.setattr(allowance.time, "process_time", lambda: now[0])
    allowed = Allowance(began=10.0)
    now[0] += 0.1  # the first cut: 0.03 s building 9 engines, 0.02 making its sightlines
    allowed.ran(0.1, built=9, build_seconds=0.03, sights=0.02)
    assert allowed.per_pass == pytest.approx(0.05) and allowed.per_cut == pytest.approx(0.02)
    assert allowed.cost(1) == pytest.approx(0.1)  # a re-cut round: all of it again
    assert allowed.cost(2, builds=0) == pytest.approx(0.1)  # the same cells: neither
    now[0] += 0.05
    allowed.ran(0.05)  # so it was
    assert allowed.per_pass == pytest.approx(0.05) and allowed.per_cut == pytest.approx(0.02)


def test_a_plan_s_stages_simulate_the_same_plan_once():
    from dataclasses import replace

    from host.planning.plan import plan_render
    from host.planning.prepass import costs, partition_pass
    from host.planning.request import Request
    from protocols.render import EngineSpec

    scene = read_nff(spd_scene("balls_s1.nff"))
    plan = MeshPlan(2, 2, 1.0, "objects", "object", max_share=0.5)
    request = Request(scene, ImageSpec(width=64, height=64, spp=64), EngineSpec(), plan=plan)
    planned = plan_render(request)
    spec, part, keep = planned.spec, planned.partition, planned.holders
    with planning(plan.nodes) as allowed:
        first = partition_pass(scene, spec, part, keep)
        again = partition_pass(scene, spec, replace(part), keep.copy())  # equal, not the same
        assert again is first and (allowed.passes, allowed.reused) == (1, 1)
        nearest = replace(spec, plan=replace(spec.plan, forward="nearest"))
        other = partition_pass(scene, nearest, part, keep)
        assert other is not first and (allowed.passes, allowed.reused) == (2, 1)
        fewer = keep.copy()
        fewer[0, np.flatnonzero(fewer[0])[0]] = False  # one object fewer on node 0
        assert partition_pass(scene, spec, part, fewer) is not first
        assert allowed.passes == 3
    outside = partition_pass(scene, spec, part, keep)  # no plan: simulated anew
    assert outside is not first
    np.testing.assert_array_equal(costs(outside), costs(first))
