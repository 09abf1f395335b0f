"""`meshnode warmup` compiles what a render needs: every kernel variant the engine's own choice
function (`variant_of`) can pick, and a render in a fresh process after a warmup compiles
nothing (numba's cache misses say so). The structure is part of a variant: an engine's
tracing kernel holds the walk of its own structure only."""

import subprocess
import sys

from hypothesis import given, settings
from hypothesis import strategies as st

from meshnode.engine.tables import build_tables
from meshnode.engine.variants import all_variants, variant_of
from meshnode.service.warmup import variant_scene
from tests.conftest import make_scene


def test_each_warmup_scene_makes_the_engine_choose_its_variant():
    variants = all_variants()
    assert len(set(variants)) == len(variants) == 2 * 94  # each of 94 under either structure
    for v in variants:
        assert variant_of(build_tables(variant_scene(v)), v.structure) == v


def test_every_variant_is_found_by_its_name_and_only_those():
    from meshnode.engine.variants import Variant

    for v in all_variants():
        assert Variant.parse(v.name) == v
        kinds = v.name.rsplit("/", 1)[0]
        # as a render's statistics name it: the grid's storage in the structure's place
        storages = ("csr", "hash", "brute-force") if v.structure == "grid" else ("bvh",)
        assert all(Variant.parse(f"{kinds}/{s}") == v for s in storages)
    for name in (
        "spheres",
        "cones+spheres/flat/shadows/refraction/bvh",
        "empty/smooth/x/y/grid",
        "spheres/flat/shadows/refraction",  # no structure
        "spheres/flat/shadows/refraction/octree",
    ):
        try:
            Variant.parse(name)
        except ValueError as e:
            assert name in str(e)
        else:
            raise AssertionError(f"{name!r} parsed")


@settings(max_examples=60, deadline=None)
@given(
    counts=st.lists(st.integers(0, 2), min_size=4, max_size=4),
    lights=st.integers(0, 2),
    smooth=st.booleans(),
    transmit=st.lists(st.booleans(), min_size=8, max_size=8),
)
def test_whatever_a_node_holds_its_variant_is_one_warmup_compiles(counts, lights, smooth, transmit):
    ns, nt, npoly, nc = counts
    mats = [((1, 1, 1), 0.5, 0.2, 10, 0.9 if t else 0.0, 1.5) for t in transmit]
    scene = make_scene(
        spheres=[((3 * i, 0, 0), 1.0, i) for i in range(ns)],
        triangles=[((i, 0, 0), (i + 1, 0, 0), (i, 1, 0), 2 + i) for i in range(nt)],
        polygons=[
            ([(i, 0, 1), (i + 1, 0, 1), (i + 1, 1, 1), (i, 1, 1)], 4 + i) for i in range(npoly)
        ],
        cones=[((i, 0, 2), 0.5, (i, 1, 2), 0.2, 6 + i) for i in range(nc)],
        lights=[(0, 5, -5)] * lights,
        materials=mats,
    )
    scene.triangles["smooth"] = smooth
    assert all(variant_of(build_tables(scene), s) in all_variants() for s in ("grid", "bvh"))


FRESH_RENDER = """
import numpy as np
from host.planning.request import Request
from host.run.oneprocess import render
from meshnode.engine import Engine
from meshnode.engine.camera import eye_rays
from meshnode.engine.kernelcache import kernels_compiled
from meshnode.engine.raycheck import first_untraceable
from meshnode.engine.occupancy import occupancy_arrays
from meshnode.engine.locator import owners
from meshnode.engine.lightmaps import light_maps
from meshnode.engine.sightlines import eye_map
from meshnode.service.warmup import ALL_KINDS, variant_scene
from protocols.render import ImageSpec

scene = variant_scene(ALL_KINDS)
render(Request(scene, ImageSpec(width=8, height=8)))
render(Request(scene, ImageSpec(spd=True, width=8, height=8)))
engine = Engine(scene, storage="hash")
rays = eye_rays(scene.view, ImageSpec(width=4, height=4))
engine.trace_node(rays)
owners(rays, np.zeros((1, 3)), np.ones((1, 3)))
engine.routed(rays, (np.zeros((1, 3)), np.ones((1, 3))), True, 0)
# an object-space map, its two occupied voxels' sub-voxel masks set (a node's has them)
masks = (2**64 - 1).to_bytes(8, "little") * 2
occ = occupancy_arrays(np.zeros(3), np.ones(3), (2, 2, 2), bytes([0x81]), masks)
light_maps(occ, np.array([[2.0, 2.0, 2.0]]))
cells = (np.zeros((1, 3)), np.ones((1, 3)))
eye, _ = eye_map(occ, scene.view, ImageSpec(width=4, height=4), cells)
engine.routed(rays, (np.zeros((1, 3)), np.ones((1, 3))), True, 0, eye)
first_untraceable(rays)
print(kernels_compiled())
"""


