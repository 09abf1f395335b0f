"""Object space under a memory budget (`MeshPlan.max_share`, `node_bytes`): cells that divide
the objects whatever the view, a plan that keeps every node within its budget (asserted from
the nodes' own reports) and still gives the single node's image and ray counts, and a scene
that cannot be divided refused before any work, naming the smallest share reached."""

import asyncio
import math
from unittest import mock

import numpy as np
import pytest

from bench.generate import tetra
from host.cli import main
from host.planning import allowance
from host.planning.budget import BudgetError
from host.planning.cells import grown, node_cells, scene_box, traced
from host.planning.clip import holders
from host.planning.holding import engine_bytes
from host.planning.objectcells import object_cells
from host.planning.plan import plan_render
from host.planning.request import Auto, Request
from host.run.connections import Nodes
from host.run.framebuffer import Framebuffer
from host.run.localmesh import LocalMesh
from host.run.meshclient import render_on_mesh
from host.run.oneprocess import render
from host.scene.nff import read_nff
from host.scene.subset import subset
from meshnode.engine.counters import RAY_COUNTS
from meshnode.mesh.simulator import simulate
from protocols.render import EngineSpec, ImageSpec, MeshPlan
from tests.conftest import spd_scene
from tests.meshsim import render_mesh

SIZE = 32
ONE = EngineSpec(threads=1)


def single(scene, size=SIZE):
    img, stats = render(Request(scene, ImageSpec(width=size, height=size), ONE), progress=False)
    return img, {k: stats["rays"][k] for k in RAY_COUNTS}


def copied_render(scene, shape, **plan):
    """The per-node records of a simulated SIZE x SIZE render of `scene` on a `shape` mesh,
    cells cut by the objects, with copies and the plan's other fields (`plan`), its image
    and counts checked against one node's."""
    ref, ref_counts = single(scene)
    img, totals, records, _ = render_mesh(
        scene, *shape, 1.0, SIZE, SIZE, balance="objects", copies=True, **plan
    )
    assert {k: totals[k] for k in ref_counts} == ref_counts
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    return records


def planned_render(scene, plan: MeshPlan, size=SIZE):
    """(image, counts, per-node records, the plan made) of a simulated mesh render planned
    as the host plans a real one (`plan_render`: budget, retreats, cuts), every stage of the
    pre-pass run (a render this small affords none of them: `host.planning.allowance`)."""
    with mock.patch.object(allowance, "PREPASS_SHARE", math.inf):
        planned = plan_render(Request(scene, ImageSpec(width=size, height=size), ONE, plan=plan))
    part = planned.partition
    scenes = [subset(scene, planned.holders[n]) for n in range(part.nodes)]
    out = simulate(scenes, planned.spec, part)
    w, h = planned.spec.image.size
    fb = Framebuffer(w, h, planned.spec.corners, planned.spec.image.spp)
    for d in out.deposits:
        fb.add(d["pixel"], d["rgb"])
    totals = out.totals()
    return fb.image(), {k: totals[k] for k in RAY_COUNTS}, out.nodes, planned


def test_object_cells_tile_the_scene_and_divide_the_objects():
    # Cells cut from the image follow the view: teapot 2x2 left one node 90% of the
    # objects, tetra 54%. Cut by the objects, the fullest holds near 1/N plus what its cuts
    # cross, on every mesh shape, and the cells tile the scene's box exactly.
    for name, limits in (("tetra.nff", (0.3, 0.15, 0.1)), ("teapot.nff", (0.3, 0.16, 0.11))):
        scene = read_nff(spd_scene(name))
        box = scene_box(scene)
        meshes = ((2, 2), (3, 3), (4, 4))
        for (rows, cols), limit in zip(meshes, limits, strict=True):
            los, his = object_cells(scene, box, rows, cols)
            assert np.all(los <= his)
            assert np.prod(his - los, axis=1).sum() == pytest.approx(np.prod(box[1] - box[0]))
            inside = (los >= box[0] - 1e-12) & (his <= box[1] + 1e-12)
            assert inside.all()
            share = holders(scene, *traced(*grown(los, his, 1.0))).mean(axis=1)
            view = node_cells(scene, box, 512, 512, rows, cols)
            by_view = holders(scene, *traced(*grown(*view, 1.0))).mean(axis=1)
            assert share.max() <= limit < by_view.max(), (name, rows, cols)


