"""bench.spd's pure helpers: the published counts table it checks our counts against, the
configuration names and plan, and the goal line the benchmark's verdict rests on."""

import pytest

from bench.spd_povray import goal, goal_line, parse_povray
from bench.spd_published import compare_published, parse_published
from bench.spd_runs import _label, config_plan, default_density
from bench.spd_scaling import _chosen
from tests.conftest import spd_readme

README = """# Scenes

| file | primitives |
| --- | --- |
| balls.nff | 7381 spheres |

## Published ray counts (SPD Readme, 513x513 corner rays, depth 5)

| scene | eye rays that hit | reflected rays | refracted rays | shadow rays |
| --- | --- | --- | --- | --- |
| balls | 263169 | 175095 | 0 | 954368 |
| gears | 245086 | 304,643 | 207564 | 2246955 |

The author notes | that counts vary.

## Later section

| scene | x |
| --- | --- |
| other | 1 |
"""


def test_published_table_is_parsed_and_only_it():
    assert parse_published(README) == {
        "balls": {
            "eye_hits": 263169,
            "reflected_rays": 175095,
            "refracted_rays": 0,
            "shadow_rays": 954368,
        },
        "gears": {
            "eye_hits": 245086,
            "reflected_rays": 304643,
            "refracted_rays": 207564,
            "shadow_rays": 2246955,
        },
    }
    assert parse_published("# Scenes\n\n| a | b |\n| --- | --- |\n| 1 | 2 |\n") == {}


def test_published_table_of_the_scenes_folder_has_the_six_scenes():
    table = parse_published(spd_readme().read_text())
    assert set(table) == {"balls", "gears", "rings", "teapot", "tetra", "tree"}
    assert all(
        set(c) == {"eye_hits", "reflected_rays", "refracted_rays", "shadow_rays"}
        for c in table.values()
    )


def test_compare_published_relative_and_tolerance():
    published = {"eye_hits": 1000, "refracted_rays": 0}
    ok = compare_published("balls", {"eye_hits": 1001, "refracted_rays": 0}, published)
    assert ok["relative"] == {"eye_hits": pytest.approx(0.001), "refracted_rays": 0.0}
    assert ok["within"]
    assert not compare_published("balls", {"eye_hits": 1002, "refracted_rays": 0}, published)[
        "within"
    ]
    assert compare_published("teapot", {"eye_hits": 1004, "refracted_rays": 0}, published)["within"]
    zero = compare_published("balls", {"eye_hits": 1000, "refracted_rays": 3}, published)
    assert zero["relative"]["refracted_rays"] == 3.0 and not zero["within"]  # finite over 0
    assert compare_published("shells", {"eye_hits": 1}, None) is None


def config(structure, used, storage="auto", used_storage="csr", density=1.0):
    return {
        "structure": structure,
        "used_structure": used,
        "storage": storage,
        "used_storage": used_storage,
        "density": density,
    }


def test_labels_say_what_was_asked_and_what_auto_chose():
    assert _label(config("grid", "grid", "hash", "hash", 2.0)) == "grid hash d2"
    assert _label(config("grid", "grid", "auto", "csr", 0.5)) == "grid auto(csr) d0.5"
    assert _label(config("bvh", "bvh", used_storage=None)) == "bvh"
    assert _label(config("auto", "bvh", used_storage=None)) == "auto(bvh)"
    assert _label(config("auto", "grid")) == "auto(grid csr d1)"


def test_plan_ends_with_the_default_whatever_is_restricted():
    d = default_density()
    full = config_plan(["grid", "bvh", "auto"], [1.0, 2.0])
    assert [c[0] for c in full] == ["grid"] * 4 + ["bvh", "auto"]
    assert full[-1] == ("auto", "auto", d)
    assert config_plan(["bvh"], [1.0]) == [("bvh", "auto", d), ("auto", "auto", d)]
    assert config_plan(["auto"], [1.0]) == [("auto", "auto", d)]


def test_goal_sorts_scenes_by_the_default_ratio():
    pov = {
        "scenes": {
            "balls": {"ratio_default": 3.5},
            "gears": {"ratio_default": 1.9},
            "tetra": {"ratio_default": 3.0},
            "shells": {"ratio_default": 9.0},
            "mount_s1": {"ratio_default": 1.0},
        }
    }
    g = goal(pov)
    assert g["met"] == {"balls": 3.5, "tetra": 3.0, "shells": 9.0}
    assert g["missed"] == {"gears": 1.9}
    assert g["absent"] == ["rings", "teapot", "tree", "jacks"]
    assert goal_line(g) == (
        "goal POV-Ray/default >= 3.0: met on balls 3.50, tetra 3.00, shells 9.00; "
        "not met on gears 1.90; not measured: rings, teapot, tree, jacks"
    )
    assert goal({})["absent"] == [
        "balls",
        "tetra",
        "gears",
        "rings",
        "teapot",
        "tree",
        "shells",
        "jacks",
    ]


POVRAY_OUTPUT = """Parser Time
  Parse Time:       0 hours  0 minutes  0 seconds (0.038 seconds)
              using 1 thread(s) with 0.037 CPU-seconds total
  Bounding Time:    0 hours  0 minutes  0 seconds (0.011 seconds)
              using 1 thread(s) with 0.010 CPU-seconds total
Rays:               6996   Saved:                 0   Max Level: 5/5
Shadow Ray Tests:             14855   Succeeded:                  4454
Reflected Rays:                2900
Render Time:
  Photon Time:      No photons
  Radiosity Time:   No radiosity
  Trace Time:       0 hours  0 minutes  0 seconds (0.167 seconds)
              using 1 thread(s) with 0.080 CPU-seconds total
"""


def test_povray_trace_cpu_seconds_are_the_trace_times_not_the_parsers():
    got = parse_povray(POVRAY_OUTPUT)
    assert got["trace_seconds"] == 0.167 and got["cpu_seconds"] == 0.080
    assert (got["rays"], got["shadow_rays"], got["shadow_rays_blocked"]) == (6996, 14855, 4454)
    assert got["reflected_rays"] == 2900 and got["refracted_rays"] == 0
    with pytest.raises(RuntimeError, match="CPU-seconds"):
        parse_povray(POVRAY_OUTPUT.replace("with 0.080 CPU-seconds total", ""))


def test_scaling_says_what_auto_chose():
    def row(n, used):
        return {"size_factor": n, "runs": {"auto": {"used_structure": used}}}

    assert _chosen([row(1, "bvh"), row(2, "bvh")]) == "bvh at every size"
    assert _chosen([row(1, "bvh"), row(2, "grid"), row(3, "bvh")]) == "bvh at n=1,3, grid at n=2"
