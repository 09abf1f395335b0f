"""What each structure would cost a render: the hierarchy's and the uniform grid's expected
seconds to load their build kernels, to build, and to trace the rays the render is expected to
send through the node, and the bytes each keeps (DESIGN.md 4; issue 42). The engine builds the
one whose total is smaller (`choose`).

The grid is forecast before it is built: `grid_forecast` follows `grid.build_grid`'s choice of
resolution with every object's box span in voxels standing in for the voxels it touches, which
gives the references and voxels the build would make, the voxels its counting passes would
test, and the tests and steps of a ray crossing it. The hierarchy is built first (its build
is a few milliseconds) and gives its own forecast (`Bvh.stats`).
"""

import math
from dataclasses import dataclass

import numpy as np

from meshnode.engine.grid import (
    MAX_REFS,
    MAX_REFS_PER_OBJECT,
    MAX_VOXELS,
    choose_resolution,
    grow_box,
    occupancy,
)
from protocols.render import ImageSpec
from protocols.scene import SceneData

# Unit costs in seconds on this machine (2 cores shared with other work; one thread), fitted
# by `python -m bench.structure_cost --size 256 --repeat 3` (2026-12-04): per scene, each
# structure's build with its kernels loaded and the tracing CPU per ray of a 256x256 SPD
# render, best of 3, over the SPD scenes balls, gears, rings, teapot, tetra, tree, shells,
# jacks and mount_s1 and two nested_spheres scenes (200 and 800: the grid traces faster
# there); docs/measurements.md has the estimated seconds against the measured. Tracing, per
# ray: apart from its walk (making, shading, spawning), and per object tested or node or
# voxel stepped that the forecasts say a ray crossing the node meets (rays stop at their first
# hit and the camera aims at the objects, so the forecasts' counts are not the rays' own: the
# fit absorbs it: the estimates run 0.3x-1.6x of the measured tracing, the grid's build
# 0.33x-1.45x of its measured).
PER_RAY = 6.7e-8
PER_BVH_TEST = 3.6e-9
# A visit of the 4-wide hierarchy (four boxes at once; 7.5e-9 was fitted for the binary tree's
# two): set so the model's hierarchy estimates move as the measured tracing did when the tree
# became 4-wide (bench.spd, rings 0.85x, teapot 0.84x, tetra 0.88x: 1.2e-8, 1.07e-8, 1.35e-8
# by scene), not re-fitted over every scene.
PER_BVH_VISIT = 1.2e-8
PER_GRID_TEST = 3.0e-9
PER_GRID_STEP = 1.2e-8
# Building: the hierarchy per object x log2(objects); the grid per voxel of an object's span
# tested while counting or filling (every round), per reference kept and per voxel.
PER_BVH_OBJECT_LOG2 = 3.8e-8
PER_GRID_CANDIDATE = 2.8e-9
PER_GRID_REF = 1.2e-7
PER_GRID_VOXEL = 1.4e-8
# Loading the grid's build kernels from the disk cache once the hierarchy's are loaded (numba's
# start-up, about half a second, is paid by whichever kernel a process runs first).
GRID_LOAD = 0.011
# The primary rays of a render the engine is not told of: an SPD one (513 x 513 corner rays).
UNTOLD_EYE_RAYS = 513 * 513


@dataclass(frozen=True)
class GridForecast:
    """The grid `build_grid` would build over a box, forecast from the objects' boxes."""

    res: tuple[int, int, int]  # voxels per axis
    voxels: int
    refs: int  # object references (box spans: the touching voxels are fewer)
    candidates: int  # voxels the counting passes test, every round together
    tests: float  # objects tested by a ray crossing the box (each once: mailbox)
    steps: float  # voxels a ray crossing the box steps through
    bytes: int  # CSR offsets and references


def _spans(lo, hi, glo, cell, res):
    """First and last voxel (inclusive) of each object's box, as `voxelize.voxel_refs` finds
    them."""
    tol = 1e-7 * cell
    i0 = np.clip(np.floor((lo - tol - glo) / cell), 0, res - 1).astype(np.int64)
    i1 = np.clip(np.floor((hi + tol - glo) / cell), 0, res - 1).astype(np.int64)
    return i0, i1