def test_a_cut_takes_its_box_s_objects_bounds_sorted_as_sorting_them_would():
    # `_Cutter` sorts every object's bounds and centres once per axis; each cut takes its
    # box's objects from those in order: the same values as sorting the box's own
    from host.planning.objectcells import _Cutter

    rng = np.random.default_rng(7)
    lo = rng.normal(size=(500, 3)).round(2)  # ties on purpose
    hi = lo + rng.random((500, 3))
    cutter = _Cutter((lo, hi), None, None)
    for idx in (np.arange(500), np.flatnonzero(rng.random(500) < 0.3), np.array([4]), []):
        idx = np.asarray(idx, np.int64)
        los, his, centres = cutter.values(idx)
        for a in range(3):
            np.testing.assert_array_equal(los[a], np.sort(lo[idx, a]))
            np.testing.assert_array_equal(his[a], np.sort(hi[idx, a]))
            np.testing.assert_array_equal(centres[a], np.sort(0.5 * (lo[idx, a] + hi[idx, a])))


def test_work_evened_cuts_count_a_block_by_its_nodes_not_its_columns():
    # Under a limit of objects a node, a cut between a column of three nodes and two columns
    # of six compared the objects per column with the limit (three times the per-node
    # figure), so every such cut fell back to the fewest objects and ignored the work: rings
    # 3x3 under a quarter share, the pre-pass's busiest node 318k units -> 214k counted per
    # node. Uniform small spheres, most of the work in the corner 64th of the box, a limit
    # of a quarter: the busiest node's work 1.45 of the mean (2.49 counted per column; the
    # cuts' slack over the fewest objects, not the limit, bounds it here).
    from host.planning.objectcells import WorkGrid
    from host.scene.nff import parse_nff

    rng = np.random.default_rng(7)
    centres = rng.uniform(0, 10, (3000, 3))
    text = "v\nfrom 5 5 -30\nat 5 5 5\nup 0 1 0\nangle 40\nhither 1\nresolution 8 8\n"
    text += "l 5 5 -30\nf 1 1 1 1 0 0 0 0\n"
    text += "".join(f"s {x:.4f} {y:.4f} {z:.4f} 0.01\n" for x, y, z in centres)
    scene = parse_nff(text)
    box = scene_box(scene)
    density = np.ones((16, 16, 16))
    density[:4, :4, :4] = 100.0
    work = WorkGrid(*box, density)
    limit = 0.25 * 3000
    los, his = object_cells(scene, box, 3, 3, work, limit)
    parts = zip(los, his, strict=True)
    mass = np.array([(work.density * work.fractions(lo, hi)).sum() for lo, hi in parts])
    assert mass.max() <= 1.6 * mass.mean()
    held = holders(scene, los, his).sum(axis=1)
    assert held.max() <= limit


@pytest.mark.parametrize(
    "name,shape,max_share,extra",
    [
        ("tetra_s3.nff", (1, 2), 0.8, {}),
        ("tetra_s3.nff", (2, 2), 0.55, {}),
        ("tetra_s3.nff", (2, 3), 0.4, {"overlap": 5.0}),
        ("tetra_s3.nff", (3, 3), 0.4, {"balance": "cost"}),
        ("balls_s2.nff", (2, 2), 0.5, {"copies": True}),
        ("balls_s2.nff", (3, 3), 0.2, {"balance": "objects", "overlap": 0.0}),
        ("teapot_s1.nff", (2, 3), 0.5, {"steal": True}),
    ],
)
def test_a_budgeted_mesh_gives_the_single_node_image_within_its_budget(
    name, shape, max_share, extra
):
    scene = read_nff(spd_scene(name))
    ref, ref_counts = single(scene)
    plan = MeshPlan(*shape, max_share=max_share, **extra)
    img, counts, nodes, planned = planned_render(scene, plan)
    assert counts == ref_counts
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    # the nodes' own reports: objects in the engines they built, each counted once
    total = planned.holders.shape[1]
    assert max(n.objects for n in nodes) <= max_share * total
    budget = planned.balance["budget"]
    assert [n.objects for n in nodes] == budget["objects_held"] or planned.spec.plan.copies
    assert max(budget["share_held"]) <= max_share


