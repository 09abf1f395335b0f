"""The Python-facing engine: holds one node's tables and grid, checks inputs, calls kernels.

    from host.nff import read_nff
    from meshnode.engine import Engine
    engine = Engine(read_nff("scene.nff"))
    t, gid = engine.first_hits(origins, directions)      # nearest hit per ray
    rgb, counts = engine.trace(rays)                     # Whitted colour per RAY record
"""

import itertools
import math
import time
from typing import NamedTuple

import numpy as np

from meshnode.engine import kernelcache
from meshnode.engine.counters import COUNTER_NAMES, N_COUNTERS
from meshnode.engine.grid import build_grid
from meshnode.engine.tables import MAT_TRANSMIT, Shading, Tables, build_tables
from meshnode.engine.trace import first_hits, trace_batch
from protocols.dtypes import RAY
from protocols.render import SPD_DEPTH, EngineSpec
from protocols.scene import SceneData
from protocols.spec import default

# Primitive kinds in local-id order, as `build_tables` names them in `Tables.kinds` (kept here:
# a change in tables.py, which kernels import, empties everyone's kernel cache).
KINDS = ("spheres", "triangles", "polygons", "cones")


class Variant(NamedTuple):
    """What one compiled variant of the kernels holds code for: numba compiles a kernel once
    per combination of argument types, and an absent kind, lights or transmitters is None.
    (Grid storage and brute force are values, not types: they share a variant.)"""

    kinds: tuple[str, ...]  # primitive kinds present, in KINDS order
    smooth: bool  # some triangle has vertex normals
    shadows: bool  # there are lights
    refraction: bool  # some object transmits

    @property
    def name(self) -> str:
        return "/".join(["+".join(self.kinds) or "empty",
                         "smooth" if self.smooth else "flat",
                         "shadows" if self.shadows else "no-shadows",
                         "refraction" if self.refraction else "no-refraction"])  # fmt: skip


def variant_of(tables: Tables) -> Variant:
    """The variant the engine compiles for these tables: the engine's one choice function."""
    return Variant(tuple(tables.kinds), tables.tri_normals is not None,
                   tables.lights is not None, bool(tables.transmitters))  # fmt: skip


def all_variants() -> list[Variant]:
    """Every variant `variant_of` can choose: any set of kinds, smooth only with triangles,
    refraction only with some object; lights or not (what `meshnode warmup` compiles)."""
    out = []
    for n in range(len(KINDS) + 1):
        for kinds in itertools.combinations(KINDS, n):
            for smooth, shadows, refraction in itertools.product((False, True), repeat=3):
                if (smooth and "triangles" not in kinds) or (refraction and not kinds):
                    continue
                out.append(Variant(kinds, smooth, shadows, refraction))
    return out