def _span_counts(i0, i1, res) -> np.ndarray:
    """References per occupied voxel (in no order) if each object filled its box span:
    enumerated where the spans hold fewer references than the grid has voxels, else summed
    over the grid from a difference table of the spans' corners."""
    ext = i1 - i0 + 1
    size = ext.prod(axis=1)
    nx, ny, nz = (int(r) for r in res)
    if size.sum() < nx * ny * nz:
        own = np.repeat(np.arange(len(size)), size)
        k = np.arange(int(size.sum())) - np.repeat(np.cumsum(size) - size, size)
        kx, k = k % ext[own, 0], k // ext[own, 0]
        ky, kz = k % ext[own, 1], k // ext[own, 1]
        v = (i0[own, 0] + kx) + nx * ((i0[own, 1] + ky) + ny * (i0[own, 2] + kz))
        counts = np.bincount(v)
        return counts[counts > 0]
    table = np.zeros((nz + 1) * (ny + 1) * (nx + 1), np.int64)
    stop = i1 + 1
    for corner in range(8):
        x = (i0, stop)[corner & 1][:, 0]
        y = (i0, stop)[(corner >> 1) & 1][:, 1]
        z = (i0, stop)[corner >> 2][:, 2]
        sign = -1 if bin(corner).count("1") & 1 else 1
        table += sign * np.bincount(x + (nx + 1) * (y + (ny + 1) * z), minlength=len(table))
    grid = table.reshape(nz + 1, ny + 1, nx + 1)
    for axis in range(3):
        np.cumsum(grid, axis=axis, out=grid)
    return grid[:-1, :-1, :-1].reshape(-1)


def _half_area(ext) -> np.ndarray:
    """Half the surface area of boxes of sides `ext` (..., 3)."""
    x, y, z = ext[..., 0], ext[..., 1], ext[..., 2]
    return x * y + y * z + z * x


def grid_forecast(lo, hi, box_lo, box_hi, density: float, res=None) -> GridForecast:
    """The grid `build_grid` would build over [box_lo, box_hi] for objects with bounds lo, hi
    (n, 3): its rounds of resolution, each stopping as the build's stops, on box spans."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    glo, ghi = grow_box(np.asarray(box_lo, float), np.asarray(box_hi, float))
    n, target = len(lo), 4.0 / density
    fixed, boost, previous, candidates = res is not None, 1.0, None, 0
    cap = min(MAX_REFS, MAX_REFS_PER_OBJECT * max(n, 1))
    for _ in range(1 if fixed else 4):
        trial = np.asarray(res if fixed else choose_resolution(glo, ghi, n, density * boost))
        trial = trial.astype(np.int64)
        cell = (ghi - glo) / trial
        i0, i1 = _spans(lo, hi, glo, cell, trial)
        refs = int((i1 - i0 + 1).prod(axis=1).sum())
        candidates += refs  # a counting pass tests every voxel of every span
        over = previous is not None and refs > cap
        occ = math.inf if over else occupancy(_span_counts(i0, i1, trial))
        if previous is not None and (over or occ > 0.75 * previous[4]):
            trial, cell, i0, i1, occ, refs = previous
            break
        previous = (trial, cell, i0, i1, occ, refs)
        if fixed or occ <= 1.5 * target or np.prod(trial) * 2 > MAX_VOXELS:
            break
        boost *= occ / target
    trial, cell, i0, i1, occ, refs = previous
    candidates += refs  # and the filling pass once more
    voxels = int(np.prod(trial))
    area = _half_area(ghi - glo)
    # A line crossing a convex box crosses a flat piece inside it with probability twice the
    # piece's area over the box's surface (Cauchy-Crofton): so a crossing ray meets an
    # object's span with probability half-area(span) / half-area(box), and crosses
    # (n_a - 1) inner voxel walls of axis a with probability face_a / half-area(box) each.
    tests = float(_half_area((i1 - i0 + 1) * cell).sum() / area) if n else 0.0
    side = ghi - glo
    faces = np.array([side[1] * side[2], side[0] * side[2], side[0] * side[1]])
    steps = 1.0 + float(((trial - 1) * faces).sum() / area)
    return GridForecast(
        res=tuple(int(r) for r in trial),
        voxels=voxels,
        refs=refs,
        candidates=candidates,
        tests=tests,
        steps=steps,
        bytes=4 * (voxels + 1) + 4 * refs,
    )


@dataclass(frozen=True)
class Estimate:
    """One structure's expected seconds for a render, and the bytes it keeps."""

    structure: str  # "bvh" or "grid"
    load: float  # loading its build kernels (those not loaded already)
    build: float
    trace: float  # the render's expected rays, at `per_ray` each
    per_ray: float
    bytes: int
    least: bool = False  # a lower bound of the estimate (`grid_least`), not the estimate

    @property
    def total(self) -> float:
        return self.load + self.build + self.trace

    def to_dict(self) -> dict:
        """For the engine's stats."""
        return {
            "load_seconds": self.load,
            "build_seconds": self.build,
            "trace_seconds": self.trace,
            "total_seconds": self.total,
            "seconds_per_ray": self.per_ray,
            "bytes": self.bytes,
            **({"lower_bound": True} if self.least else {}),
        }


def hierarchy_estimate(objects: int, tests: float, visits: float, rays: float, nbytes: int):
    """The hierarchy's seconds for `rays` from its forecast for a crossing ray (`Bvh.stats`:
    expected tests and visits); its kernels count as loaded (choosing built it)."""
    per_ray = PER_RAY + PER_BVH_TEST * tests + PER_BVH_VISIT * visits
    build = PER_BVH_OBJECT_LOG2 * objects * math.log2(max(objects, 2))
    return Estimate("bvh", 0.0, build, rays * per_ray, per_ray, int(nbytes))