def test_a_byte_budget_holds_on_every_node_and_builds_hierarchies():
    scene = read_nff(spd_scene("tetra.nff"))  # 4,096 triangles, about 1.8 MB of engine
    ref, ref_counts = single(scene)
    plan = MeshPlan(2, 2, node_bytes=1_000_000)
    img, counts, nodes, planned = planned_render(scene, plan)
    assert counts == ref_counts
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    assert planned.spec.engine.structure == "bvh"
    assert all(0 < n.engine_bytes <= 1_000_000 for n in nodes)
    # the host's estimate is what each node then counts, within the engine's small arrays
    est = planned.balance["budget"]["engine_bytes"]
    assert all(0 <= e - n.engine_bytes <= 0.2 * e for e, n in zip(est, nodes, strict=True))


def test_a_scene_that_cannot_be_divided_is_refused_naming_the_smallest_share():
    scene = read_nff(spd_scene("balls_s2.nff"))
    with pytest.raises(BudgetError, match=r"fullest node (\d+\.\d)% of the objects") as e:
        plan_render(
            Request(
                scene, ImageSpec(width=SIZE, height=SIZE), ONE, plan=MeshPlan(2, 2, max_share=0.1)
            )
        )
    reached = float(str(e.value).split("fullest node ")[1].split("%")[0]) / 100
    assert 0.1 < reached < 0.5  # the objects' cells at overlap 0: about a quarter
    with pytest.raises(BudgetError, match="--node-memory 1000 bytes"):
        plan_render(
            Request(
                scene, ImageSpec(width=SIZE, height=SIZE), ONE, plan=MeshPlan(2, 2, node_bytes=1000)
            )
        )


def test_the_cli_refuses_an_impossible_budget_before_starting_any_node(capsys, monkeypatch):
    started = []
    monkeypatch.setattr(LocalMesh, "__enter__", lambda self: started.append(self))
    scene = str(spd_scene("balls_s2.nff"))
    rc = main(["render", scene, "--mesh", "2x2", "--max-share", "5%", "-o", "/tmp/never.png"])
    err = capsys.readouterr().err
    assert rc == 2 and not started
    assert "cannot divide the scene over 2x2 nodes within --max-share 0.05" in err
    assert "fullest node" in err and "Traceback" not in err


def test_a_scene_no_node_can_hold_renders_on_real_nodes_within_their_memory():
    # A generated 16,384-triangle tetra (about 7 MB of engine) on 3x3 nodes each allowed a
    # quarter of that: no single node could hold it, the mesh renders it, every node within
    # its budget by its own report, and the image is one unbudgeted node's.
    scene = tetra(7)
    budget = engine_bytes(scene) // 4
    ref, ref_stats = render(Request(scene, ImageSpec(width=24, height=24), ONE), progress=False)
    with LocalMesh(9) as addresses:
        coro = render_on_mesh(
            Request(
                scene,
                ImageSpec(width=24, height=24),
                ONE,
                plan=MeshPlan(3, 3),
                auto=Auto(mode="auto", node_memory=budget),
            ),
            Nodes(addresses),
        )
        img, stats = asyncio.run(asyncio.wait_for(coro, 240))
    assert stats["mesh"]["mode"] == "object" and stats["mesh"]["node_bytes"] == budget
    assert all(0 < n["engine_bytes_held"] <= budget for n in stats["nodes"])
    assert all(n["frame_cpu_seconds"] > 0 for n in stats["nodes"])
    assert {k: stats["rays"][k] for k in RAY_COUNTS} == {
        k: ref_stats["rays"][k] for k in RAY_COUNTS
    }
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)


