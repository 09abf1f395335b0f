"""The structure "auto" takes: the hierarchy or the grid, whichever `structure_cost` expects to
finish the render sooner (build and tracing of the render's expected rays), the reason in the
stats; and the rays a render is expected to trace, told to the engine by one process and by a
mesh node."""

import numpy as np

from bench.structure_cost import nested_spheres
from host.planning.partition import partition
from host.planning.request import Request
from host.run.oneprocess import render
from host.scene.nff import read_nff
from host.scene.subset import subset
from meshnode.engine import Engine, structure_cost
from meshnode.engine.structure_cost import (
    Estimate,
    choose,
    expected_rays,
    eye_ray_count,
    grid_estimate,
    grid_forecast,
    grid_least,
)
from meshnode.mesh.node import NodeCore
from protocols.render import EngineSpec, ImageSpec, MeshPlan, RenderSpec
from tests.conftest import spd_scene

NESTED = nested_spheres(400)  # boxes nesting: the grid traces it faster, the hierarchy builds


def test_a_small_render_takes_the_quick_build_and_a_large_one_the_quick_tracing():
    small = Engine(NESTED, eye_rays_expected=100)
    large = Engine(NESTED, eye_rays_expected=1e9)
    assert (small.structure, large.structure) == ("bvh", "grid")
    # (the large render's: the grid is forecast there, not bounded: `grid_least`)
    bvh, grid = (large.stats["structure_estimates"][s] for s in ("bvh", "grid"))
    assert "lower_bound" not in grid
    assert bvh["build_seconds"] < grid["build_seconds"]
    assert grid["seconds_per_ray"] < bvh["seconds_per_ray"]
    # the crossing point: from there on the grid's faster tracing has paid for its build
    pays = (grid["load_seconds"] + grid["build_seconds"] - bvh["build_seconds"]) / (
        bvh["seconds_per_ray"] - grid["seconds_per_ray"]
    )
    for eye in (0.5, 2.0):
        rays = pays * eye / (small.rays_expected / 100)  # eye rays bringing that many rays
        assert Engine(NESTED, eye_rays_expected=rays).structure == ("bvh", "grid")[eye > 1]
    # the reason gives both structures' build, trace and total seconds and the choice
    for engine in (small, large):
        reason = engine.stats["structure_reason"]
        assert reason.count(" to build + ") == 2 and reason.count(" to trace = ") == 2
        sooner = "hierarchy builds sooner" in reason or "than the grid could be" in reason
        assert sooner == (engine is small)
        assert ("grid traces faster" in reason) == (engine is large)


def test_the_choice_counts_build_time(monkeypatch):
    # Only the grid's build estimate grows (its unit costs, not its tracing): the render the
    # grid won goes to the hierarchy, by the very margin the build took.
    rays = 1e9
    before = Engine(NESTED, eye_rays_expected=rays)
    assert before.structure == "grid"
    bvh, grid = (before.stats["structure_estimates"][s] for s in ("bvh", "grid"))
    margin = bvh["total_seconds"] - grid["total_seconds"]
    grow = 1.0 + 2.0 * margin / grid["build_seconds"]
    for name in ("PER_GRID_CANDIDATE", "PER_GRID_REF", "PER_GRID_VOXEL"):
        monkeypatch.setattr(structure_cost, name, getattr(structure_cost, name) * grow)
    after = Engine(NESTED, eye_rays_expected=rays)
    assert after.structure == "bvh"
    again = after.stats["structure_estimates"]
    assert again["grid"]["trace_seconds"] == grid["trace_seconds"]
    assert again["bvh"] == bvh
    assert np.isclose(again["grid"]["build_seconds"], grid["build_seconds"] + 2.0 * margin)


def test_the_grids_lower_bound_is_under_its_forecast_and_leaves_every_choice_as_it_was():
    # the grid is not forecast where its bound is over the hierarchy's estimate: the bound
    # must be under the forecast's estimate at every render size, so the choice is the same
    for name, cut in (("balls_s2.nff", 2), ("rings_s1.nff", 3), ("teapot_s1.nff", 2)):
        tb = Engine(read_nff(spd_scene(name)), structure="bvh").tables
        lo, hi = tb.lo.min(axis=0), tb.hi.max(axis=0)
        for k in range(cut):  # slabs along x, as object-space cells cut the objects
            box_lo, box_hi = lo.copy(), hi.copy()
            box_lo[0], box_hi[0] = (lo[0] + (hi[0] - lo[0]) * f / cut for f in (k, k + 1))
            held = np.all((tb.hi >= box_lo) & (tb.lo <= box_hi), axis=1)
            for rays in (1e2, 1e5, 1e8):
                exact = grid_estimate(
                    grid_forecast(tb.lo[held], tb.hi[held], box_lo, box_hi, 1.0), rays
                )
                least = grid_least(tb.lo[held], tb.hi[held], box_lo, box_hi, rays)
                assert least.least and not exact.least
                assert least.total <= exact.total and least.per_ray <= exact.per_ray
    for rays in (1e2, 1e9):  # where the grid wins, it is forecast and taken
        engine = Engine(NESTED, eye_rays_expected=rays)
        grid = engine.stats["structure_estimates"]["grid"]
        assert ("lower_bound" in grid) == (engine.structure == "bvh")


