"""The structure is a type of the tracing kernels (`meshnode.engine.variants.Variant`): an
engine passes the structure it does not walk as None, so its compiled tracing kernel holds
its own structure's walk only; the variant's name says which, a stand-in structure of no
objects compiles the same kernel without any build kernel (`meshnode warmup --variant`
beside a first render), and the structure announced before the build is corrected when
"auto" chooses the other (`host.run.aside` then compiles that one)."""

import numpy as np
from numba.core import types

from meshnode.engine import Engine, kernelcache
from meshnode.engine.trace import trace_batch
from meshnode.service.warmup import ALL_KINDS, variant_scene


def _signature(engine: Engine) -> tuple:
    """The argument types of the tracing kernel `engine` ran (its one-node kernel)."""
    engine.warmup(["trace"])
    entries = set(engine._trace_batch.entries.values())
    [sig] = [sig for sig, cres in trace_batch.overloads.items() if cres.entry_point in entries]
    return sig


GRID, BVH = 5, 12  # the structures' places among trace_batch's arguments


def test_a_tracing_kernel_holds_only_the_structure_it_walks():
    scene = variant_scene(ALL_KINDS)
    bvh = _signature(Engine(scene, structure="bvh"))
    assert isinstance(bvh[GRID], types.NoneType) and "GridArrays" not in str(bvh)
    assert "BvhArrays" in str(bvh[BVH])
    for engine in (Engine(scene, structure="grid"), Engine(scene, brute=True)):
        grid = _signature(engine)
        assert isinstance(grid[BVH], types.NoneType) and "BvhArrays" not in str(grid)
        assert "GridArrays" in str(grid[GRID])
        assert engine.kernel_variant.structure == "grid"
    # brute force shares the grid's kernel: a value, not a type
    assert _signature(Engine(scene, brute=True)) == _signature(Engine(scene, structure="grid"))


def test_a_stand_in_structure_compiles_the_kernel_a_built_one_runs_and_finds_nothing():
    scene = variant_scene(ALL_KINDS)
    for structure in ("grid", "bvh"):
        built = Engine(scene, structure=structure)
        stand_in = Engine(scene, structure=structure, stand_in=True)
        assert stand_in.kernel_variant == built.kernel_variant
        assert stand_in.kernel_variant.name.endswith("/" + structure)
        assert _signature(stand_in) == _signature(built)
        o, d = np.zeros((2, 3)), np.array([[0.0, 0.0, 1.0], [0.05, -0.05, 1.0]])
        t, gid = stand_in.first_hits(o - (0, 0, 5), d)
        assert np.isinf(t).all() and (gid == -1).all()
        t, gid = built.first_hits(o - (0, 0, 5), d)
        assert (gid >= 0).all()  # the scene's sphere at the origin, for the built one


def test_the_variant_announced_names_the_structure_and_is_corrected_after_the_choice(
    monkeypatch,
):
    import meshnode.engine.engine as engine_module

    monkeypatch.setattr(kernelcache, "is_warm", lambda name: False)
    scene = variant_scene(ALL_KINDS)
    kinds = ALL_KINDS.name.rsplit("/", 1)[0]
    for options, expected in (
        ({"structure": "bvh"}, ["bvh"]),
        ({"structure": "grid"}, ["grid"]),
        ({"brute": True}, ["grid"]),
        ({"resolution": (2, 2, 2)}, ["grid"]),  # "auto" with a resolution: the grid
    ):
        said = []
        Engine(scene, announce=said.append, **options)
        assert said == [f"{kinds}/{s}" for s in expected], options
    # "auto" is foreseen to take the hierarchy; where it takes the grid, that is said next
    monkeypatch.setattr(engine_module, "foreseen", lambda asked, resolution: "bvh")
    said = []
    engine = Engine(scene, structure="grid", announce=said.append)
    assert said == [f"{kinds}/bvh", f"{kinds}/grid"] and engine.structure == "grid"


def test_the_second_process_starts_again_for_another_variant_only(monkeypatch):
    from host.run import aside

    started, killed = [], []

    class Process:
        def __init__(self, command, **_):
            self.variant = command[command.index("--variant") + 1]
            started.append(self.variant)

        def poll(self):
            return None if self.variant not in killed else -9

        def kill(self):
            killed.append(self.variant)

        def wait(self):
            return -9

    monkeypatch.setattr(aside.subprocess, "Popen", Process)
    monkeypatch.setattr(aside, "_cores", lambda: 2)
    with aside.CompileAside() as second:
        announce = second.announce()
        announce("spheres/flat/shadows/no-refraction/bvh")
        announce("spheres/flat/shadows/no-refraction/bvh")  # the same: left compiling
        assert started == ["spheres/flat/shadows/no-refraction/bvh"] and killed == []
        announce("spheres/flat/shadows/no-refraction/grid")  # auto chose the grid
        assert killed == ["spheres/flat/shadows/no-refraction/bvh"]
        assert started[-1] == "spheres/flat/shadows/no-refraction/grid"
    assert killed[-1] == "spheres/flat/shadows/no-refraction/grid"  # stopped at the end
