"""The cost pre-pass: the mesh simulated in this process on a coarse image, to measure where
the work lies before any cut is chosen.

A node's work is the rays it traces inside its box, wherever they came from, so the pre-pass
runs the mesh itself: the simulated mesh of `meshnode.mesh.simulator`, whose nodes decide with
the same scheduler as real ones, each node's cost counted as its intersection tests, voxel
steps and segments, with each segment sent on weighted (`meshnode.mesh.stats.work_units`).
"""

from collections import Counter
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field, replace

import numpy as np

from host.planning.allowance import Allowance, Work
from host.planning.partition import partition
from host.planning.rectangles import bands, splits
from host.scene.subset import subset
from meshnode.engine.loading import cpu_less_loads
from meshnode.engine.mapbounds import asked_in, per_map_seconds
from meshnode.mesh.engines import EngineCache
from meshnode.mesh.simulator import simulate
from meshnode.mesh.stats import UNIT_WEIGHTS, work_units
from protocols.camera import CameraSampling, Generation
from protocols.render import EVERYWHERE, ImageSpec, RenderSpec

COARSE = 64  # coarse samples along the longer image axis
# A plan's simulated meshes build their engines in one cache (`planning`): the same boxes
# are simulated with other copies, dealings or gates, and rebuilt each time took a fifth of a
# 3x3 plan's CPU (balls under a quarter share: 117 builds, 0.56 s of 2.7 s). At most this
# many meshes' engines are kept, the least recently used dropped first.
MESHES_KEPT = 3
# One node's tracing CPU a unit of its rays' own walks (`tracing_seconds`), set below every
# scene's so the pre-pass rather affords too little than too much. Against one node's
# measured tracing CPU (256x256, 2x2 / 3x3 / 4x4 under 0.5 / 0.25 / 0.15, `bench.mesh
# --min-trace 3`, two runs of the seven scenes) one node took 3.4-4.7 ns a unit on tetra,
# tetra_s8, mount, teapot, gears and balls, 5.5-5.7 on rings: at 3.2 the estimate was
# 0.56-0.94 of the tracing (tetra 2x2 the highest), so 3.0 keeps a margin for a quicker run
# (docs/measurements.md, session 54).
NS_ALONE = 3.0


@dataclass
class Planning:
    """What a plan's simulations share: their engines, and the pre-pass's CPU allowance."""

    engines: EngineCache
    allowance: Allowance
    held: dict = field(default_factory=dict)  # `held_scenes`: (id, objects) -> (scene, subset)
    passes: dict = field(default_factory=dict)  # `partition_pass`: its key -> (camera, Outcome)
    tables: set = field(default_factory=set)  # the map's tables its simulations read


_PLANNING: ContextVar[Planning | None] = ContextVar("planning", default=None)


@contextmanager
def planning(nodes: int):
    """While planning a mesh of `nodes`: every simulated mesh (`simulated`) takes its
    engines from one cache of at most MESHES_KEPT meshes' worth and is counted against one
    allowance (`host.planning.allowance`); both dropped when the plan is made. Yields the
    allowance."""
    cache = EngineCache(least=MESHES_KEPT * nodes, same_scenes=True)
    now = Planning(cache, Allowance())
    token = _PLANNING.set(now)
    try:
        with asked_in(now.tables):
            yield now.allowance
    finally:
        _PLANNING.reset(token)


def allowance() -> Allowance:
    """The plan's pre-pass allowance (outside a plan: one without bound)."""
    now = _PLANNING.get()
    return now.allowance if now is not None else Allowance(bounded=False)


def unaffordable(spec: RenderSpec) -> str:
    """Why no simulation of the render fits the pre-pass's allowance ("" where one may,
    `Allowance.too_small`): a 16x16 render's plan on 3x3 spent 0.3 s simulating 4,096
    coarse samples to place 256."""
    samples = spec.sample_grid[0] * spec.sample_grid[1] * spec.rays_per_pixel
    coarse = coarse_spec(spec).sample_grid
    return allowance().too_small(samples, coarse[0] * coarse[1])


def simulated(scenes, spec: RenderSpec, part):
    """The simulated mesh's Outcome (`meshnode.mesh.simulator.simulate`), its engines from
    the plan's cache, where a plan is being made (`planning`), and charged to the plan's
    allowance for what it counted (`allowance.Work`), its CPU measured beside (the engines
    it built, the map's tables it made once, `mapbounds.per_map`; kernels loaded meanwhile
    left out)."""
    now = _PLANNING.get()
    if now is None:
        return simulate(scenes, spec, part)
    cache = now.engines
    began, built, building = cpu_less_loads(), cache.built, cache.build_seconds
    objects, sights, sighting = Counter(cache.built_objects), cache.sights, cache.sight_seconds
    once, tables = per_map_seconds(), len(now.tables)
    out = simulate(scenes, spec, part, engines=cache)
    seconds = cpu_less_loads() - began
    work = Work(
        nodes=len(out.nodes),
        batches=sum(rec.batches for rec in out.nodes),
        units=work_units(out.totals()),
        built=cache.built - built,
        objects=dict(cache.built_objects - objects),
        sights=cache.sights - sights,
        tables=len(now.tables) - tables,
        held=sum(sum(s.records_by_kind.values()) for s in scenes),
    )
    now.allowance.ran(
        work,
        seconds,
        cache.build_seconds - building,
        once=per_map_seconds() - once,
        sights=cache.sight_seconds - sighting,
    )
    return out


