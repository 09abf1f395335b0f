"""Shared test helpers: where the SPD scenes are, the kernel cache, small scene builders.

Kernels are cached on disk in one folder (`meshnode.engine.jit`: a folder per version of the
kernel sources, under NUMBA_CACHE_DIR or ~/.cache/meshtrace, which the node processes the
tests start share), so each kernel variant compiles once per session, or never when the cache
is warm; the session's first fixture compiles the common variants up front and the summary
says how long that took and whether the cache was cold. With MESHTRACE_REQUIRE_SCENES=1 (CI
sets it) a missing scene folder fails every test that needs it instead of skipping it.
"""

import os
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

from host.camera.setup import CameraSetup, Focus
from protocols import dtypes
from protocols.camera import CameraSampling
from protocols.render import EngineSpec, ImageSpec
from protocols.scene import SceneData, View
from tests import tiers

ROOT = Path(__file__).resolve().parents[1]

# The SPD scenes (docs/scenes.md: where they come from): $MESHTRACE_SCENES, else beside the
# checkout.
SCENES = Path(os.environ.get("MESHTRACE_SCENES") or ROOT.parent / "shared" / "scenes")
KERNEL_LOAD: dict[str, float] = {}


def spd_scene(name: str) -> Path:
    """Path of an SPD scene; without the scene folder the test is skipped, or fails when
    MESHTRACE_REQUIRE_SCENES=1."""
    return shared_file(SCENES / name)


def shared_file(path: Path) -> Path:
    """`path` of the data shared beside the checkout (scenes, lens files): a test without
    it is skipped, or fails when MESHTRACE_REQUIRE_SCENES=1 (CI has them)."""
    if not path.exists():
        if os.environ.get("MESHTRACE_REQUIRE_SCENES") == "1":
            pytest.fail(f"{path} is missing and MESHTRACE_REQUIRE_SCENES=1")
        pytest.skip(f"{path} not available")
    return path


EXAMPLE = Path(__file__).resolve().parents[1] / "host" / "examples" / "showcase.nff"
# Scenes whose kernel variants most test files use (the all-kinds variant aside).
WARM_SCENES = (
    "balls_s1.nff",
    "tetra_s1.nff",
    "teapot_s1.nff",
    "rings_s1.nff",
    "tree_s1.nff",
    "gears_s1.nff",
    "mount_s1.nff",
)


def example_variants() -> tuple[set, set]:
    """The kernel variants of the README example's engines: (one node's, those of the nodes
    of the 2x2 object-space mesh that subprocess tests (live view, Ctrl-C) render it on
    within short deadlines; a node compiling its variant there would miss them)."""
    from host.planning.partition import partition
    from host.scene.nff import read_nff
    from host.scene.subset import subset
    from meshnode.engine.tables import build_tables
    from meshnode.engine.variants import variant_of
    from protocols.render import MeshPlan, RenderSpec

    scene = read_nff(EXAMPLE)
    nodes = set()
    for size in ((40, 30), (None, None)):
        image = ImageSpec(width=size[0], height=size[1]).sized(scene.view)
        part, keep = partition(scene, RenderSpec(image, plan=MeshPlan(2, 2, mode="object")))
        nodes |= {variant_of(build_tables(subset(scene, keep[n]))) for n in range(part.nodes)}
    return {variant_of(build_tables(scene))}, nodes


def warm_jobs() -> list:
    """What the session compiles up front, heaviest first: the all-kinds variant's every
    kernel, the common kernels (eye rays, routing, camera), then the one-node and mesh-node
    kernels of the SPD scenes' variants (when present) and the README example's, and the
    mesh-node kernel of its 2x2 nodes' (`example_variants`). The probe's kernel of other
    variants compiles where a test focuses on them (`Engine.warmup`: kernels apiece)."""
    from meshnode.engine.tables import build_tables
    from meshnode.engine.variants import variant_of
    from meshnode.service.warmup import ALL_KINDS, warmup

    jobs = [lambda: warmup([ALL_KINDS], common=False), lambda: warmup([], common=True)]
    whole, nodes = example_variants()
    if SCENES.exists():
        from host.scene.nff import read_nff

        whole |= {
            variant_of(build_tables(read_nff(SCENES / n)))
            for n in WARM_SCENES
            if (SCENES / n).exists()
        }
    kernels = {v: ("trace", "passing") for v in whole - {ALL_KINDS}}
    kernels.update({v: ("passing",) for v in nodes - whole - {ALL_KINDS}})
    jobs += [lambda v=v: warmup([v], common=False, kernels=kernels[v]) for v in sorted(kernels)]
    return jobs