class Engine:
    """One node's tracing engine, specialised to the objects, materials and lights it holds.

    Absent primitive kinds, lights and transmitters are passed to the kernels as None, so the
    compiled variant carries no code for them; `stats` says what was chosen and why.
    `brute=True` tests every object against every ray (no grid): the reference for tests."""

    def __init__(
        self,
        scene: SceneData,
        *,
        density: float = default(EngineSpec, "density"),
        storage: str = default(EngineSpec, "storage"),
        resolution=None,
        max_depth: int = SPD_DEPTH,
        brute: bool = False,
        box: tuple | None = None,
        scene_box: tuple | None = None,
        announce=None,
    ):
        """`announce(variant name)` is called, before anything compiles, when this variant's
        kernels are not in the disk cache yet (building the grid compiles some of them)."""
        start = time.perf_counter()
        self.scene = scene
        self.brute = bool(brute)
        self.tables = tb = build_tables(scene)
        if announce is not None and not kernelcache.is_warm(variant_of(tb).name):
            announce(variant_of(tb).name)
        if box is not None:
            lo, hi = (np.asarray(b, float) for b in box)
        elif tb.n:
            lo, hi = tb.lo.min(axis=0), tb.hi.max(axis=0)
        else:
            lo, hi = np.zeros(3), np.ones(3)
        self.grid = build_grid(tb, lo, hi, density=density, storage=storage, res=resolution)
        # A mesh node's box is part of the scene's; rays leaving it inside the scene go on.
        sb = (self.grid.lo, self.grid.hi) if scene_box is None else scene_box
        self.scene_lo, self.scene_hi = (np.asarray(b, float) for b in sb)
        # From the scene's box, not this node's: every node must use the same guard, or a hit
        # at a tiny t (touching spheres) would count on one node and not on another.
        extent = float(np.max(self.scene_hi - self.scene_lo))
        scale = max(extent, float(np.max(np.abs(np.concatenate([self.scene_lo, self.scene_hi])))))
        # Secondary rays exclude their own surface; this guard only absorbs round-off.
        t_eps = 1e-12 * scale
        n_lights = 0 if tb.lights is None else len(tb.lights)
        ambient = math.sqrt(max(n_lights, 1)) / (2.0 * max(n_lights, 1))
        self.shading = Shading(
            mat=tb.mat, materials=tb.materials, tri_n=tb.tri_normals, ambient=ambient,
            background=np.asarray(scene.background, float), max_depth=int(max_depth), t_eps=t_eps,
        )  # fmt: skip
        self.transmit = (
            np.ascontiguousarray(tb.materials[:, MAT_TRANSMIT]) if tb.transmitters else None
        )
        self.geometry = tb.geometry()
        self.grid_arrays = self.grid.arrays()
        self.preprocess_seconds = time.perf_counter() - start
        self.stats = {
            "objects": int(len(np.unique(tb.gid))),
            "kinds_present": list(tb.kinds),
            "kernel_variant": self.variant(),
            "variant_reason": (
                "kinds, shadow rays and refraction compiled in only when the node holds "
                "objects of that kind, lights, or transmitting materials"
            ),
            "grid": self.grid.stats,
            "preprocess_seconds": self.preprocess_seconds,
        }

    def variant(self) -> str:
        """Name of the compiled variant, e.g. 'spheres+polygons/flat/shadows/no-refraction/csr'."""
        storage = "brute-force" if self.brute else self.grid.storage
        return f"{variant_of(self.tables).name}/{storage}"

    @property
    def compiled(self) -> bool:
        """Whether this variant's kernels are in the disk cache already (a warmup marked
        them), so `warmup` loads instead of compiling: callers say so on a first run."""
        return kernelcache.is_warm(variant_of(self.tables).name)

    def warmup(self) -> float:
        """Compile (or load from the disk cache) this variant's kernels, single-node and mesh
        node, on a one-ray batch, so tracing time excludes compilation; returns the seconds."""
        start = time.perf_counter()
        ray = np.zeros(1, RAY)
        ray["d"] = (0.0, 0.0, 1.0)
        ray["t_max"] = math.inf
        ray["origin"] = -1
        ray["depth"] = 1
        self.trace(ray)
        self.trace_node(ray)
        self.first_hits(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
        kernelcache.mark_warm(variant_of(self.tables).name)
        self.stats["kernel_load_seconds"] = seconds = time.perf_counter() - start
        return seconds

    def first_hits(self, origins, directions, t_min: float = 0.0):
        """Nearest hit per ray: distance (inf on a miss) and scene object id (-1 on a miss).

        Directions are normalised here, so distances are in scene units."""
        o = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
        d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
        if o.shape != d.shape:
            raise ValueError(f"origins {o.shape} and directions {d.shape} differ in shape")
        norm = np.linalg.norm(d, axis=1)
        if np.any(norm == 0) or not np.all(np.isfinite(d)) or not np.all(np.isfinite(o)):
            raise ValueError("directions must be finite and non-zero; origins finite")
        d = d / norm[:, None]
        counters = np.zeros(N_COUNTERS, np.int64)
        t, u = first_hits(o, d, float(t_min), self.brute, counters, self.geometry,
                          self.grid_arrays)  # fmt: skip
        gid = np.full(len(u), -1, np.int64)
        gid[u >= 0] = self.tables.gid[u[u >= 0]]
        return t, gid

    def trace(self, rays: np.ndarray, out_rgb: np.ndarray | None = None):
        """Trace RAY records and all their descendants; returns (rgb per ray, counter dict)."""
        rgb, counts, _ = self._trace(rays, out_rgb, None)
        return rgb, counts

    def trace_node(self, rays: np.ndarray):
        """As a mesh node: returns (rgb per ray, counter dict, rays continuing elsewhere)."""
        return self._trace(rays, None, np.empty(max(16, len(rays) // 4), RAY))

    def _trace(self, rays, out_rgb, out):
        if rays.dtype != RAY:
            raise TypeError(f"rays must have dtype protocols.dtypes.RAY, not {rays.dtype}")
        if out_rgb is None:
            out_rgb = np.zeros((len(rays), 3))
        counters = np.zeros(N_COUNTERS, np.int64)
        out, n_out = trace_batch(
            np.ascontiguousarray(rays), out_rgb, counters, self.brute, self.geometry,
            self.grid_arrays, self.shading, self.transmit, self.tables.lights,
            # new arguments go last: numba code for this kernel ran 2x slower on tetra with two
            # more arrays early in the list (code layout), so keep the hot ones first (tetra:
            # 2-4% slower with the shading table ahead of the geometry and grid)
            self.scene_lo, self.scene_hi, out,
        )  # fmt: skip
        passed = None if out is None else out[:n_out].copy()
        return out_rgb, dict(zip(COUNTER_NAMES, counters.tolist(), strict=True)), passed
