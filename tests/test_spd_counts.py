"""The SPD scenes at their default size give the ray counts of the databases' author's published
table (scenes README: 513x513 corner rays, depth 5) within 0.1%, teapot within 0.5%: the
independent reference for the whole tracer (camera, intersections, shading rules, counting)."""

import pytest

from bench.spd_published import PUBLISHED_TOLERANCE, TOLERANCE, parse_published
from host.planning.request import Request
from host.run.oneprocess import render
from host.scene.nff import read_nff
from meshnode.engine.counters import spd_counts
from protocols.render import EngineSpec, ImageSpec
from tests.conftest import spd_readme, spd_scene


@pytest.mark.parametrize("name", ["balls", "gears", "rings", "teapot", "tetra", "tree"])
def test_default_scene_counts_match_the_published_table(name):
    scene = read_nff(spd_scene(f"{name}.nff"))
    published = parse_published(spd_readme().read_text())[name]
    _, stats = render(Request(scene, ImageSpec(spd=True), EngineSpec()))
    ours = spd_counts(stats["rays"])
    tolerance = PUBLISHED_TOLERANCE.get(name, TOLERANCE)
    for key, n in published.items():
        assert abs(ours[key] - n) <= tolerance * max(n, 1), (key, ours[key], n)
