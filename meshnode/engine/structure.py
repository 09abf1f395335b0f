"""The node's acceleration structure, the hierarchy or the uniform grid: as asked, or for "auto"
the one `structure_cost` expects to finish the render sooner (its build, memory and tracing of
the render's expected rays). Each structure's build kernels are loaded on a one-object call
before the timed build, so loading them from the disk cache (with numba's start-up, which the
first kernel a process runs pays) and building are timed apart (DESIGN.md 4).
"""

import time
from dataclasses import dataclass

import numpy as np

from meshnode.engine import kernelcache
from meshnode.engine.bvh import empty_nodes
from meshnode.engine.bvhbuild import Bvh
from meshnode.engine.grid import Grid, box_only, build_grid
from meshnode.engine.structure_cost import (
    Estimate,
    choose,
    grid_estimate,
    grid_forecast,
    grid_least,
    hierarchy_estimate,
)
from meshnode.engine.tables import Tables


@dataclass
class Structure:
    """What `build_structure` built and why; exactly one of `bvh` and `grid` is set."""

    bvh: Bvh | None
    grid: Grid | None
    reason: str
    estimates: dict | None  # "bvh"/"grid" -> Estimate.to_dict(), when chosen by them
    load_seconds: float = 0.0  # the build kernels loaded (or compiled, on a first run)
    build_seconds: float = 0.0  # the structures built (in "auto", the hierarchy too)


def foreseen(asked: str, resolution) -> str:
    """The structure `build_structure` is expected to build, known before it builds: the one
    asked, the grid for "auto" with a `resolution`, else the hierarchy ("auto" chooses it
    for every SPD scene; where it takes the grid the engine finds out after the build)."""
    if asked == "grid" or (asked == "auto" and resolution is not None):
        return "grid"
    return "bvh"


def stand_in(tables: Tables, box: tuple, structure: str) -> Structure:
    """A `structure` of no objects over `box`, of the same kernel types as a built one, made
    without running (or compiling) any build kernel: an engine over it compiles its variant's
    tracing kernels (`meshnode warmup --variant`, beside a first render) and finds no hit."""
    if structure == "grid":
        return Structure(None, box_only(*box), "a stand-in of no objects", None)
    bvh = Bvh.__new__(Bvh)  # one node whose four boxes are empty (lo > hi)
    bvh.nodes = empty_nodes()
    bvh.order = np.arange(tables.n, dtype=np.int64)
    bvh.stats = {"structure_bytes": int(bvh.nodes.nbytes), "stand_in": True}
    return Structure(bvh, None, "a stand-in of no objects", None)


def build_structure(
    tables: Tables,
    box: tuple,
    *,
    asked: str,
    resolution,
    density: float,
    storage: str,
    rays: float,
) -> Structure:
    """The structure `asked` ("grid", "bvh", "auto") over `box` (lo, hi): "auto" takes the
    grid when a `resolution` is given, else the one of smaller expected total seconds for
    `rays` rays (the hierarchy is built either way: its forecast is the estimate's; the
    grid is forecast only where its lower bound, `grid_least`, is under the hierarchy's)."""
    lo, hi = box
    timer = _Timer()
    if asked == "grid" or (asked == "auto" and resolution is not None):
        why = "forced by flag (grid)" if asked == "grid" else "a grid resolution was given"
        grid = timer.grid(tables, lo, hi, density, storage, resolution)
        return timer.done(Structure(None, grid, why, None))
    bvh = timer.bvh(tables)
    if asked == "bvh":
        return timer.done(Structure(bvh, None, "forced by flag (bvh)", None))
    start, s = time.perf_counter(), bvh.stats
    hierarchy = hierarchy_estimate(
        tables.n, s["expected_tests"], s["expected_visits"], rays, s["structure_bytes"]
    )
    grid = grid_least(tables.lo, tables.hi, lo, hi, rays)
    if hierarchy.total <= grid.total:  # the grid cannot win: not forecast
        chosen, why = hierarchy, _unforecast(hierarchy, grid, rays)
    else:
        grid = grid_estimate(grid_forecast(tables.lo, tables.hi, lo, hi, density), rays)
        chosen, why = choose([hierarchy, grid], rays)
    timer.build += time.perf_counter() - start  # choosing counts as building
    estimates = {e.structure: e.to_dict() for e in (hierarchy, grid)}
    if chosen is hierarchy:
        return timer.done(Structure(bvh, None, why, estimates))
    built = timer.grid(tables, lo, hi, density, storage, None)
    return timer.done(Structure(None, built, why, estimates))


def _unforecast(hierarchy: Estimate, least: Estimate, rays: float) -> str:
    """Why the hierarchy was taken with the grid's lower bound alone (`grid_least`)."""
    return (
        f"expected for {rays:.3g} rays: hierarchy {hierarchy.build:.3g} s to build + "
        f"{hierarchy.trace:.3g} s to trace = {hierarchy.total:.3g} s; grid at least "
        f"{least.load + least.build:.3g} s to build + {least.trace:.3g} s to trace = "
        f"{least.total:.3g} s: the hierarchy is expected sooner than the grid could be, "
        "which is not forecast"
    )


# Builds whose kernels this process loaded on their one-object call (`_Timer._timed`): a
# later build has nothing to load, and its one-object build cost 0.4 ms an engine (3.6 ms of
# a 3x3 simulation's 90 in the cost pre-pass, which builds hundreds)
_LOADED: set[str] = set()


class _Timer:
    """Seconds loading build kernels (a one-object build first) and building, kept apart."""

    def __init__(self):
        self.load = self.build = 0.0

    def _timed(self, load, build, once: str = ""):
        """build() timed apart from load(); with `once` named, load() only on the first
        such build in this process (the kernels stay loaded)."""
        start = time.perf_counter()
        if once not in _LOADED:
            load()
            if once:
                _LOADED.add(once)
        middle = time.perf_counter()
        out = build()
        self.load += middle - start
        self.build += time.perf_counter() - middle
        return out

    def bvh(self, tb: Tables) -> Bvh:
        with kernelcache.compiled_once("build/bvh"):
            return self._timed(
                lambda: Bvh(tb.lo[:1], tb.hi[:1], np.minimum(tb.offsets, 1)),
                lambda: Bvh(tb.lo, tb.hi, tb.offsets),
                once="bvh",  # every build's arguments are of one type: loaded, loaded for all
            )

    def grid(self, tb: Tables, lo, hi, density, storage, resolution) -> Grid:
        # One voxel: every object counted once, on the kernels of this node's kinds.
        one = np.ones(3, np.int64)
        with kernelcache.compiled_once("build/grid"):
            return self._timed(
                lambda: build_grid(tb, lo, hi, density=density, storage=storage, res=one),
                lambda: build_grid(tb, lo, hi, density=density, storage=storage, res=resolution),
            )

    def done(self, structure: Structure) -> Structure:
        structure.load_seconds, structure.build_seconds = self.load, self.build
        return structure
