"""One node's render in a process of its own, for `bench.mesh_runs.at_once`: its whole
process's CPU for the frame is then its own, where on a thread of the bench's process it
was mixed with the mesh's host (so only its tracing thread could be compared).

    python -m bench.one_process JOB

JOB is a pickle of (scene, image, camera) that the bench wrote for this run. The render runs
twice, as `bench.mesh_reference.single` does (the first loads the kernels its scene needs,
so no load falls in the measured frame); the second's frame is measured. One line of JSON on
stdout: its tracing and frame CPU seconds, and its frame's start and end on the clock
`time.perf_counter` reads, which on Linux is the system's monotonic clock, the same in every
process (the bench counts the mesh renders that ended within it).
"""

import json
import pickle
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def measured(scene, image, camera) -> dict:
    """The figures `at_once` reads of one node's render after a warm one."""
    from bench.mesh_reference import single

    single(scene, image, warm=False, camera=camera)  # loads the kernels
    began = time.perf_counter()
    _, stats = single(scene, image, warm=False, camera=camera)
    return {
        "trace_cpu_seconds": stats["trace_cpu_seconds"],
        "frame_cpu_seconds": stats["frame_cpu_seconds"],
        "began": began,
        "ended": time.perf_counter(),
    }


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m bench.one_process JOB", file=sys.stderr)
        return 2
    with open(argv[0], "rb") as f:
        scene, image, camera = pickle.load(f)  # the bench's own file, written for this run
    print(json.dumps(measured(scene, image, camera)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
