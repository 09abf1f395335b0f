"""bench.occupancy_map: one plan's mesh simulated under the bounds map, the surfaces map and the
surfaces map with sub-voxels counts the same rays, each map passing fewer rays on than the
one before (the surfaces map holding fewer voxels than the bounds map)."""

import json

from bench.occupancy_map import main
from tests.conftest import spd_scene


def test_the_surfaces_map_and_its_sub_voxels_pass_fewer_rays_on_the_same_cells(tmp_path, capsys):
    folder = spd_scene("teapot_s1.nff").parent
    out = tmp_path / "map.json"
    argv = ["--scenes", str(folder), "--only", "teapot_s1", "--meshes", "2x2,3x3"]
    argv += ["--max-share", "0.6", "--size", "48", "--spp", "2", "--json", str(out)]
    assert main(argv) == 0  # the same hits, escapes and shadow rays under all three maps
    rows = json.loads(out.read_text())
    assert [r["mesh"] for r in rows] == ["2x2", "3x3"]
    for r in rows:
        assert 0 < r["surfaces_occupied"] < 0.8 * r["bounds_occupied"]
        assert r["surfaces_passed"] < r["bounds_passed"]
        assert r["surfaces_units"] < r["bounds_units"]
        assert r["sub_voxels_occupied"] == r["surfaces_occupied"]  # the same voxels ...
        assert r["sub_voxels_passed"] < r["surfaces_passed"]  # ... their sub-voxels pass fewer
    assert "under all three maps" in capsys.readouterr().out
