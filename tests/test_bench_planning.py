"""bench.planning: a budgeted plan timed with what a plan shares and with everything made anew,
and the bounded plan's allowance and skipped stages, side by side."""

import json

from bench.planning import main
from tests.conftest import spd_scene


def test_bench_planning_times_both_ways_and_says_what_the_bound_skipped(tmp_path, capsys):
    folder = spd_scene("teapot_s1.nff").parent
    out = tmp_path / "planning.json"
    argv = ["--scenes", str(folder), "--only", "teapot_s1", "--meshes", "2x2"]
    argv += ["--max-share", "0.6", "--size", "48", "--spp", "1", "--repeat", "1"]
    assert main([*argv, "--json", str(out)]) == 0
    (row,) = json.loads(out.read_text())
    assert row["every_stage_shared_cpu_seconds"] > 0 and row["every_stage_anew_cpu_seconds"] > 0
    assert row["anew_over_shared"] > 0
    # a 48x48 render at one sample affords no simulation, not even the first cut's: each
    # stage is named
    prepass = row["prepass"]
    stages = {s["stage"] for s in prepass["skipped"]}
    assert {"the first cut", "copies", "growth"} <= stages
    assert prepass["simulations"] == 0 and prepass["allowed_cpu_seconds"] == 0
    assert "teapot_s1" in capsys.readouterr().out
