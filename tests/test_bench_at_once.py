"""`bench.mesh_runs.at_once`: one node rendering in a subprocess of its own (`bench.one_process`)
while the mesh renders, the mesh renders counted those that ended within its frame."""

import time

import pytest

from bench.mesh_runs import _within, at_once
from host.scene.nff import read_nff
from protocols.render import ImageSpec

SHOWCASE = "host/examples/showcase.nff"


def _render(start, end, busiest):
    return (
        start,
        end,
        {"busiest_node_cpu_seconds": busiest, "busiest_node_frame_cpu_seconds": 2 * busiest},
    )


def test_the_renders_that_ended_within_the_frame_are_counted():
    renders = [_render(0, 1, 1.0), _render(1, 2, 2.0), _render(2, 3, 3.0), _render(3, 4, 4.0)]
    assert [r[2]["busiest_node_cpu_seconds"] for r in _within(renders, 1.5, 3.5)] == [2.0, 3.0]


def test_with_none_ended_within_it_the_one_overlapping_it_most_is_counted():
    renders = [_render(0, 1, 1.0), _render(1, 5, 2.0), _render(5, 9, 3.0)]
    assert [r[2]["busiest_node_cpu_seconds"] for r in _within(renders, 3.0, 6.0)] == [2.0]
    assert [r[2]["busiest_node_cpu_seconds"] for r in _within(renders, 5.5, 8.5)] == [3.0]


@pytest.mark.slow
@pytest.mark.spawn  # bench.one_process runs in a subprocess of its own
def test_one_node_in_a_subprocess_reports_its_whole_frame_and_the_window_it_ran_in():
    """Its frame CPU (the whole process's) is at least its tracing thread's, and the mesh
    renders counted are those the window selects: here stand-ins that each render the same
    scene in this process, so the load is real."""
    from bench.mesh_reference import single

    scene = read_nff(SHOWCASE)
    image = ImageSpec(width=48, height=48, spp=4)
    made = []

    def mesh_render():
        start = time.perf_counter()
        _, stats = single(scene, ImageSpec(width=16, height=16, spp=1), warm=False)
        end = time.perf_counter()
        made.append(
            (
                start,
                end,
                {
                    "busiest_node_cpu_seconds": float(len(made) + 1),
                    "busiest_node_frame_cpu_seconds": 10.0 * (len(made) + 1),
                },
            )
        )
        return made[-1]

    got = at_once((scene, image, None), mesh_render)
    assert 0 < got["one_node_cpu_seconds"] <= got["one_node_frame_cpu_seconds"]
    began, ended = got["window"]
    # the mesh was kept rendering over the whole frame, and the renders counted are the
    # window's
    assert made[0][0] < began < ended <= made[-1][1]
    counted = _within(made, began, ended)
    assert got["mesh_renders"] == len(counted)
    assert got["busiest_cpu_seconds"] == pytest.approx(
        sum(r[2]["busiest_node_cpu_seconds"] for r in counted) / len(counted)
    )
    assert got["busiest_frame_cpu_seconds"] == pytest.approx(10 * got["busiest_cpu_seconds"])
