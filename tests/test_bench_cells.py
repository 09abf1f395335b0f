"""bench.cells: a budgeted object-space plan simulated with either first guess, side by side;
both plans keep every node within the budget, and the guess is restored after each."""

import json

from bench.cells import main
from host.planning import seenwork
from tests.conftest import spd_scene


def test_bench_cells_plans_both_guesses_within_the_budget(tmp_path, capsys):
    folder = spd_scene("teapot_s1.nff").parent
    before = seenwork.SEEN
    out = tmp_path / "cells.json"
    argv = ["--scenes", str(folder), "--only", "teapot_s1", "--meshes", "2x2"]
    argv += ["--max-share", "0.6", "--size", "256", "--spp", "1", "--simulate-spp", "1"]
    assert main([*argv, "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [r["guess"] for r in rows] == ["seen", "objects"]
    for r in rows:
        # a render this small (16 coarse passes' samples) affords the first cut's simulation
        # but no re-cut round (`host.planning.allowance`)
        assert r["fullest_share"] <= 0.6 and r["busiest_units"] > 0
        assert len(r["by_round"]) >= 1 and r["busiest_over_mean"] >= 1.0
    assert seenwork.SEEN == before  # put back as it was
    assert "busiest node against objects" in capsys.readouterr().out


def test_bench_cells_plans_without_a_budget(tmp_path):
    # No budget (--max-share 1): no copies stage, and the fullest node's share is counted
    # from the plan's holders, as with one (it used to look for the budget's report).
    folder = spd_scene("teapot_s1.nff").parent
    out = tmp_path / "cells.json"
    argv = ["--scenes", str(folder), "--only", "teapot_s1", "--meshes", "1x2", "--guess", "seen"]
    argv += ["--max-share", "1", "--size", "48", "--spp", "1", "--simulate-spp", "1"]
    assert main([*argv, "--json", str(out)]) == 0
    (row,) = json.loads(out.read_text())
    assert 0.5 <= row["fullest_share"] <= 1.0 and row["copies_prepass_cpu"] == 0.0
