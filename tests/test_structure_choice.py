"""The cost model `structure_cost`: the grid forecast before building, the choice of smaller
expected total, and the rays a render is expected to trace."""

import numpy as np

from host.scene.nff import read_nff
from meshnode.engine import Engine
from meshnode.engine.structure_cost import (
    Estimate,
    choose,
    expected_rays,
    eye_ray_count,
    grid_forecast,
)
from meshnode.engine.tables import build_tables
from protocols.render import ImageSpec
from tests.conftest import spd_scene


def test_the_choice_is_the_smaller_total_and_says_when_the_other_would_pay():
    quick_build = Estimate("bvh", 0.0, 0.01, 1.0, 1e-6, 100)
    quick_trace = Estimate("grid", 0.01, 0.5, 0.4, 4e-7, 200)
    chosen, why = choose([quick_build, quick_trace], 1e6)
    assert chosen is quick_trace
    assert "grid traces faster, which pays back its build from 8.33e+05 rays" in why
    slower = Estimate("grid", 0.01, 0.5, 0.7, 7e-7, 200)
    chosen, why = choose([quick_build, slower], 1e6)
    assert chosen is quick_build and "from 1.67e+06 rays" in why


def test_the_grid_forecast_follows_the_build_and_runs_before_it():
    # the resolution and references the build makes, from the objects' boxes alone
    for name in ("tetra_s3.nff", "balls_s2.nff", "rings_s1.nff"):
        engine = Engine(read_nff(spd_scene(name)), structure="grid")
        tb = build_tables(engine.scene)
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
