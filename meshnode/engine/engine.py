"""The Python-facing engine: holds one node's tables and grid, checks inputs, calls kernels.

from host.scene.nff import read_nff
from meshnode.engine import Engine
engine = Engine(read_nff("scene.nff"))
t, gid = engine.first_hits(origins, directions)      # nearest hit per ray
blocked = engine.occluded(origins, directions, t_max)  # anything before t_max
rgb, counts = engine.trace(rays)                     # Whitted colour per RAY record
"""

import math
import time
from contextlib import nullcontext

import numpy as np

from meshnode.engine import kernelcache, queries
from meshnode.engine.bound import Bound, array_key
from meshnode.engine.counters import COUNTER_NAMES, N_COUNTERS
from meshnode.engine.grid import box_only
from meshnode.engine.heap import keep_freed_memory
from meshnode.engine.lightmaps import NO_LIGHT_MAPS, light_maps
from meshnode.engine.locator import cell_locator
from meshnode.engine.occupancy import everywhere, map_stats, occupancy_arrays
from meshnode.engine.packet import PACKET
from meshnode.engine.quads import quads_as_triangles
from meshnode.engine.routing import routed
from meshnode.engine.sightlines import NO_EYE_MAP
from meshnode.engine.structure import build_structure, foreseen
from meshnode.engine.structure import stand_in as stand_in_structure
from meshnode.engine.structure_cost import UNTOLD_EYE_RAYS, expected_rays
from meshnode.engine.tables import MAT_TRANSMIT, Shading, build_tables
from meshnode.engine.trace import trace_batch
from meshnode.engine.variants import KERNELS, variant_of
from protocols.dtypes import RAY
from protocols.render import SPD_DEPTH, EngineSpec
from protocols.scene import SCENE_TABLES, SceneData
from protocols.spec import default


