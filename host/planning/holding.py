"""What each node holds and whether it fits: the overlap its box is grown by (`--overlap auto`
chooses among candidates within the nodes' memory), whether it gets the occupancy map, and the
memory an engine takes. A wider overlap keeps rays longer on a node at the price of objects
held twice, so the choice is simulated, never guessed.
"""

from dataclasses import replace

import numpy as np

from host.scene.derived import kept, scene_tables
from protocols.render import RenderSpec
from protocols.scene import OBJECT_KINDS, SCENE_TABLES, SceneData

FITS = 0.25  # the share of a node's memory its engine may take (image space when the whole
# scene's does; `--overlap auto` picks among the overlaps whose largest node's does)
OVERLAPS = (2.0, 30.0, 60.0, 100.0)  # `--overlap auto`'s candidates, percent

# A hierarchy's 128-byte 4-wide nodes: fewer than 2/3 of its leaves (a node has at least two
# children and only a node of four has inner ones), so fewer than 2/3 of its objects.
HIERARCHY_BYTES_PER_OBJECT = 86
ENGINE_FIXED_BYTES = 4096  # an engine's small arrays (boxes, offsets, the map's corners)


def engine_bytes(scene: SceneData) -> int:
    """An engine's memory (`Engine.nbytes`) over these objects, before anything is built:
    the records, the kernels' tables built from them, and a hierarchy's nodes at most (a
    node under a byte budget builds the hierarchy: `MeshPlan.node_bytes`)."""
    tables = scene_tables(scene)
    own = sum(a.nbytes for a in vars(tables).values() if isinstance(a, np.ndarray))
    records = sum(getattr(scene, t).nbytes for t in SCENE_TABLES)
    return int(own + records + HIERARCHY_BYTES_PER_OBJECT * tables.n + ENGINE_FIXED_BYTES)


def held_bytes(scene: SceneData, held: np.ndarray) -> int:
    """`engine_bytes(subset(scene, held))` without the subset or its tables: each object's
    share of the records and tables, summed over those `held` (a mask over the scene's
    objects), counted once per scene (`_Shares`). A plan counts the cells for its budget,
    its copies and its growth, and built every cell's tables for each count (gears 4x4
    under 0.15: 3 ms a cell, its polygons' band tables)."""
    return kept(scene, "held bytes", lambda: _Shares(scene))(held)


class _Shares:
    """Bytes an engine keeps for each object of a scene (`engine_bytes`' parts), and what
    depends on the objects held together: vertex normals for every triangle where any is
    smooth, and the band table's end where any polygon has bands."""

    def __init__(self, scene: SceneData):
        tb = scene_tables(scene)
        each = np.full(tb.n, 2 * 4 + 2 * 24 + HIERARCHY_BYTES_PER_OBJECT, np.int64)  # ids, bounds
        self.at = at = tb.offsets
        kinds = zip(OBJECT_KINDS, (tb.spheres, tb.triangles, tb.polygons, tb.cones), strict=True)
        for k, (kind, rows) in enumerate(kinds):
            record = getattr(scene, kind).dtype.itemsize
            row = 0 if rows is None else rows.itemsize * rows.shape[1]
            each[at[k] : at[k + 1]] += row + record
        self.smooth = scene.triangles["smooth"] != 0  # per triangle
        self.banded = np.zeros(0, bool)  # per polygon
        if tb.poly_info is not None:
            first, count, bands = tb.poly_info[:, 4], tb.poly_info[:, 1], tb.poly_info[:, 5]
            listed = np.zeros(len(count), np.int64)
            if tb.poly_bands is not None and bands.any():
                ends = tb.poly_bands
                listed = np.where(bands > 0, ends[first + bands] - ends[first], 0)
            vertex = scene.vertices.itemsize * scene.vertices.shape[-1]
            uv = tb.poly_uv.itemsize * 2
            each[at[2] : at[3]] += tb.poly_info.itemsize * 6 + count * (uv + vertex)
            each[at[2] : at[3]] += 8 * (bands + listed)
            self.banded = bands > 0
        self.each = each
        self.normal = 0 if tb.triangles is None else tb.triangles.itemsize * 9
        fixed = (tb.offsets, tb.materials, tb.lights, scene.materials, scene.lights)
        self.fixed = sum(0 if a is None else a.nbytes for a in fixed) + ENGINE_FIXED_BYTES

    def __call__(self, held: np.ndarray) -> int:
        at = self.at
        triangles, polygons = held[at[1] : at[2]], held[at[2] : at[3]]
        total = self.fixed + int(self.each[held].sum())
        if (triangles & self.smooth).any():
            total += self.normal * int(np.count_nonzero(triangles))
        return total + 8 * bool((polygons & self.banded).any())


