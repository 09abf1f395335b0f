"""Cold start of nodes sharing one kernel cache: N processes that need the same cold variant
warm it at once, with the cache's compile lock (`meshnode.engine.kernelcache.compiling`: one
compiles, the others wait and load it) and each compiling its own, side by side in one run.

    python -m bench.compile_lock [--processes 3] [--turns 1]

Each mode starts from an empty cache folder (the common kernels compiled first, as a node's
image has them); the two modes take turns (lock, own, lock, own ...) `--turns` rounds
(`bench.timing`). Printed per mode: its wall seconds (what a mesh waits for, the lock's point)
and the processes' summed CPU seconds (`RUSAGE_CHILDREN`), each a median (least-most) over the
rounds; the last line gives the ratios no lock / lock, each the median of the rounds' paired
ratios (least-most).
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.timing import Turns, child_cpu, turns  # noqa: E402 (after the path is set)

# One mesh node's engine of a variant the common warmup does not hold, warmed as a node does.
NODE = """
import contextlib, sys
from meshnode.engine import Engine, kernelcache
from meshnode.engine.variants import Variant
from meshnode.service.warmup import variant_scene
if sys.argv[1] == "own":
    kernelcache.compiling = lambda name: contextlib.nullcontext()
scene = variant_scene(Variant(("spheres", "polygons"), False, True, False, "grid"))
Engine(scene, box=((-1, -1, -1), (0, 0, 0)), scene_box=((-5, -5, -5), (5, 5, 5))).warmup()
"""


def cold_start(mode: str, processes: int) -> tuple[float, float]:
    """(wall seconds, summed CPU seconds) of `processes` nodes warming the variant at once,
    from an empty cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        common = "from meshnode.service.warmup import _common_warmup; _common_warmup()"
        subprocess.run([sys.executable, "-c", common], env=env, check=True)
        before = child_cpu()
        start = time.perf_counter()
        procs = [
            subprocess.Popen([sys.executable, "-c", NODE, mode], env=env) for _ in range(processes)
        ]
        if any(p.wait() for p in procs):
            raise RuntimeError(f"a node failed to warm up ({mode})")
        wall = time.perf_counter() - start
        cpu = child_cpu() - before
    return wall, cpu


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.compile_lock", description=__doc__.split("\n\n")[0])
    p.add_argument("--processes", type=int, default=3)
    p.add_argument("--turns", type=int, default=1, help="rounds of lock, own (1)")
    args = p.parse_args(argv)
    walls, cpus = Turns(), Turns()
    for _, mode in turns(("lock", "own"), args.turns):
        wall, cpu = cold_start(mode, args.processes)
        walls.add(mode, wall)
        cpus.add(mode, cpu)
    print(f"{args.processes} processes, {args.turns} rounds in turns: median (least-most)")
    for mode in ("lock", "own"):
        name = "shared lock" if mode == "lock" else "each its own"
        wall, cpu = walls.figure(mode).text("{:.1f}"), cpus.figure(mode).text("{:.1f}")
        print(f"{name:>13}: wall {wall} s   CPU {cpu} s")
    wall, cpu = walls.ratio("own", "lock"), cpus.ratio("own", "lock")
    print(
        f"each its own / shared lock (median of paired ratios): wall {wall.text('{:.2f}')}, "
        f"CPU {cpu.text('{:.2f}')}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