@pytest.mark.parametrize("name", ["tetra.nff", "gears.nff"])
def test_object_cells_re_cut_on_the_measured_work_lighten_the_busiest_node(name):
    # Cells dividing the objects evenly left one node of a 3x3 with most of the work; cut on
    # where the eye rays' work starts, then re-cut on the cost pre-pass's measured work
    # (within a share budget), the simulated busiest node carries at most three quarters of
    # what it did, the first cut alone too, and the plan's cells keep every node within the
    # budget. (Teapot's objects-only cells lost most of their imbalance when the occupancy
    # map's walk took the ray's octant: its busiest node 393k -> 241k units.)
    from host.planning.objectwork import balanced_object_cells, object_limit
    from host.planning.prepass import node_costs
    from protocols.render import RenderSpec

    scene = read_nff(spd_scene(name))
    plan = MeshPlan(3, 3, balance="objects", max_share=0.25)
    spec = RenderSpec(ImageSpec(width=128, height=128).sized(scene.view), plan=plan)
    cells, cost, report = balanced_object_cells(scene, spec, object_limit(scene, plan), rounds=3)
    counted = node_costs(scene, spec, None, None, object_cells(scene, scene_box(scene), 3, 3))
    assert cost.max() <= 0.75 * counted.max()
    # the first cut, on the first guess alone, divides the work better than the objects do
    first = report["simulated_busiest_by_round"]
    assert len(first) == 4 and first[0] <= 0.75 * counted.max()
    planned = plan_render(Request(scene, ImageSpec(width=256, height=256), ONE, plan=plan))
    assert max(planned.balance["budget"]["share_held"]) <= 0.25
    assert planned.balance["budget"]["gave_up"] == []  # the work-evened cells kept
    # the plan's own pre-pass is bounded by the render it plans (`host.planning.allowance`):
    # 256 x 256 at one sample is 16 coarse passes' samples, so a tenth of it affords the
    # first cut but no re-cut, and the report says so; a render of 1024 x 1024 at 256 spp
    # (minutes on one node) affords all three and skips nothing
    reason = planned.balance["rounds_reason"]
    assert planned.balance["rounds"] == 0 and reason.startswith("0 of 3"), reason
    skipped = {s["stage"]: s["why"] for s in planned.balance["prepass"]["skipped"]}
    assert "one node's tracing" in skipped["re-cut rounds"]
    assert len(planned.balance["simulated_busiest_by_round"]) == 1  # the first cut alone
    copies = planned.balance["budget"]["copies"]["why"]
    assert copies.startswith("skipped: ") and "one node's tracing" in copies, copies
    assert planned.balance["budget"]["growth"]["why"].startswith("skipped: ")
    big = plan_render(Request(scene, ImageSpec(width=1024, height=1024, spp=256), ONE, plan=plan))
    assert big.balance["rounds"] == 3 and big.balance["prepass"]["skipped"] == []
    # 128 x 128 at one sample is 4 coarse passes' samples: not even the first cut fits a
    # tenth of its tracing, so none is simulated; its cells even the first guess's work
    tiny = plan_render(Request(scene, ImageSpec(width=128, height=128), ONE, plan=plan))
    prepass = tiny.balance["prepass"]
    assert prepass["simulations"] == 0 and tiny.balance["first_cut"] == "not simulated"
    assert "no simulation fits in 10% of its tracing" in prepass["skipped"][0]["why"]
    assert prepass["skipped"][0]["stage"] == "the first cut"
    assert max(tiny.balance["budget"]["share_held"]) <= 0.25


def test_with_copies_to_come_a_cut_is_judged_by_what_its_copies_promise():
    # teapot 3x3 under a quarter share, three re-cut rounds: without copies to come the cut
    # kept is the one whose simulated busiest node is lightest; with them each cut is judged
    # by the least of that and what its copies promise (`objectwork.PROMISED` times
    # `replicas.cut_promise`), and the cut kept is the one judged lightest
    from host.planning.objectwork import balanced_object_cells, object_limit
    from protocols.render import RenderSpec

    scene = read_nff(spd_scene("teapot.nff"))
    plan = MeshPlan(3, 3, balance="objects", max_share=0.25)
    spec = RenderSpec(ImageSpec(width=128, height=128).sized(scene.view), plan=plan)
    limit = object_limit(scene, plan)
    _, bare_cost, bare = balanced_object_cells(scene, spec, limit, rounds=3)
    _, cost, judged = balanced_object_cells(scene, spec, limit, rounds=3, copies=True)
    busiest = bare["simulated_busiest_by_round"]
    assert judged["simulated_busiest_by_round"] == busiest and len(busiest) > 1
    assert bare["judged_busiest_by_round"] == busiest
    assert bare_cost.max() == min(busiest)
    promised = judged["judged_busiest_by_round"]
    assert all(p <= b for p, b in zip(promised, busiest, strict=True))
    assert any(p < b for p, b in zip(promised, busiest, strict=True))
    assert cost.max() == busiest[int(np.argmin(promised))]


