"""The cost pre-pass's allowance (`host.planning.allowance`): simulations only within a tenth of
one node's tracing, stages refused named with why, and the copies a short render cannot afford
to simulate chosen anyway where they promise the busiest node less (`replicas._unsimulated`)."""

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


@pytest.fixture
def round_charges(monkeypatch):
    """Charges in round figures (`allowance.charge`): a node simulated 10 ms, an engine
    built 10 ms, a sightlines' entry 10 ms, a map table 40 ms, no batch, unit or object
    charge and no work between simulations; the measured CPU a clock the test moves."""
    for name, value in (
        ("NODE_SECONDS", 0.01),
        ("BATCH_SECONDS", 0.0),
        ("UNIT_SECONDS", 0.0),
        ("ENGINE_SECONDS", 0.01),
        ("OBJECT_SECONDS", {}),
        ("SIGHT_SECONDS", 0.01),
        ("TABLE_SECONDS", 0.04),
        ("BETWEEN", 1.0),
    ):
        monkeypatch.setattr(allowance, name, value)
    now = [10.0]
    monkeypatch.setattr(allowance.time, "process_time", lambda: now[0])
    return now


def test_the_allowance_affords_simulations_within_a_tenth_of_the_tracing(round_charges):
    from host.planning.allowance import Allowance, Work

    allowed = Allowance(began=10.0)
    assert allowed.affords("first cut", 5)  # nothing learnt yet: the first cut always runs
    allowed.ran(Work(nodes=10))  # charged 0.1 s each
    allowed.ran(Work(nodes=10))
    allowed.learn(5.2)  # one node traces about 5.2 s: the pre-pass may take 0.52 s
    assert allowed.seconds == pytest.approx(0.52)
    assert allowed.affords("rounds", 1, reserve=2)  # 0.2 spent + 3 x 0.1 = 0.5
    allowed.ran(Work(nodes=10))
    assert not allowed.affords("rounds", 1, reserve=2)  # 0.3 + 0.3 > 0.52
    assert allowed.affords("copies", 2)
    report = allowed.report()
    assert report["simulations"] == 3 and report["allowed_cpu_seconds"] == pytest.approx(0.52)
    assert report["charged_cpu_seconds"] == pytest.approx(0.3)
    assert [s["stage"] for s in report["skipped"]] == ["rounds"]
    assert "0.52 s" in report["skipped"][0]["why"] and "2 kept" in report["skipped"][0]["why"]
    nothing = Allowance(began=round_charges[0])
    nothing.learn(0.0)  # a render with no work affords no simulation
    nothing.ran(Work(nodes=1))
    assert not nothing.affords("rounds")


def test_the_allowance_decides_on_charges_whatever_the_clock_says(round_charges):
    """The same simulations get the same answers on a quiet machine and a busy one: the
    clock is reported, not decided on, until it passes VALVE times the allowance."""
    from host.planning.allowance import VALVE, Allowance, Work

    for spell in (0.01, 0.25):  # each simulation's measured CPU: quick, then 25 times slower
        round_charges[0] = 10.0
        allowed = Allowance(began=10.0)
        allowed.ran(Work(nodes=10), seconds=spell)
        round_charges[0] += spell
        allowed.learn(4.0)  # 0.4 s allowed, 0.1 charged
        assert allowed.affords("round", 1, reserve=1)  # 0.1 + 0.2 charged: within
        assert allowed.report()["cpu_seconds"] == pytest.approx(spell)
    round_charges[0] += VALVE * 0.4  # a machine far slower than the charges say
    assert not allowed.affords("round")
    assert "measured" in allowed.why and f"over {VALVE:g} times" in allowed.why


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
    round_charges, monkeypatch
):
    from host.planning.allowance import Allowance, Work

    loads = [1.0]
    monkeypatch.setattr(allowance, "load_seconds", lambda: loads[0])
    allowed = Allowance(began=10.0)
    round_charges[0] += 0.2  # the first cut: 0.05 s loading kernels, 9 engines built
    loads[0] += 0.05
    allowed.ran(Work(nodes=1, built=9), seconds=0.15)  # charged 0.01 + 0.09
    allowed.learn(4.0)  # the pre-pass may take 0.4 s
    assert allowed.cpu == pytest.approx(0.15)  # the process's kernel loads are not its own
    assert allowed.per_pass == pytest.approx(0.01) and allowed.per_build == pytest.approx(0.01)
    assert allowed.cost(1) == pytest.approx(0.1)  # new cells: every node's engine built
    assert allowed.cost(2, builds=0) == pytest.approx(0.02)  # the copies: on the cells' engines
    for _ in range(2):  # 0.1 + 0.1 (and 0.02 kept for the copies), then 0.2 + 0.12: rounds
        assert allowed.affords("re-cut rounds", 1, reserve=2)
        allowed.ran(Work(nodes=1, built=9))
    assert not allowed.affords("re-cut rounds", 1, reserve=2)  # 0.3 + 0.12 > 0.4
    assert "about 0.100 s CPU" in allowed.why
    assert allowed.affords("copies", 2, builds=0)  # 0.3 + 0.02: two simulations of new
    assert not allowed.affords("growth", 2)  # cells would not have fitted
    report = allowed.report()
    assert report["engines_built"] == 27 and report["kernel_load_cpu_seconds"] == pytest.approx(
        0.05
    )
    assert report["charged_cpu_seconds"] == pytest.approx(0.3)