class Engine:
    """One node's tracing engine, specialised to the objects, materials and lights it holds.

    Absent primitive kinds, lights and transmitters are passed to the kernels as None, so the
    compiled variant carries no code for them, and so is the structure not walked (the grid's
    arrays beside a hierarchy, the hierarchy's beside a grid); `stats` says what was chosen
    and why. `brute=True` tests every object against every ray (no walk; the grid's variant,
    whose box bounds the rays): the reference for tests."""

    def __init__(
        self,
        scene: SceneData,
        *,
        density: float = default(EngineSpec, "density"),
        storage: str = default(EngineSpec, "storage"),
        structure: str = default(EngineSpec, "structure"),
        resolution=None,
        max_depth: int = SPD_DEPTH,
        brute: bool = False,
        box: tuple | None = None,
        scene_box: tuple | None = None,
        announce=None,
        packets: bool = True,
        occupancy: tuple | None = None,
        eye_rays_expected: float | None = None,
        stand_in: bool = False,
    ):
        """`announce(variant name)` is called, before anything compiles, when this variant's
        kernels are not in the disk cache yet (building the grid compiles some of them).
        `packets=False`: every ray walks alone (the reference packets are tested against).
        `occupancy` (voxels per axis, packed bits): the scene's occupancy map over
        `scene_box` (`Partition.occ_res`, `occ_bits`), so a mesh node ends or skips segments
        with only empty space ahead; None: nothing skipped. `eye_rays_expected`: the primary
        rays this engine is expected to take on in the render (a mesh node's share of them),
        with which an "auto" structure is chosen for the rays they bring
        (`structure_cost.expected_rays`); None: an SPD render's. `stand_in`: the structure
        ("grid" or "bvh", not "auto") holds no objects and is made without its build
        kernels (`structure.stand_in`): an engine that only compiles its tracing kernels, as
        `meshnode warmup --variant` does beside a first render; it finds no hit."""
        start = time.perf_counter()
        keep_freed_memory()  # batches reuse freed memory instead of faulting in new pages
        self.scene = scene
        self.brute = bool(brute)
        self.tables = tb = build_tables(quads_as_triangles(scene))  # rows: not the scene's
        objects = tb.objects  # before renumbering: scenes list their ids in order
        asked = "grid" if self.brute else structure
        # The tracing kernel's variant depends on the structure, known before it is built but
        # where "auto" chooses the grid: announced again then (`host.run.aside` restarts).
        announced = self._announce(announce, variant_of(tb, foreseen(asked, resolution)))
        if box is not None:
            lo, hi = (np.asarray(b, float) for b in box)
        elif tb.n:
            # column by column: numpy reduces an (n, 3) array across rows 10x slower
            lo = np.array([tb.lo[:, a].min() for a in range(3)])
            hi = np.array([tb.hi[:, a].max() for a in range(3)])
        else:
            lo, hi = np.zeros(3), np.ones(3)
        eye = UNTOLD_EYE_RAYS if eye_rays_expected is None else eye_rays_expected
        self.rays_expected = expected_rays(scene, eye, max_depth)
        # (brute force builds the grid as before: its box bounds the rays)
        if stand_in:
            built = stand_in_structure(tb, (lo, hi), foreseen(asked, resolution))
        else:
            built = build_structure(
                tb,
                (lo, hi),
                asked=asked,
                resolution=resolution,
                density=density,
                storage=storage,
                rays=self.rays_expected,
            )
        self.bvh = built.bvh
        self.structure = "bvh" if self.bvh is not None else "grid"
        # the structure not walked is passed as None: its walk is compiled out
        if self.bvh is not None:
            self.tables = tb = tb.permuted(self.bvh.order)  # leaves become runs of ids
            self.grid = box_only(lo, hi)
            self.bvh_arrays, self.grid_arrays = self.bvh.arrays(), None
        else:
            self.grid = built.grid
            self.bvh_arrays, self.grid_arrays = None, self.grid.arrays()
        self.kernel_variant = variant_of(tb, self.structure)
        if self.kernel_variant != announced:
            self._announce(announce, self.kernel_variant)
        # the node's box, as the tracing kernel reads it: the grid's, or a one-voxel grid's
        self.box = (self.grid.lo, self.grid.cell, self.grid.res)
        # A mesh node's box is part of the scene's; rays leaving it inside the scene go on.
        sb = (self.grid.lo, self.grid.hi) if scene_box is None else scene_box
        self.scene_lo, self.scene_hi = (np.asarray(b, float) for b in sb)
        # A box holding the whole scene (image space, one node) has no segment to pass on,
        # so `trace_node` traces with the one-node kernel: it skips the box and occupancy
        # spans every segment pays on an object-space node (bench.node_kernel: 1.06-1.23x).
        # (Neither box given: one node, all objects. A node's box: it holds the objects
        # touching it, so all of them when it covers the scene's; the kernel's is it padded.)
        whole = box is None and scene_box is None
        covers = bool(np.all(lo <= self.scene_lo) and np.all(hi >= self.scene_hi))
        self.holds_scene = whole or covers
        self.occupancy = (
            everywhere(self.scene_lo, self.scene_hi)
            if occupancy is None
            else occupancy_arrays(self.scene_lo, self.scene_hi, *occupancy)
        )
        # the map seen from each light: shadow rays leaving the box walk it less
        self.light_near = (
            NO_LIGHT_MAPS
            if occupancy is None or self.holds_scene
            else light_maps(self.occupancy, self.tables.lights)
        )
        # A batch's own rays walk a hierarchy in packets, on object-space nodes too: eye rays
        # are made where they enter the node's cell, and rays passed on arrive in the order
        # they left a neighbour (tetra 3x3, one node's batches traced again: 7-16% less CPU;
        # `keep_packets` goes back to single rays where packets stop paying).
        self.packets = bool(packets)
        # From the scene's box, not this node's: every node must use the same guard, or a hit
        # at a tiny t (touching spheres) would count on one node and not on another.
        extent = float(np.max(self.scene_hi - self.scene_lo))
        scale = max(extent, float(np.max(np.abs(np.concatenate([self.scene_lo, self.scene_hi])))))
        # Secondary rays exclude their own surface; this guard only absorbs round-off.
        t_eps = 1e-12 * scale
        n_lights = 0 if tb.lights is None else len(tb.lights)
        ambient = math.sqrt(max(n_lights, 1)) / (2.0 * max(n_lights, 1))
        self.shading = Shading(
            mat=tb.mat,
            materials=tb.materials,
            tri_n=tb.tri_normals,
            ambient=ambient,
            background=np.asarray(scene.background, float),
            max_depth=int(max_depth),
            t_eps=t_eps,
        )
        self.transmit = (
            np.ascontiguousarray(tb.materials[:, MAT_TRANSMIT]) if tb.transmitters else None
        )
        self.geometry = tb.geometry()
        self._trace_batch = Bound(trace_batch)  # this engine's tables: the same every call
        self.preprocess_seconds = time.perf_counter() - start
        self.stats = {
            "objects": objects,
            "kinds_present": list(tb.kinds),
            "kernel_variant": self.variant(),
            "variant_reason": (
                "kinds, shadow rays and refraction compiled in only when the node holds "
                "objects of that kind, lights, or transmitting materials"
            ),
            "structure": self.structure,
            "structure_reason": (
                "brute force: every object against every ray" if self.brute else built.reason
            ),
            # each structure's expected seconds (load, build, trace, total) and bytes for
            # this render's expected rays, when "auto" chose by them
            "structure_estimates": built.estimates,
            "rays_expected": self.rays_expected,
            # the build kernels loaded (or compiled), and the build (in "auto", a hierarchy's too)
            "structure_load_seconds": built.load_seconds,
            "structure_build_seconds": built.build_seconds,
            "grid": self.grid.stats,
            "bvh": None if self.bvh is None else self.bvh.stats,
            "packet": PACKET if self.bvh is not None and self.packets else 1,
            "packet_reason": (
                "the grid walks each ray alone"
                if self.bvh is None
                else f"a batch's own rays walk the hierarchy {PACKET} neighbours together"
                if self.packets
                else "asked for single rays"
            ),
            "structure_bytes": (self.bvh.stats if self.bvh else self.grid.stats)["structure_bytes"],
            "occupancy": map_stats(self.occupancy),
            "preprocess_seconds": self.preprocess_seconds,
        }
        self.stats["engine_bytes"] = self.nbytes()

    @staticmethod
    def _announce(announce, variant):
        """`announce(variant's name)` if given and the variant is not in the disk cache; the
        variant either way."""
        if announce is not None and not kernelcache.is_warm(variant.name):
            announce(variant.name)
        return variant

    def nbytes(self) -> int:
        """Bytes of every array this engine keeps (its tables, structure, occupancy map and
        the records it was built from): what a node's memory budget bounds
        (`MeshPlan.node_bytes`)."""
        seen: dict[int, int] = {}
        parts = (
            self.tables.__dict__.values(),
            self.geometry,
            self.shading,
            self.grid_arrays or (),
            self.bvh_arrays or (),
            self.occupancy,
            (getattr(self.scene, k) for k in SCENE_TABLES),
        )
        for part in parts:
            for a in part:
                while isinstance(a, np.ndarray) and isinstance(a.base, np.ndarray):
                    a = a.base  # a view (the hierarchy's references) counts as its array
                if isinstance(a, np.ndarray):
                    seen[id(a)] = a.nbytes  # an array shared by two parts counts once
        return int(sum(seen.values()))

    @classmethod
    def from_spec(
        cls, scene: SceneData, spec: EngineSpec, *, max_depth: int = SPD_DEPTH, **placement
    ) -> "Engine":
        """The engine `spec` describes, over `scene`: the one place an EngineSpec becomes an
        engine, so no caller can drop one of its fields (`threads` is the caller's: how many
        threads run it). `placement`: box, scene_box, occupancy, announce, packets,
        eye_rays_expected."""
        return cls(
            scene,
            density=spec.density,
            storage=spec.storage,
            structure=spec.structure,
            brute=spec.brute,
            max_depth=max_depth,
            **placement,
        )

    def variant(self) -> str:
        """Name of the compiled variant, e.g. 'spheres+polygons/flat/shadows/no-refraction/csr'."""
        storage = "brute-force" if self.brute else ("bvh" if self.bvh else self.grid.storage)
        return f"{self.kernel_variant.name.rsplit('/', 1)[0]}/{storage}"

    @property
    def runs(self) -> tuple[str, ...]:
        """The one tracing kernel of `KERNELS` this engine runs (`trace_node` picks it): one
        node's where its box holds the whole scene, else a mesh node's."""
        return ("trace",) if self.holds_scene else ("passing",)

    @property
    def compiled(self) -> bool:
        """Whether the kernels this engine runs are in the disk cache already (a warmup marked
        them), so `warmup` loads instead of compiling: callers say so on a first run."""
        return self._warm(self.runs)

    def _warm(self, kernels) -> bool:
        """Whether each of `kernels` of this variant was marked warm in the disk cache."""
        return all(kernelcache.is_warm(self._mark(k)) for k in kernels)

    def _mark(self, kernel: str) -> str:
        return f"{self.kernel_variant.name}/{kernel}"

    def warmup(self, kernels=None) -> float:
        """Compile (or load from the disk cache) kernels of this variant on a one-ray batch, so
        tracing time excludes compilation; returns the seconds. `kernels`: names from
        `KERNELS`; default `runs`, the one this engine traces with. Each is a numba
        specialisation of tens of seconds cold (a variant's three took 37 s, a mesh node
        runs one), so a node, the probe and one node each compile only their own."""
        start = time.perf_counter()
        kernels = self.runs if kernels is None else tuple(kernels)
        unknown = set(kernels) - set(KERNELS)
        if unknown:
            raise ValueError(f"unknown kernels {sorted(unknown)}: choose from {KERNELS}")
        cold = not self._warm(kernels)
        with kernelcache.compiling(self.kernel_variant.name) if cold else nullcontext():
            self._run_once(kernels)
        self.stats["kernel_load_seconds"] = seconds = time.perf_counter() - start
        return seconds

    def _run_once(self, kernels) -> None:
        """Each of `kernels` on a one-ray batch (compiled or loaded on first use), marked warm."""
        ray = np.zeros(1, RAY)
        ray["d"] = (0.0, 0.0, 1.0)
        ray["t_max"] = math.inf
        ray["origin"] = -1
        ray["depth"] = 1
        if "trace" in kernels:
            self.trace(ray)
        if "passing" in kernels:
            self.trace_passing(ray)
        if "probe" in kernels:
            self.first_hits(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
        kernelcache.mark_warm(self.kernel_variant.name)
        for k in kernels:
            kernelcache.mark_warm(self._mark(k))

    def routed(self, rays: np.ndarray, cells, skip: bool, fallback: int = -1, eye=NO_EYE_MAP):
        """(rays regrouped by the cell that takes each on, runs' starts, rays no cell takes)
        for `cells` = (los, his), with `skip` from where each ray's work starts on the
        scene's occupancy map (`meshnode.engine.routing.routed`), seen from the eye for
        pinhole eye rays (`eye`, an `EyeMap`); `rays` stay as they were."""
        los, his, box = *cells, (self.scene_lo, self.scene_hi)
        locator = cell_locator(los, his)
        return routed(rays, skip, fallback, *box, self.occupancy, los, his, locator, eye)

    def first_hits(self, origins, directions, t_min: float = 0.0):
        """Nearest hit per ray: distance (inf on a miss) and scene object id (-1 on a miss).

        Directions are normalised here, so distances are in scene units."""
        return queries.first_hits(self, origins, directions, t_min)

    def occluded(self, origins, directions, t_max, leaving=None, t_min: float = 0.0):
        """Whether some object lies on each ray in (t_min, t_max) (scene units: directions
        are normalised): a shadow ray's question, stopping at the first object found; bool
        per ray. `leaving`: the scene id of the object each ray leaves (-1, or None: none),
        skipped as the renderer's shadow rays skip their own surface."""
        return queries.occluded(self, origins, directions, t_max, leaving, t_min)

    def trace(self, rays: np.ndarray, out_rgb: np.ndarray | None = None):
        """Trace RAY records and all their descendants; returns (rgb per ray, counter dict)."""
        rgb, counts, _ = self._trace(rays, out_rgb, None)
        return rgb, counts

    def trace_node(self, rays: np.ndarray):
        """As a mesh node: returns (rgb per ray, counter dict, rays continuing elsewhere:
        none when this node's box holds the whole scene)."""
        if self.holds_scene:
            rgb, counts, _ = self._trace(rays, None, None)
            return rgb, counts, rays[:0]
        return self.trace_passing(rays)

    def trace_passing(self, rays: np.ndarray):
        """`trace_node` with the mesh kernel whatever the box (segments clipped to it, those
        leaving it returned): what an object-space node always runs."""
        return self._trace(rays, None, np.empty(max(16, len(rays) // 4), RAY))

    def _trace(self, rays, out_rgb, out):
        if rays.dtype != RAY:
            raise TypeError(f"rays must have dtype protocols.dtypes.RAY, not {rays.dtype}")
        if out_rgb is None:
            out_rgb = np.zeros((len(rays), 3))
        counters = np.zeros(N_COUNTERS, np.int64)
        rays = np.ascontiguousarray(rays)
        key = (array_key(rays), array_key(out_rgb), out is None)  # counters, out: made here
        out, n_out = self._trace_batch(
            key,
            rays,
            out_rgb,
            counters,
            self.brute,
            self.geometry,
            self.grid_arrays,
            self.shading,
            self.transmit,
            self.tables.lights,
            # new arguments go last: numba code for this kernel ran 2x slower on tetra with two
            # more arrays early in the list (code layout), so keep the hot ones first (tetra:
            # 2-4% slower with the shading table ahead of the geometry and grid)
            self.scene_lo,
            self.scene_hi,
            out,
            self.bvh_arrays,
            self.packets,
            self.occupancy,
            self.box,
            self.light_near,
        )
        # a view, not a copy: copying records costs ~10 us a call, and the buffer was made
        # for this call alone (callers route the passed rays into new arrays at once)
        passed = None if out is None else out[:n_out]
        return out_rgb, dict(zip(COUNTER_NAMES, counters.tolist(), strict=True)), passed