def test_re_cut_cells_that_break_the_budget_are_cut_again_within_it():
    # The re-cuts count objects per node as if every later cut divided them evenly, and the
    # boxes then grow by the overlap: teapot 3x3 under a quarter share reached 28.5%, and
    # the plan fell back to the cells of the fewest objects (2x the work of the best round).
    # Such a cut is made again under a lower cap, so the plan keeps the re-cut cells.
    scene = read_nff(spd_scene("teapot.nff"))
    plan = MeshPlan(3, 3, balance="objects", max_share=0.25)
    image = ImageSpec(width=1024, height=1024, spp=256)
    planned = plan_render(Request(scene, image, ONE, plan=plan))
    balance = planned.balance
    assert balance["rounds"] == 3
    assert balance["budget"]["gave_up"] == []
    assert max(balance["budget"]["share_held"]) <= 0.25
    # the first cut (on the first guess) and each round's: those within the budget simulated
    first, *rounds = balance["fullest_vs_limit_by_round"]
    kept = [x for x in rounds if x <= 1]
    assert first <= 1 and len(balance["simulated_busiest_by_round"]) == 1 + len(kept)


def test_shared_cells_are_chosen_only_within_the_budget():
    # Under copies the pre-pass may share the hottest cells with every node; under a budget
    # only those that keep every node within it. With the budget at what the copies alone
    # hold, every candidate is refused for it (and named so); without a budget the same
    # candidates are tried on their simulated work alone.
    from host.planning.budget import holdings
    from host.planning.partition import partition
    from host.planning.shared_cells import choose_shared
    from protocols.render import RenderSpec

    scene = read_nff(spd_scene("tetra.nff"))
    image = ImageSpec(width=96, height=96).sized(scene.view)
    open_plan = MeshPlan(4, 4, 1.0, copies=True)
    spec = RenderSpec(image, plan=open_plan)
    held = holdings(scene, spec, *partition(scene, spec))
    tight = RenderSpec(image, plan=MeshPlan(4, 4, 1.0, copies=True, max_share=max(held["share"])))
    chosen, report = choose_shared(scene, tight, None, None, None, True, 1.0, efficiency=0.0)
    assert chosen == () and report["tried"]
    refused = [r for r in report["too_big_for_memory"] if r.get("over")]
    assert refused and all(r["over"] == "the plan's memory budget" for r in refused)
    _, free = choose_shared(scene, spec, None, None, None, True, 1.0, efficiency=0.0)
    assert len(free["simulated_busiest_vs_none"]) > 1  # without a budget they were simulated


@pytest.mark.parametrize(
    "name", ["gears_s1.nff", "teapot_s1.nff", "rings_s1.nff", "balls_s1.nff", "tree_s1.nff"]
)
def test_a_cells_engine_bytes_summed_from_its_objects_are_those_of_its_tables(name):
    # the budget counts a cell's bytes from each object's share (`holding.held_bytes`):
    # they must be engine_bytes of the cell's own tables, banded polygons and smooth
    # triangles among them or not, any objects held, none or all
    from host.planning.holding import held_bytes
    from host.scene.derived import scene_tables

    scene = read_nff(spd_scene(name))
    n = scene_tables(scene).n
    rng = np.random.default_rng(11)
    masks = [np.zeros(n, bool), np.ones(n, bool)]
    masks += [rng.random(n) < share for share in (0.01, 0.1, 0.3, 0.7) for _ in range(3)]
    for mask in masks:
        assert held_bytes(scene, mask) == engine_bytes(subset(scene, mask))