def test_a_plan_is_the_same_however_quick_the_machine_s_clock(monkeypatch):
    """A budgeted 3x3 plan's stages chosen on a clock running at half and at one and a
    half times its speed: the same cells, holders and copies, the same stages run and
    skipped (timed, a shared machine's load had moved them run to run)."""
    import time

    from host.planning.plan import plan_render
    from host.planning.request import Auto, Request
    from protocols.render import EngineSpec

    scene = read_nff(spd_scene("balls_s2.nff"))
    plan = MeshPlan(3, 3, 1.0, "objects", "object", max_share=0.4)
    image = ImageSpec(width=128, height=128, spp=600)  # affords some stages, not all
    request = Request(scene, image, EngineSpec(), plan=plan, auto=Auto(budget_copies=True))
    real, plans = time.process_time, []  # the first plan makes the map's tables, the second
    # reads them kept: charged alike
    for rate in (0.5, 1.5):
        monkeypatch.setattr(time, "process_time", lambda rate=rate: rate * real())
        plans.append(plan_render(request))
    monkeypatch.setattr(time, "process_time", real)
    slow, quick = (p.balance["prepass"] for p in plans)
    assert slow["skipped"] and slow["skipped"] == quick["skipped"]  # some refused: it binds
    assert slow["simulations"] == quick["simulations"] > 1
    assert slow["charged_cpu_seconds"] == pytest.approx(quick["charged_cpu_seconds"])
    assert plans[0].spec.plan == plans[1].spec.plan  # its copies and holders too
    np.testing.assert_array_equal(plans[0].holders, plans[1].holders)
    np.testing.assert_array_equal(plans[0].partition.cell_los, plans[1].partition.cell_los)


def test_an_engine_s_build_is_charged_by_its_objects():
    from host.planning.allowance import ENGINE_SECONDS, OBJECT_SECONDS, Work, charge

    triangles = charge(Work(built=1, objects={"triangles": 1000}))[1]
    polygons = charge(Work(built=1, objects={"polygons": 1000}))[1]
    assert triangles == pytest.approx(ENGINE_SECONDS + 1000 * OBJECT_SECONDS["triangles"])
    assert polygons > triangles  # a polygon's edges and plane cost more to build than a
    unknown = charge(Work(built=1, objects={"blobs": 1000}))[1]  # triangle's; an unknown kind
    assert unknown == pytest.approx(ENGINE_SECONDS + 1000 * max(OBJECT_SECONDS.values()))