def _coarse(bounds: list, n: int, coarse_n: int) -> list:
    """Boundaries on an n-sample axis scaled to a coarse_n-sample one (a list of them: each)."""
    if len(bounds) and isinstance(bounds[0], list):
        return [_coarse(b, n, coarse_n) for b in bounds]
    return bands([round(b * coarse_n / n) for b in bounds[1:-1]], coarse_n)


def coarse_spec(spec: RenderSpec) -> RenderSpec:
    """The render at COARSE samples across, pixel centres, one centre ray through a camera:
    where work lies, at a fraction of the cost; its tiles (stealing's chunks, the tiles
    dealt under copies) scaled with it, so it deals as many as the render (at 32 samples
    a tile, a 768-sample render's coarse pass had 4 tiles to spread over a 3x3)."""
    width, height = spec.sample_grid
    scale = COARSE / max(width, height)
    # (the byte budget is the planner's to check, on the plan it makes: not each try's)
    plan = replace(spec.plan, tile=max(1, round(spec.plan.tile * scale)), node_bytes=0)
    image = ImageSpec(
        width=max(plan.cols, round(width * scale)),
        height=max(plan.rows, round(height * scale)),
        depth=spec.image.depth,
    )
    camera = spec.camera
    if camera is not None:
        camera = replace(
            camera,
            sampling=CameraSampling(generation=Generation.CENTRE, sampling="uniform"),
        )
    return RenderSpec(image, spec.engine, plan, camera)


def node_costs(scene, spec: RenderSpec, xs, ys, cells=None, occupancy=True) -> np.ndarray:
    """Cost of every node on a coarse image cut at `xs`, `ys` (given on the full sample
    grid; None: even), its cells `cells` (None: from the image cuts), with or without the
    occupancy map: the mesh simulated in this process."""
    return costs(coarse_pass(scene, spec, xs, ys, cells, occupancy))


def coarse_pass(scene, spec: RenderSpec, xs, ys, cells=None, occupancy=True):
    """The simulated mesh's Outcome on the coarse image (`node_costs`' arguments)."""
    coarse, part, scenes = coarse_mesh(scene, spec, xs, ys, cells, occupancy)
    return simulated(scenes, coarse, part)


def partition_pass(scene, spec: RenderSpec, part, keep: np.ndarray):
    """The simulated mesh's Outcome on the coarse image with a partition's own cells, map,
    boxes (grown as they may be, node by node) and holders (`keep`). Within a plan, once for
    the same of all these: the stages after the copies each simulated the plan they were
    handed before changing it (teapot 3x3: the copies' plan three times, a tenth of its
    pre-pass), the outcome kept for the plan and its reuse counted (`Allowance.reused`)."""
    now, key = _PLANNING.get(), _pass_key(scene, spec, part, keep)
    if now is not None and key in now.passes:
        now.allowance.reused += 1
        return now.passes[key][1]
    coarse, cpart = coarse_partition(scene, spec, part)
    out = simulated(held_scenes(scene, keep[: part.nodes]), coarse, cpart)
    if now is not None:
        now.passes[key] = (spec.camera, out)  # the camera kept: its id stays its own
    return out


def unsimulated(scene, specs, part, keep: np.ndarray) -> int:
    """How many of `specs` `partition_pass` would simulate, not having kept them: what a
    stage asks the allowance for."""
    now = _PLANNING.get()
    kept = now.passes if now is not None else {}
    return sum(_pass_key(scene, spec, part, keep) not in kept for spec in specs)


def _pass_key(scene, spec: RenderSpec, part, keep: np.ndarray) -> tuple:
    """What `partition_pass` simulates from: the scene and camera by identity (a plan's
    are the same objects throughout; a camera's elements are an array), the rest of the
    spec, the partition's cells, boxes and map, and the holders' bits."""
    occupancy = (part.occ_res, part.occ_bits) != EVERYWHERE
    cells = (part.cell_los, part.cell_his, part.los, part.his, occupancy)
    held = np.packbits(np.asarray(keep[: part.nodes], bool)).tobytes()
    return id(scene), id(spec.camera), replace(spec, camera=None), cells, held


