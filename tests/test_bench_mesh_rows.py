"""`bench.mesh_rows.frame_parts`: the frame speedup taken apart into the work the mesh adds
and the balance between its nodes."""

import math

import numpy as np
import pytest

from bench.mesh_rows import frame_parts


def _row(frames, batches, kernels, one_frame, one_kernels):
    return {
        "node_frame_cpu_seconds": frames,
        "node_batch_cpu_seconds": batches,
        "node_cpu_seconds": kernels,
        "one_frame_cpu_seconds": one_frame,
        "single_cpu_seconds": one_kernels,
        "work_summed_over_one": 1.3,
        "frame_speedup": one_frame / max(frames),
    }


@pytest.mark.parametrize("seed", range(5))
def test_the_frame_speedup_is_the_nodes_over_summed_and_balance(seed):
    """N / (summed x balance) is the frame speedup, and the nodes' kernels, routing and the
    rest of their process add up to the summed frame, whatever the nodes' figures; the event
    loop's thread is a part of that rest."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 17))
    kernels = rng.uniform(0.1, 2.0, n)
    batches = kernels + rng.uniform(0.0, 0.5, n)
    frames = batches + rng.uniform(0.0, 0.5, n)
    row = _row(list(frames), list(batches), list(kernels), float(rng.uniform(1, 9)), 0.9)
    row["node_loop_cpu_seconds"] = list((frames - batches) * rng.uniform(0.0, 1.0, n))
    f = frame_parts(row)
    assert 0.0 <= f["event_loop"] <= f["outside_batches"] + 1e-12
    assert math.isclose(n / (f["summed"] * f["balance"]), row["frame_speedup"], rel_tol=1e-12)
    parts = f["kernels"] + f["routing"] + f["outside_batches"]
    assert math.isclose(parts, f["summed"], rel_tol=1e-12)
    assert f["even"] >= row["frame_speedup"] - 1e-12  # an even load is the best balance


def test_an_even_mesh_doing_no_more_work_than_one_process_speeds_up_n_times():
    f = frame_parts(_row([1.0] * 4, [0.9] * 4, [0.8] * 4, 4.0, 3.2))
    assert f["summed"] == pytest.approx(1.0)
    assert f["balance"] == pytest.approx(1.0)
    assert f["even"] == pytest.approx(4.0)
    assert f["kernels"] == pytest.approx(0.8)
    assert f["one_kernels"] == pytest.approx(0.8)
