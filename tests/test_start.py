"""A render's process starts with what it runs (issue 42 item 4; `bench.start` times it): a
one-process render imports no mesh, network, live-view or lens module, and once its kernels
are in the disk cache it loads them without readying numba's compiler
(`meshnode.engine.loading`), while a compile after such loads is as numba makes it."""

import ast
import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import EXAMPLE

ROOT = Path(__file__).resolve().parents[1]

# The `meshtrace` script's run, then the modules the process imported (main() returns: the
# script would exit with its status).
RENDER = """
import sys
sys.argv[0] = "meshtrace"
from host.cli import main
assert main() == 0
print("\\n".join(sorted(sys.modules)))
"""
# What a one-process pinhole render runs without: the mesh and its network, the live view,
# the lens code, and (its kernels cached) numba's compiler and what its readying imports.
NOT_IMPORTED = {
    "network and mesh": [
        "asyncio",
        "ssl",
        "msgpack",
        "aiohttp",
        "host.run.meshclient",
        "host.run.connections",
        "host.run.localmesh",
        "host.planning.prepass",
        "meshnode.mesh.simulator",
        "meshnode.transport.link",
        "meshnode.service",
    ],
    "live view and progress": ["host.live", "tqdm"],
    "lens": [
        "host.cli.camera",
        "host.camera.lens",
        "host.camera.lensfile",
        "meshnode.engine.optics",
        "meshnode.engine.lenscamera",
        "meshnode.engine.pupil",
    ],
    "numba's compiler": [
        "numba.np.arrayobj",
        "numba.np.arraymath",
        "numba.np.npyimpl",
        "numba.cpython.unicode",
        "numba.typed.typedlist",
        "cffi",
        "scipy.linalg",
    ],
    "image library": ["PIL"],
}