def test_the_choice_is_the_smaller_total_and_says_when_the_other_would_pay():
    quick_build = Estimate("bvh", 0.0, 0.01, 1.0, 1e-6, 100)
    quick_trace = Estimate("grid", 0.01, 0.5, 0.4, 4e-7, 200)
    chosen, why = choose([quick_build, quick_trace], 1e6)
    assert chosen is quick_trace
    assert "grid traces faster, which pays back its build from 8.33e+05 rays" in why
    slower = Estimate("grid", 0.01, 0.5, 0.7, 7e-7, 200)
    chosen, why = choose([quick_build, slower], 1e6)
    assert chosen is quick_build and "from 1.67e+06 rays" in why
    tie = Estimate("grid", 0.0, 0.01, 1.0, 1e-6, 100)
    chosen, why = choose([quick_build, tie], 1e6)  # the first, compared with the other
    assert chosen is quick_build and why.endswith("the hierarchy builds and traces sooner")


def test_the_grid_forecast_follows_the_build_and_runs_before_it():
    # the resolution and references the build makes, from the objects' boxes alone
    for name in ("tetra_s3.nff", "balls_s2.nff", "rings_s1.nff"):
        engine = Engine(read_nff(spd_scene(name)), structure="grid")
        tb = engine.tables  # the engine's own rows (a convex quad is two triangles there)
        fc = grid_forecast(tb.lo, tb.hi, tb.lo.min(axis=0), tb.hi.max(axis=0), 1.0)
        stats = engine.grid.stats
        assert np.all(np.abs(np.log(np.array(fc.res) / stats["resolution"])) < np.log(1.25))
        # box spans hold every voxel an object touches, and not many more here
        assert stats["object_references"] <= fc.refs < 3 * stats["object_references"]
        assert fc.candidates >= 2 * fc.refs  # counted, then filled
        assert 1.0 <= fc.steps <= sum(fc.res) and fc.tests > 0


def test_expected_rays_count_shadows_per_light_and_one_generation_of_secondary_rays():
    balls = read_nff(spd_scene("balls_s1.nff"))  # three lights, reflective
    assert expected_rays(balls, 1000, depth=5) == 1000 * (1 + 3 + 1)
    assert expected_rays(balls, 1000, depth=1) == 1000 * (1 + 3)
    gears = read_nff(spd_scene("gears_s1.nff"))  # five lights, transmitting
    assert expected_rays(gears, 10, depth=5) == 10 * (1 + 5 + 2)
    image = ImageSpec(spd=True, width=32, height=32).sized(balls.view)
    assert eye_ray_count(image) == 33 * 33
    assert eye_ray_count(ImageSpec(width=32, height=16, spp=4).sized(balls.view)) == 32 * 16 * 4


def test_one_process_tells_the_engine_its_render_and_splits_loading_from_building():
    scene = read_nff(spd_scene("tetra_s3.nff"))
    image = ImageSpec(width=24, height=20, spp=2)
    stats = render(Request(scene, image, EngineSpec(threads=1)))[1]
    engine = stats["engine"]
    assert engine["rays_expected"] == expected_rays(scene, 24 * 20 * 2, image.depth)
    assert engine["structure_build_seconds"] >= 0 and engine["structure_load_seconds"] > 0
    structure = engine["structure_load_seconds"] + engine["structure_build_seconds"]
    assert structure <= engine["preprocess_seconds"]
    # the one-object build that loaded the build kernels is load, not build
    assert stats["load_seconds"] >= engine["structure_load_seconds"] - stats["compile_seconds"]


def test_a_mesh_node_expects_an_even_share_of_the_renders_eye_rays():
    scene = read_nff(spd_scene("teapot_s1.nff"))
    image = ImageSpec(width=40, height=30, spp=3).sized(scene.view)
    spec = RenderSpec(image, plan=MeshPlan(2, 2))
    part, keep = partition(scene, spec)
    mine = subset(scene, keep[0])
    core = NodeCore(0, mine, spec, part)
    assert core.engine.stats["rays_expected"] == expected_rays(mine, 40 * 30 * 3 / 4, 5)