def held_scenes(scene, keep: np.ndarray) -> list:
    """Each node's scene: `scene`'s objects in each row of `keep`. Within a plan the same
    rows give the same scene objects, whose engines' keys digest them once (`EngineCache`
    `same_scenes`): a plan simulates the same cells again with other copies or dealing,
    and made anew they took 10 ms of a 60 ms tetra_s8 3x3 simulation, their digests 11."""
    now = _PLANNING.get()
    if now is None:
        return [subset(scene, row) for row in keep]
    out = []
    for row in keep:
        key = (id(scene), row.shape, np.packbits(row).tobytes())
        if key not in now.held:
            now.held[key] = (scene, subset(scene, row))  # the scene kept: its id stays its
        out.append(now.held[key][1])
    return out


def coarse_partition(scene, spec: RenderSpec, part):
    """(coarse spec, partition) `partition_pass` simulates: the coarse image's rectangles
    with `part`'s cells, map and boxes."""
    cells = np.array(part.cell_los), np.array(part.cell_his)
    occupancy = (part.occ_res, part.occ_bits) != EVERYWHERE
    coarse, cpart, _ = _coarse_cut(scene, spec, None, None, cells, occupancy)
    return coarse, replace(cpart, los=part.los, his=part.his)


def rays_passed(outcome) -> int:
    """Rays the simulated nodes sent each other, in all."""
    return int(sum(r.rays_sent for r in outcome.nodes))


def costs(outcome) -> np.ndarray:
    """Every simulated node's cost, in work units."""
    return np.array([r.cost for r in outcome.nodes], float)


def tracing_seconds(spec: RenderSpec, outcome) -> float:
    """One node's tracing CPU for the render, estimated from a coarse simulation's
    `outcome`: its rays' own walks (`walked_units`) scaled by the render's samples over the
    coarse image's, at NS_ALONE a unit (the pre-pass's allowance is a share of it)."""
    return walked_units(outcome.totals()) * per_coarse_sample(spec) * NS_ALONE * 1e-9


def per_coarse_sample(spec: RenderSpec) -> float:
    """The render's samples for each of the coarse image's: what scales work measured on
    the coarse pass to the render's."""
    coarse = coarse_spec(spec).sample_grid
    return (
        spec.sample_grid[0]
        * spec.sample_grid[1]
        * spec.rays_per_pixel
        / max(1, coarse[0] * coarse[1])
    )


def walked_units(counts: dict) -> float:
    """The work units of `counts` one node would spend on the same rays: tests, segments
    and the hierarchy steps the rays take alone. A mesh's map walks and rays sent on are
    its own, and a coarse image's packets walk for rays that have not entered a node
    (`packet_idle_steps`), rays four times as far apart as the render's sharing less of
    each walk: counted, they put the coarse pass's units at 1.1-2.1 times one node's render
    (tetra 3x3: 4.2 hierarchy steps a sample in the coarse pass's packets, 2.0 alone,
    2.4 in the render's packets at 256x256)."""
    steps = counts.get("voxel_steps", 0) - counts.get("packet_idle_steps", 0)
    return float(
        UNIT_WEIGHTS["intersection_tests"] * counts.get("intersection_tests", 0)
        + UNIT_WEIGHTS["voxel_steps"] * steps
        + UNIT_WEIGHTS["ray_segments"] * counts.get("ray_segments", 0)
    )


def primary_costs(outcome) -> np.ndarray:
    """Every simulated node's cost in its primary batches (its eye rays and all they spawn
    on the node), in work units."""
    return np.array([r.primary_cost for r in outcome.nodes], float)


def coarse_mesh(scene, spec: RenderSpec, xs, ys, cells=None, occupancy=True):
    """(coarse spec, partition, each node's objects) of the mesh `node_costs` simulates."""
    coarse, part, keep = _coarse_cut(scene, spec, xs, ys, cells, occupancy)
    return coarse, part, held_scenes(scene, keep[: part.nodes])


def _coarse_cut(scene, spec: RenderSpec, xs, ys, cells=None, occupancy=True):
    """(coarse spec, partition, objects each node holds) of `coarse_mesh`."""
    coarse = coarse_spec(spec)
    (width, height), (cw, ch) = spec.sample_grid, coarse.sample_grid
    xs, ys = xs or splits(width, spec.plan.cols), ys or splits(height, spec.plan.rows)
    part, keep = partition(
        scene, coarse, _coarse(xs, width, cw), _coarse(ys, height, ch), cells, occupancy
    )
    return coarse, part, keep


def efficiency(cost: np.ndarray) -> float:
    """Sum of node costs / (nodes x busiest): 1 when every node works as long."""
    return float(cost.sum() / (len(cost) * cost.max())) if cost.max() > 0 else 1.0