def largest_engine(scene, spec: RenderSpec, xs, ys, cells=None) -> int:
    """Bytes of the largest node's engines with these cuts (`engine_bytes`): its own, and
    under MeshPlan.copies its linked neighbours' too."""
    from host.planning.prepass import coarse_mesh  # the mesh simulator: planning a mesh only

    own = [engine_bytes(s) for s in coarse_mesh(scene, spec, xs, ys, cells)[2]]
    return max(sum(own[m] for m in spec.plan.held(n)) for n in range(spec.plan.nodes))


def choose_holding(
    scene, spec: RenderSpec, xs, ys, cells, busiest: float, overlaps=(), memory: int = 0
) -> tuple[float, bool, dict]:
    """(overlap, occupancy map, report) for the nodes on these cuts, whose busiest node
    simulates at `busiest` with the plan's overlap and the map: the plan's overlap, or
    of `overlaps` (with the plan's) the one whose busiest node simulates least among
    those whose largest node's engine takes at most FITS of `memory` (0: not known, every
    overlap); with the map or without, whichever lightens the busiest node (the map's walk
    costs, in a fractal of many small empty cubes, more than the passes it saves). Each
    simulation asks the pre-pass's allowance (`host.planning.allowance`): an overlap it
    refuses is not tried, a map not weighed against none is kept."""
    from host.planning.prepass import allowance, node_costs  # the simulator: planning only

    plan, allowed = spec.plan, allowance()
    tried, too_big = {}, []
    for overlap in sorted({plan.overlap, *overlaps}):
        at = at_overlap(spec, overlap)
        if overlap != plan.overlap and (
            too_big_for_memory(scene, at, xs, ys, cells, memory, too_big)
            or not allowed.affords(f"overlap {overlap:g}")
        ):
            continue
        with_map = (
            busiest if overlap == plan.overlap else node_costs(scene, at, xs, ys, cells).max()
        )
        tried[overlap, True] = float(with_map)
        if allowed.affords(f"overlap {overlap:g} without the occupancy map"):
            tried[overlap, False] = float(node_costs(scene, at, xs, ys, cells, False).max())
    # ties: the smaller overlap (less held), then the map (fewer rays passed)
    (overlap, occupancy), _ = min(tried.items(), key=lambda t: (t[1], t[0][0], not t[0][1]))
    without = tried.get((overlap, False), tried[overlap, True])  # not simulated: the same
    report = {
        "occupancy_map": occupancy,
        "simulated_busiest_without_map_vs_with": ratio(without, tried[overlap, True]),
    }
    if overlaps:
        report["overlap"] = overlap_report(
            overlap, {o: b for (o, m), b in tried.items() if m == occupancy}, too_big, memory
        )
    return overlap, occupancy, report


def at_overlap(spec: RenderSpec, overlap: float) -> RenderSpec:
    """The render with its plan at `overlap`: each candidate is simulated as a render."""
    return replace(spec, plan=replace(spec.plan, overlap=overlap))


def too_big_for_memory(scene, spec: RenderSpec, xs, ys, cells, memory: int, refused: list) -> bool:
    """Whether the largest node's engine would take more than FITS of `memory` (noted in
    `refused`); never when the memory is not known (0)."""
    if not memory:
        return False
    held = largest_engine(scene, spec, xs, ys, cells)
    if held <= FITS * memory:
        return False
    refused.append(
        {"overlap": spec.plan.overlap, "shared": list(spec.plan.shared), "largest_node_bytes": held}
    )
    return True


def overlap_report(chosen: float, busiest: dict, too_big: list, memory: int) -> dict:
    """What the statistics say of an overlap choice: each overlap's simulated busiest node
    (work units) and against the chosen one's, and those refused for memory."""
    return {
        "chosen": chosen,
        "simulated_busiest": {f"{o:g}": b for o, b in busiest.items()},
        "simulated_busiest_vs_chosen": {
            f"{o:g}": ratio(b, busiest[chosen]) for o, b in busiest.items()
        },
        "too_big_for_memory": too_big,
        "memory_bytes": memory,
    }


def ratio(a: float, b: float) -> float:
    """a / b for the statistics, 1 where there is nothing to compare against."""
    return float(a / b) if b else 1.0