def _render(tmp_path, name: str, env: dict | None = None) -> tuple[set[str], dict]:
    """(modules imported, statistics) of a small render of the README example in a fresh
    process, as the `meshtrace` script runs it."""
    out, stats = tmp_path / f"{name}.png", tmp_path / f"{name}.json"
    argv = ["render", str(EXAMPLE), "--width", "40", "--height", "30", "-o", str(out)]
    argv += ["--stats", str(stats), "--quiet", "--mesh", "1x1"]
    r = subprocess.run(
        [sys.executable, "-c", RENDER, *argv],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stderr
    return set(r.stdout.split()), json.loads(stats.read_text())


@pytest.fixture(scope="module")
def cached(tmp_path_factory):
    """One render first, once for the module: its kernels into the cache, if a worker has
    not yet (the renders the tests look at then load every kernel)."""
    _render(tmp_path_factory.mktemp("first"), "first")


def test_a_one_process_render_imports_only_what_it_runs(tmp_path, cached):
    modules, stats = _render(tmp_path, "warm")
    assert stats["compile_seconds"] == 0.0  # every kernel loaded from the cache
    for what, names in NOT_IMPORTED.items():
        loaded = [m for m in modules for n in names if m == n or m.startswith(n + ".")]
        assert not loaded, f"{what}: {loaded}"
    assert {"host.run.oneprocess", "meshnode.engine.trace", "numba"} <= modules


def test_numba_left_as_it_is_renders_the_same_image(tmp_path, cached):
    _, ours = _render(tmp_path, "ours")
    plain_modules, plain = _render(tmp_path, "plain", {**os.environ, "MESHTRACE_PLAIN_NUMBA": "1"})
    assert (tmp_path / "ours.png").read_bytes() == (tmp_path / "plain.png").read_bytes()
    assert ours["rays"] == plain["rays"]
    assert "numba.np.arrayobj" in plain_modules  # the switch really leaves numba readying all


# A kernel of this test's own, cached in its own module: compiled in one process after a
# cached kernel loaded there, loaded in the next; typed lists, strings and BLAS need the
# compiler's every registry, which loads alone never readied. (numba's np.dot needs scipy,
# which the project does not install: without it the product is summed by hand.)
DOT = "np.dot(a, b)" if importlib.util.find_spec("scipy") is not None else "(a * b).sum()"
KERNEL_MODULE = """
import numba
import numpy as np
from numba.typed import List


@numba.njit(cache=True)
def mixed(a, b):
    parts = List()
    for x in a:
        parts.append(x * 2.0)
    label = "n=" + str(len(parts))
    return DOT, sum(parts), label
""".replace("DOT", DOT)
COMPILE_AFTER_LOADS = """
import sys
import numpy as np
from meshnode.engine.camera import eye_rays
from protocols.render import ImageSpec
from protocols.scene import View

eye_rays(View((0, 0, 0), (0, 0, 1), (0, 1, 0), 45.0), ImageSpec(width=1, height=1))
sys.path.insert(0, sys.argv[1])
from ownkernel import mixed

dot, total, label = mixed(np.arange(3.0), np.ones(3))
print(dot, total, label, sum(mixed.stats.cache_hits.values()), mixed.stats.cache_path)
"""


def test_a_compile_after_cached_loads_is_numbas_own(tmp_path):
    (tmp_path / "ownkernel.py").write_text(KERNEL_MODULE)
    runs = []
    try:
        for _ in range(2):  # compiled (a cache miss), then loaded (a hit)
            r = subprocess.run(
                [sys.executable, "-c", COMPILE_AFTER_LOADS, str(tmp_path)],
                capture_output=True,
                text=True,
                timeout=600,
                cwd=ROOT,
            )
            assert r.returncode == 0, r.stderr
            runs.append(r.stdout.split())
    finally:  # the kernel's folder in the shared cache (numba's, named after tmp_path)
        for run in runs:
            shutil.rmtree(run[-1], ignore_errors=True)
    assert runs[0][:3] == runs[1][:3] == ["3.0", "6.0", "n=3"]
    assert (runs[0][3], runs[1][3]) == ("0", "1")


# numpy functions numba lowers to BLAS or LAPACK calls (numba.np.linalg)
BLAS_CALLS = {"dot", "vdot", "inner", "outer", "matmul", "kron", "linalg"}
KERNEL_DECORATORS = {"kernel", "leaf", "inline"}


def test_no_kernel_calls_blas():
    """`meshnode.engine.loading` loads scipy's BLAS module alone, outside its package: no
    kernel may need more of it (np.dot, np.linalg, the @ operator)."""
    found = []
    for path in sorted((ROOT / "meshnode" / "engine").glob("*.py")):
        for fn in ast.walk(ast.parse(path.read_text())):
            if not isinstance(fn, ast.FunctionDef):
                continue
            names = {d.id for d in fn.decorator_list if isinstance(d, ast.Name)}
            if not names & KERNEL_DECORATORS:
                continue
            for node in ast.walk(fn):
                attr = isinstance(node, ast.Attribute) and node.attr in BLAS_CALLS
                matmul = isinstance(node, ast.BinOp | ast.AugAssign) and isinstance(
                    node.op, ast.MatMult
                )
                if attr or matmul:
                    found.append(f"{path.name}:{node.lineno} in {fn.name}")
    assert not found, found


# A first render from an empty cache, in this tree, saying what it compiled where: numba's
# misses of the tracing kernel in the render's own process, and the setup's statistics.
COLD = """
import sys
from host.planning.request import Request
from host.run.oneprocess import render
from host.scene.nff import read_nff
from meshnode.engine.trace import trace_batch
from protocols.render import ImageSpec

img, stats = render(Request(read_nff(sys.argv[1]), ImageSpec(width=16, height=12)), progress=True)
print(sum(trace_batch.stats.cache_misses.values()), sum(trace_batch.stats.cache_hits.values()))
print(stats["compile_aside_seconds"], stats["rays"]["eye_rays"])
"""
SPHERES = """v
from 0 0 -5
at 0 0 0
up 0 1 0
angle 40
hither 0.1
resolution 16 12
f 1 0.5 0.5 0.8 0 10 0 1
s 0 0 0 1
s 1.5 0 1 0.5
"""


@pytest.mark.slow
def test_a_cold_first_render_compiles_its_tracing_kernel_in_a_second_process(tmp_path):
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if cores < 2:
        pytest.skip("one core: the render compiles its tracing kernel itself")
    scene = tmp_path / "spheres.nff"
    scene.write_text(SPHERES)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}  # empty: all compiles
    r = subprocess.run(
        [sys.executable, "-c", COLD, str(scene)],
        capture_output=True,
        text=True,
        timeout=1200,
        env=env,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stderr
    misses, hits, aside, eye_rays = r.stdout.split()
    assert (misses, hits) == ("0", "1")  # loaded from the cache the second process filled
    assert float(aside) > 0 and int(eye_rays) == 16 * 12
    assert "compiled the tracing kernel in a second process in" in r.stderr


def test_compiles_and_loads_are_timed_once_outermost_on_the_thread_that_runs_them():
    # the host's cost pre-pass leaves kernels readied out of its CPU (`load_seconds`): a
    # kernel compiled on a first run counts there, its callees within it, a second call not
    import time

    import numba
    import numpy as np

    from meshnode.engine.loading import load_seconds

    @numba.njit(cache=False)
    def inner(a):
        return a.sum()

    @numba.njit(cache=False)
    def outer(a):
        return inner(a) * 2.0

    before, cpu = load_seconds(), time.process_time()
    assert outer(np.ones(3)) == 6.0
    counted, spent = load_seconds() - before, time.process_time() - cpu
    assert 0.5 * spent < counted <= spent + 1e-3  # the compile, callees once, not twice
    again = load_seconds()
    assert outer(np.ones(4)[::2]) == 4.0  # a new type: compiled again
    assert load_seconds() > again
    settled = load_seconds()
    for _ in range(3):
        outer(np.ones(3))
    assert load_seconds() == settled
