"""bench.setup: a local mesh's setup on its nodes' first render (cold) and on a later one with
no engine kept (warm), the simulated figure beside it, and a budget the plan refuses named."""

import json

import pytest

from bench.setup import main
from tests.conftest import spd_scene


def test_bench_setup_times_cold_and_warm_renders_and_names_a_refused_budget(tmp_path, capsys):
    folder = spd_scene("teapot_s1.nff").parent
    out = tmp_path / "setup.json"
    argv = ["--scenes", str(folder), "--only", "teapot_s1", "--measured", "1x2"]
    assert main([*argv, "--simulated", "1x2", "--json", str(out)]) == 0
    measured, simulated = json.loads(out.read_text())
    # the warm render rebuilt every engine (the bench stops where a node reused one)
    assert measured["how"] == "measured" and measured["build_max"] > 0
    for got in (measured, measured["cold"]):
        assert got["setup"] >= got["plan"] + got["configure"] > 0
    assert simulated["setup"] == pytest.approx(
        simulated["plan"] + simulated["configure"] + simulated["build_max"]
    )
    assert simulated["cold"]["setup"] > simulated["setup"]  # a process's start added
    # half of a 1x2's objects at most: the plan refuses before any work, and the row says so
    assert main([*argv, "--simulated", "", "--max-share", "0.3", "--json", str(out)]) == 0
    (refused,) = json.loads(out.read_text())
    assert "cannot divide the scene over 1x2 nodes within --max-share 0.3" in refused["refused"]
    assert "fullest node" in capsys.readouterr().out
