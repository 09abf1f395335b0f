"""Cold start of nodes sharing one kernel cache: N processes that need the same cold variant
warm it at once, with the cache's compile lock (`meshnode.engine.kernelcache.compiling`: one
compiles, the others wait and load it) and each compiling its own, side by side in one run.

    python -m bench.compile_lock [--processes 3]

Each mode starts from an empty cache folder (the common kernels compiled first, as a node's
image has them) and prints its wall seconds and the processes' summed CPU seconds; the last
line gives the ratios (no lock / lock).
"""

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

# One mesh node's engine of a variant the common warmup does not hold, warmed as a node does.
NODE = """
import contextlib, sys
from meshnode.engine import Engine, kernelcache
from meshnode.engine.variants import Variant
from meshnode.service.warmup import variant_scene
if sys.argv[1] == "own":
    kernelcache.compiling = lambda name: contextlib.nullcontext()
scene = variant_scene(Variant(("spheres", "polygons"), False, True, False))
Engine(scene, box=((-1, -1, -1), (0, 0, 0)), scene_box=((-5, -5, -5), (5, 5, 5))).warmup()
"""


def cold_start(mode: str, processes: int) -> tuple[float, float]:
    """(wall seconds, summed CPU seconds) of `processes` nodes warming the variant at once,
    from an empty cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        common = "from meshnode.service.warmup import _common_warmup; _common_warmup()"
        subprocess.run([sys.executable, "-c", common], env=env, check=True)
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        procs = [
            subprocess.Popen([sys.executable, "-c", NODE, mode], env=env) for _ in range(processes)
        ]
        if any(p.wait() for p in procs):
            raise RuntimeError(f"a node failed to warm up ({mode})")
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.compile_lock", description=__doc__.split("\n\n")[0])
    p.add_argument("--processes", type=int, default=3)
    args = p.parse_args(argv)
    rows = {mode: cold_start(mode, args.processes) for mode in ("lock", "own")}
    for mode, (wall, cpu) in rows.items():
        name = "shared lock" if mode == "lock" else "each its own"
        print(f"{name:>13}: wall {wall:6.1f} s   CPU {cpu:6.1f} s   ({args.processes} processes)")
    (lw, lc), (ow, oc) = rows["lock"], rows["own"]
    print(f"each its own / shared lock: wall {ow / lw:.2f}x, CPU {oc / lc:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