def test_a_render_in_a_fresh_process_after_warmup_compiles_nothing():
    from meshnode.service.warmup import warmup

    # The session's workers share the warmup out: make sure it is all in this cache (a load
    # from disk when another worker compiled it already).
    warmup()
    r = subprocess.run(
        [sys.executable, "-c", FRESH_RENDER], capture_output=True, text=True, timeout=600
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[-1] == "0", r.stdout


def test_an_engine_warms_only_the_kernel_it_traces_with(monkeypatch):
    """A node compiles its own tracing kernel, not the variant's three (tens of seconds each
    on a cold cache): one node's where its box holds the scene, a mesh node's where it does
    not, and the probe only the nearest-hit kernel."""
    import pytest

    from meshnode.engine import Engine
    from meshnode.service.warmup import ALL_KINDS

    scene = variant_scene(ALL_KINDS)
    whole = Engine(scene)
    part = Engine(scene, box=((-1, -1, -1), (0, 0, 0)), scene_box=((-5, -5, -5), (5, 5, 5)))
    called = []
    for engine, runs in ((whole, "trace"), (part, "trace_passing")):
        called.clear()
        for name in ("trace", "trace_passing", "first_hits"):
            monkeypatch.setattr(engine, name, lambda *a, name=name: called.append(name))
        engine.warmup()
        assert called == [runs]
        called.clear()
        engine.warmup(["probe"])
        assert called == ["first_hits"]
        assert engine.compiled
    with pytest.raises(ValueError, match="unknown kernels \\['bvh'\\]"):
        whole.warmup(["bvh"])


def test_one_process_at_a_time_compiles_a_variant():
    """`kernelcache.compiling` holds the cache's lock for one name (others wait on it, then
    load from disk) and none for another; probed without waiting (a non-blocking lock)."""
    import fcntl

    import pytest

    from meshnode.engine import kernelcache

    def held(name: str) -> bool:
        with open(kernelcache.lock_path(name), "a") as probe:
            try:
                fcntl.flock(probe, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            fcntl.flock(probe, fcntl.LOCK_UN)
            return False

    with kernelcache.compiling("test-variant-a"):
        assert held("test-variant-a")
        with kernelcache.compiling("test-variant-b"):  # another name: not blocked
            assert held("test-variant-b")
    assert not held("test-variant-a") and not held("test-variant-b")
    with (
        pytest.raises(RuntimeError, match="compile failed"),
        kernelcache.compiling("test-variant-a"),
    ):
        raise RuntimeError("compile failed")
    assert not held("test-variant-a")  # released on an error too


def test_kernels_of_no_variant_compile_under_the_cache_lock_once_then_are_warm():
    # The structure builds' kernels: the first process to need them takes the lock (the
    # others wait for it, then load from disk) and marks them warm, so later ones take no
    # lock at all. A second process holding the lock keeps the first out until it lets go.
    import fcntl
    import secrets

    from meshnode.engine import kernelcache

    name = f"test/{secrets.token_hex(8)}"
    assert not kernelcache.is_warm(name)
    held = []
    with kernelcache.compiled_once(name):
        with open(kernelcache.lock_path(name), "a") as other:
            try:
                fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)  # another open file: refused
            except BlockingIOError:
                held.append(True)
    assert held == [True] and kernelcache.is_warm(name)
    with kernelcache.compiled_once(name), open(kernelcache.lock_path(name), "a") as other:
        fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)  # warm: no lock taken