@pytest.fixture(scope="session", autouse=True)
def kernels(request):
    """Compile (cold cache) or load (warm) the kernels most tests use, before any test, so
    node processes started later load them from disk. pytest-xdist workers share the jobs
    out (worker k takes jobs k, k + n, ...): on a cold cache each kernel compiles on one
    core while the other compiles others, instead of both compiling the same; a kernel
    another worker compiled is then loaded from disk when first used."""
    import numba

    cache = Path(numba.config.CACHE_DIR)
    KERNEL_LOAD["cache"] = str(cache)
    KERNEL_LOAD["cold"] = not any(cache.rglob("*.nbi")) if cache.exists() else True
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    start = time.perf_counter()
    for job in warm_jobs()[index::count]:
        job()
    KERNEL_LOAD["seconds"] = time.perf_counter() - start
    report = getattr(request.config, "workeroutput", None)  # a pytest-xdist worker
    if report is not None:
        report["kernel_load"] = dict(KERNEL_LOAD)


WORKER_LOADS: list[dict] = []


def pytest_configure(config):
    for name, what in tiers.MARKERS.items():
        config.addinivalue_line("markers", f"{name}: {what}")


def pytest_collection_modifyitems(config, items):
    tiers.classify(items)


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """pytest-xdist: a worker's kernel load figures, for the summary."""
    load = getattr(node, "workeroutput", {}).get("kernel_load")
    if load:
        WORKER_LOADS.append(load)


def pytest_terminal_summary(terminalreporter):
    missing = [
        r
        for r in terminalreporter.stats.get("skipped", [])
        if str(SCENES) in str(getattr(r, "longrepr", ""))
    ]
    if missing:
        terminalreporter.write_line(
            f"{len(missing)} tests skipped: no SPD scenes in {SCENES} (set MESHTRACE_SCENES; "
            "the README says where the scenes come from)"
        )
    for load in ([KERNEL_LOAD] if KERNEL_LOAD else []) + WORKER_LOADS:
        kind = "compiled (cold cache)" if load["cold"] else "loaded (warm cache)"
        terminalreporter.write_line(
            f"kernels {kind} in {load['seconds']:.1f} s, cache {load['cache']}"
        )


def make_scene(
    spheres=(),
    triangles=(),
    polygons=(),
    cones=(),
    lights=(),
    materials=None,
    view=None,
    background=(0.0, 0.0, 0.0),
) -> SceneData:
    """A scene from plain tuples: spheres (c, r, mat), triangles (v0, v1, v2, mat),
    polygons (vertices, mat), cones (base, br, apex, ar, mat), lights (pos). gids follow the
    order spheres, triangles, polygons, cones."""
    view = view or View(eye=(0, 0, -10), at=(0, 0, 0), up=(0, 1, 0), angle=45.0)
    mats = materials or [((1.0, 1.0, 1.0), 1.0, 0.0, 1.0, 0.0, 1.0)]
    m = np.zeros(len(mats), dtypes.MATERIAL)
    for i, (rgb, kd, ks, shine, t, ior) in enumerate(mats):
        m[i] = (rgb, kd, ks, shine, t, ior)
    gid = 0
    s = np.zeros(len(spheres), dtypes.SPHERE)
    for i, (c, r, mat) in enumerate(spheres):
        s[i] = (gid, mat, c, r)
        gid += 1
    t = np.zeros(len(triangles), dtypes.TRIANGLE)
    for i, (a, b, c, mat) in enumerate(triangles):
        v = np.array([a, b, c], float)
        n = np.cross(v[1] - v[0], v[2] - v[0])
        n /= np.linalg.norm(n)
        t[i] = (gid, mat, v, np.tile(n, (3, 1)), 0)
        gid += 1
    p = np.zeros(len(polygons), dtypes.POLYGON)
    verts = []
    for i, (vs, mat) in enumerate(polygons):
        p[i] = (gid, mat, sum(len(x) for x in verts), len(vs))
        verts.append(np.asarray(vs, float))
        gid += 1
    c = np.zeros(len(cones), dtypes.CONE)
    for i, (b, br, a, ar, mat) in enumerate(cones):
        c[i] = (gid, mat, b, br, a, ar)
        gid += 1
    li = np.zeros(len(lights), dtypes.LIGHT)
    for i, pos in enumerate(lights):
        li[i] = (pos, (1.0, 1.0, 1.0))
    return SceneData(
        view=view,
        background=background,
        lights=li,
        materials=m,
        spheres=s,
        triangles=t,
        polygons=p,
        vertices=np.concatenate(verts) if verts else np.zeros((0, 3)),
        cones=c,
    )


class Job(NamedTuple):
    """A render's records, for `render(scene, *job)`."""

    image: ImageSpec
    engine: EngineSpec
    camera: CameraSetup | None


def records(camera=None, **options) -> Job:
    """The records of a render from keywords named as their fields (ImageSpec, EngineSpec,
    and with a camera CameraSampling and Focus); an unknown keyword is an error."""

    def pick(record):
        return {k: options.pop(k) for k in list(options) if k in record.__dataclass_fields__}

    image, engine = ImageSpec(**pick(ImageSpec)), EngineSpec(**pick(EngineSpec))
    setup = None
    if camera is not None:
        setup = CameraSetup(camera, CameraSampling(**pick(CameraSampling)), Focus(**pick(Focus)))
    if options:
        raise TypeError(f"no render record has fields {sorted(options)}")
    return Job(image, engine, setup)