def test_the_map_s_tables_made_once_a_plan_are_spent_but_not_expected_again(round_charges):
    from host.planning.allowance import Allowance, Work

    allowed = Allowance(began=10.0)
    # the first cut: one node, 9 engines built, its sightlines and two of the map's tables
    allowed.ran(Work(nodes=1, built=9, sights=2, tables=2), seconds=0.1, once=0.04)
    assert allowed.spent == pytest.approx(0.01 + 0.09 + 0.02 + 0.08)  # spent all the same
    assert allowed.per_pass == pytest.approx(0.01) and allowed.per_build == pytest.approx(0.01)
    assert allowed.cost(1) == pytest.approx(0.12)  # a round on new cells: no tables again
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
def test_copies_the_allowance_refuses_are_chosen_unsimulated_only_where_they_promise_less(
    uneven,
):
    # node 4's cell carries 6 (or 1.05) against the others' 1, all of it in its primary
    # batches: copies share it with their holders (at 1.05 no set can promise less than the
    # mean, 1.006, and 1.1 times that is over 1.05: none is taken on its promise alone)
    scene = read_nff(spd_scene("balls_s2.nff"))
    plan = MeshPlan(3, 3, balance="objects", max_share=0.4)
    spec = RenderSpec(ImageSpec(width=32, height=32).sized(scene.view), plan=plan)
    part, keep = partition(scene, spec)  # cut for the fewest objects: room for copies
    load = np.ones(9)
    load[4] = 6.0 if uneven else 1.05  # the first cut's simulated work, node by node
    with planning(9) as allowed:
        allowed.learn(0.0)  # a render that affords no simulation
        at, dealt, report = with_replicas(scene, spec, part, keep, load, primary=load)
        _, _, unknown = with_replicas(scene, spec, part, keep, load)
    assert allowed.passes == 0 and report["why"].startswith("skipped: ")
    assert unknown["chosen"] == [] and "no cell's work known" in unknown["why"]
    assert report["simulated"] is False and "unsimulated" in report["why"]
    if not uneven:
        assert report["chosen"] == [] and not at.plan.copies
        assert report["estimated_busiest_vs_none"] * 1.05 >= load.mean() - 1e-12
        return
    assert report["estimated_busiest_vs_none"] * 6.0 < 4.0
    # copies of the busiest node's cell, on nodes with room; the budget holds
    assert at.plan.copies and any(4 in h for h in at.plan.holds)
    assert within(at.plan, holdings(scene, at, dealt, keep))
    ref, ref_counts = single(scene)
    img, totals, _, _ = render_mesh(
        scene, 3, 3, 1.0, 32, 32, balance="objects", copies=True, holds=at.plan.holds
    )
    assert {k: totals[k] for k in ref_counts} == ref_counts
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)


@pytest.mark.parametrize("room,ran", [(1.5, 0), (2.5, 2)])
def test_the_claims_check_asks_for_every_simulation_it_runs(round_charges, room, ran):
    # copies chosen unsimulated, their claims' shares weighed: the check simulates the plan
    # with them and without (neither kept from the copies), so it asks for two simulations:
    # with room for one and a half it runs none, with room for two and a half both.
    from host.planning.holder_shares import checked, shared
    from host.planning.prepass import partition_pass

    scene = read_nff(spd_scene("balls_s2.nff"))
    plan = MeshPlan(3, 3, balance="objects", max_share=0.4)
    spec = RenderSpec(ImageSpec(width=32, height=32).sized(scene.view), plan=plan)
    part, keep = partition(scene, spec)
    load = np.ones(9)
    load[4] = 6.0
    with planning(9) as allowed:
        allowed.learn(0.0)
        at, dealt, _ = with_replicas(scene, spec, part, keep, load, primary=load)
    at, _ = shared(at, load, load)
    assert at.plan.claim_shares
    with planning(9) as allowed:
        partition_pass(scene, spec, part, keep)  # what a simulation costs, learnt
        allowed.learn((allowed.spent + room * allowed.cost(1, 0)) / allowance.PREPASS_SHARE)
        _, report = checked(scene, at, dealt, keep)
        assert allowed.passes == 1 + ran
    assert ("not simulated" in report["why"]) == (ran == 0)


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


def test_a_stage_of_new_cells_is_estimated_with_what_the_eye_sees_of_them(round_charges):
    from host.planning.allowance import Allowance, Work

    allowed = Allowance(began=10.0)
    allowed.ran(Work(nodes=5, built=3, sights=2))  # the first cut: 0.05 + 0.03 + 0.02
    assert allowed.per_pass == pytest.approx(0.05) and allowed.per_cut == pytest.approx(0.02)
    assert allowed.cost(1) == pytest.approx(0.1)  # a re-cut round: all of it again
    assert allowed.cost(2, builds=0) == pytest.approx(0.1)  # the same cells: neither
    allowed.ran(Work(nodes=5))  # so it was
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