def grid_estimate(forecast: GridForecast, rays: float) -> Estimate:
    """The grid's seconds for `rays`, from its forecast (`grid_forecast`)."""
    per_ray = PER_RAY + PER_GRID_TEST * forecast.tests + PER_GRID_STEP * forecast.steps
    build = (
        PER_GRID_CANDIDATE * forecast.candidates
        + PER_GRID_REF * forecast.refs
        + PER_GRID_VOXEL * forecast.voxels
    )
    return Estimate("grid", GRID_LOAD, build, rays * per_ray, per_ray, forecast.bytes)


def grid_least(lo, hi, box_lo, box_hi, rays: float) -> Estimate:
    """A lower bound of `grid_estimate(grid_forecast(...), rays)` at any resolution, from
    the objects' boxes alone: every object one reference at least (counted, then filled),
    one voxel, one step a crossing ray, and the tests of spans no larger than the objects'
    boxes within the grid's (a span holds its object's part inside the grid). Where the
    hierarchy's whole estimate is under it, the grid cannot win and is not forecast: the
    forecast's counts over the grid took 30% of an engine's build in the cost pre-pass's
    simulations (gears 4x4), and the hierarchy came out 12-44 times cheaper on the SPD
    scenes' cells."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    glo, ghi = grow_box(np.asarray(box_lo, float), np.asarray(box_hi, float))
    n = len(lo)
    inside = _half_area(np.clip(hi, glo, ghi) - np.clip(lo, glo, ghi))
    # (1 - 1e-9: the spans' sides are sums of voxel sides, rounded)
    tests = float(inside.sum() / _half_area(ghi - glo)) * (1 - 1e-9) if n else 0.0
    per_ray = PER_RAY + PER_GRID_TEST * tests + PER_GRID_STEP
    build = (2 * PER_GRID_CANDIDATE + PER_GRID_REF) * n + PER_GRID_VOXEL
    return Estimate("grid", GRID_LOAD, build, rays * per_ray, per_ray, 4 * (2 + n), least=True)


NAMES = {"bvh": "hierarchy", "grid": "grid"}


def choose(estimates: list[Estimate], rays: float) -> tuple[Estimate, str]:
    """Of two estimates, the one of smaller total (the first on a tie), and why, with both."""
    chosen = min(estimates, key=lambda e: e.total)
    other = next(e for e in estimates if e is not chosen)
    each = "; ".join(
        f"{NAMES[e.structure]} {e.load + e.build:.3g} s to build + {e.trace:.3g} s to trace"
        f" = {e.total:.3g} s ({e.bytes / 1e6:.3g} MB)"
        for e in estimates
    )
    name, saves = NAMES[chosen.structure], chosen.load + chosen.build - other.load - other.build
    if chosen.per_ray <= other.per_ray and saves <= 0:
        why = f"the {name} builds and traces sooner"
    elif saves <= 0:  # builds sooner, traces slower
        pays = -saves / (chosen.per_ray - other.per_ray)
        why = f"the {name} builds sooner; the other's faster tracing pays back from {pays:.3g} rays"
    elif chosen.per_ray < other.per_ray:
        pays = saves / (other.per_ray - chosen.per_ray)
        why = f"the {name} traces faster, which pays back its build from {pays:.3g} rays"
    else:  # a tie, the first taken
        why = f"the {name} is expected as soon"
    return chosen, f"expected for {rays:.3g} rays: {each}: {why}"


def expected_rays(scene: SceneData, eye_rays: float, depth: int) -> float:
    """The rays a render of `eye_rays` primary rays traces through `scene`, bounded: each eye
    ray taken to hit and send a shadow ray per light, a reflected ray if any material reflects
    or transmits and a refracted ray if any transmits (when depth > 1); deeper generations and
    eye rays that miss are left out. On the SPD scenes the rays traced are 0.55 (shells) to
    1.44 (gears) times this (tetra 0.59, tree 0.65, teapot 0.85, balls 1.06, rings 1.26)."""
    m = scene.materials
    transmits = bool(len(m) and (m["t"] > 0).any())
    reflects = transmits or bool(len(m) and (m["ks"] > 0).any())
    secondary = (reflects + transmits) if depth > 1 else 0
    return float(eye_rays) * (1 + len(scene.lights) + secondary)


def eye_ray_count(image: ImageSpec, camera: bool = False) -> int:
    """Primary rays of a sized image: its sample grid (pixel corners under the SPD rules) x
    rays per pixel (through a camera at most that many: adaptive sampling may trace fewer)."""
    width, height = image.sample_grid(camera)
    return width * height * image.spp
