"""A render planned for a mesh: the spec every node receives, the image cuts (even, or from
the simulated cost pre-pass), every node's rectangle and box, and which objects it holds.

Everything here happens in the host before any node is configured, so a plan that cannot
work (a bad camera, too many nodes for the image) fails before any connection is made.
"""

import time
from dataclasses import dataclass, field, replace

import numpy as np

from host.planning.balance import balanced_cuts
from host.planning.budget import budgeted, holdings, refusal, report, retreats, within
from host.planning.cells import scene_box
from host.planning.growth import grown_within
from host.planning.holder_shares import checked, refined, shared
from host.planning.holding import FITS, choose_holding, engine_bytes
from host.planning.objectwork import balanced_object_cells, node_seconds, object_limit
from host.planning.partition import image_partition, partition, scene_maps
from host.planning.prepass import (
    allowance,
    coarse_pass,
    costs,
    planning,
    tracing_seconds,
    unaffordable,
)
from host.planning.replicas import COPIES_LEAST, with_replicas
from host.planning.request import Request
from host.planning.skytiles import SkyTiles
from protocols.partition import Partition
from protocols.render import EngineSpec, ImageSpec, MeshPlan, RenderSpec
from protocols.scene import SceneData

# A budgeted plan on cells evened on the work whose simulated busiest node, copies chosen,
# carries this many times the mean simulated load is simulated again on cells cut for the
# fewest objects (`_copied`): the mountain 3x3 under a quarter share 1.95; teapot 1.45,
# rings 1.17, gears 1.13, tetra 1.06 (each of those lighter evened, measured and simulated)
UNEVEN = 1.5


@dataclass
class Planned:
    spec: RenderSpec
    partition: Partition
    holders: np.ndarray  # (nodes, objects) bool
    camera: dict | None  # what the statistics say of the camera
    balance: dict  # how the cuts were chosen
    seconds: float  # planning time (autofocus probe and cost pre-pass included)
    sky: SkyTiles = field(default_factory=SkyTiles)  # dynamic tiles the host deposits itself


def plan_render(request: Request, memory: int = 0) -> Planned:
    """The render planned on `request.plan`: the request's `auto.overlaps` (object space)
    are overlaps for the pre-pass to choose among, the smallest first
    (`host.planning.balance.balanced_cuts` searches cuts at each; on even cuts
    `choose_holding` simulates them at each); `memory`: the smallest node's, 0 if not known.
    Without overlaps the plan's own overlap is kept. Its simulated meshes share their
    engines and keep within the pre-pass's allowance (`prepass.planning`), which the
    balance's report gives where any ran or was skipped."""
    _nodes_map(request)
    with planning(request.plan.nodes) as allowed:
        planned = _planned(request, memory)
    if allowed.passes or allowed.skipped:
        planned.balance["prepass"] = allowed.report()
    return planned


def _nodes_map(request: Request) -> None:
    """The maps the nodes get (`partition.scene_maps`: the occupancy map cells cut by the
    objects send them, and an inner map where the objects lie in a small part of the box),
    made and kept with the scene before the pre-pass's allowance starts: the plan makes
    them whatever is simulated, and its first guess reads them. Counted in the pre-pass,
    tetra's map with sub-voxels (0.12 s) left a fresh process's first plan at 3 s renders no
    re-cut round, where the next plan, on the map kept, afforded one or two; balls' inner
    map took 0.09 s of its first plan."""
    plan = request.plan
    if plan.mode == "object" and plan.nodes > 1 and plan.balance == "objects":
        scene_maps(request.scene, scene_box(request.scene), plan)


def _planned(request: Request, memory: int) -> Planned:
    start = time.perf_counter()
    scene, engine, plan, camera = request.scene, request.engine, request.plan, request.camera
    image, overlaps = request.sized, request.auto.overlaps
    if overlaps and plan.mode == "object":
        plan = replace(plan, overlap=min(overlaps))
    camera_spec = info = None
    if camera is not None:  # autofocus probes the scene here, before any node is configured
        camera_spec, info = camera.spec(scene, image, lambda: _probe_engine(scene, image, engine))
    spec = RenderSpec(image, engine, plan, camera_spec)
    xs = ys = cells = loads = cost = None
    occupancy, overlap, shared = True, plan.overlap, plan.shared
    balance: dict = {"cuts": plan.balance}
    t0 = time.perf_counter()
    searched = plan.balance == "cost" or (overlaps and plan.balance == "even")
    if plan.mode == "object" and plan.nodes > 1 and searched and (why := unaffordable(spec)):
        # the even cuts at the plan's overlap: no simulation to weigh others by
        allowance().refuse_all("the even cuts' simulation", why)
        balance.update(family="even", why=why)
    elif plan.mode == "object" and plan.nodes > 1 and plan.balance == "cost":
        xs, ys, report, cells, occupancy, overlap, shared = balanced_cuts(
            scene, spec, overlaps=overlaps, memory=memory
        )
        balance.update(report, seconds=time.perf_counter() - t0)
    elif plan.mode == "object" and plan.nodes > 1 and plan.balance == "objects":
        # the copies' simulations kept from the re-cut rounds, and the shares' check
        copied = budgeted(plan) and request.auto.budget_copies
        reserve = COPIES_LEAST + int(request.auto.share_claims) if copied else 0
        limit = object_limit(scene, plan)
        cells, cost, report = balanced_object_cells(scene, spec, limit, None, reserve, copied)
        loads = node_seconds(spec, cost)  # where the tiles no eye ray enters go
        balance.update(report, seconds=time.perf_counter() - t0)
    elif plan.mode == "object" and plan.nodes > 1 and overlaps:  # even cuts, overlap chosen
        first = coarse_pass(scene, spec, None, None)
        even = costs(first)
        allowance().learn(tracing_seconds(spec, first))  # the render's tracing
        overlap, occupancy, report = choose_holding(
            scene, spec, None, None, None, even.max(), overlaps, memory
        )
        balance.update(report, seconds=time.perf_counter() - t0)
    if plan.mode == "object" and (overlap, shared) != (plan.overlap, plan.shared):
        spec = replace(spec, plan=replace(plan, overlap=overlap, shared=shared))
    if plan.mode == "image":
        part, keep, sky = image_partition(scene, spec)
        return Planned(spec, part, keep, info, balance, time.perf_counter() - start, sky)
    part, keep = partition(scene, spec, xs, ys, cells, occupancy, loads)
    if budgeted(spec.plan):
        spec, part, keep, balance["budget"] = _within_budget(
            scene,
            spec,
            part,
            keep,
            request.auto.budget_copies,
            cost,
            request.auto.share_claims,
            balance.get("simulated_primary_load"),
            request.auto.steal_claims,
        )
        balance["cuts"] = spec.plan.balance  # what the budget left of the plan's cuts
    return Planned(spec, part, keep, info, balance, time.perf_counter() - start)


def _within_budget(
    scene: SceneData,
    spec: RenderSpec,
    part,
    keep,
    copies=True,
    load=None,
    share=True,
    primary=None,
    steal=True,
):
    """(spec, partition, holders, report) keeping every node within the plan's memory
    budget: the plan as made, or the first of its retreats (`host.planning.budget.retreats`)
    that keeps it, its room then filled (`copies`) with copies of the hottest cells and wider
    boxes where the pre-pass says they pay (`host.planning.replicas`, `growth`); BudgetError
    naming the smallest share reached when none does. Under a byte bound the nodes build
    hierarchies (their memory is known before they are built; a grid's is not: shells'
    took 260 MB for 1.5 MB of objects). `load`: each node's simulated work on these cells
    (the pre-pass's), for copies it cannot afford to simulate (`replicas._unsimulated`).
    `share`: each copied cell's own work shared over its holders (`holder_shares.shared`),
    `primary` the part of `load` in each node's primary batches; `steal`: the holders then
    steal each other's claimed chunks (`stealing`)."""
    gave_up = []
    if spec.plan.node_bytes and spec.engine.structure == "auto":
        spec = replace(spec, engine=replace(spec.engine, structure="bvh"))
        gave_up.append("structure auto: a hierarchy's memory is known before it is built")
    held = holdings(scene, spec, part, keep)
    if not within(spec.plan, held) and spec.plan.balance == "objects":
        gave_up.append(f"cells evened on the work: fullest node {max(held['share']):.1%}")
        part, keep, load, primary = *partition(scene, spec), None, None  # the fewest objects
        held = holdings(scene, spec, part, keep)
    for fallback in retreats(spec.plan):
        if within(spec.plan, held):
            break
        gave_up.append(f"{_difference(spec.plan, fallback)}: fullest node {max(held['share']):.1%}")
        spec, load, primary = replace(spec, plan=fallback), None, None
        part, keep, held = _objects_within(scene, spec)
    if not within(spec.plan, held):
        raise refusal(scene, spec.plan, held)
    if not copies:
        return spec, part, keep, {**report(spec.plan, held, gave_up), "copies": "none asked"}
    spec, part, keep, chosen = _copied(scene, spec, part, keep, load, primary, int(share), share)
    if steal:
        spec, chosen["steal"] = stealing(spec)
    if spec.plan.holds and share:
        work = chosen.get("simulated_load")
        primary = chosen.get("simulated_primary_load", primary)
        spec, chosen["claims"] = shared(spec, work, primary)
        if spec.plan.claim_shares:  # weighed from the cells' work: simulated where afforded
            spec, check = checked(scene, spec, part, keep)
            chosen["claims"].update(chosen=check["chosen"], checked=check)
            if not spec.plan.claim_shares:  # the check's reason, not the weighing's
                chosen["claims"]["why"] = check["why"]
    elif spec.plan.holds:
        chosen["claims"] = {"chosen": "owner", "why": "not asked"}
    part, keep, growth = grown_within(scene, spec, part, keep)
    if spec.plan.claim_shares:  # the shares as refined, if the allowance affords it
        spec, chosen["claims"]["refined"] = refined(scene, spec, part, keep)
        chosen["claims"]["shares"] = [list(s) for s in spec.plan.claim_shares]
    held = holdings(scene, spec, part, keep)
    return (
        spec,
        part,
        keep,
        {**report(spec.plan, held, gave_up), "copies": chosen, "growth": growth},
    )


def stealing(spec: RenderSpec) -> tuple[RenderSpec, dict]:
    """(spec, report): the plan with its holders stealing each other's claimed chunks
    (`MeshPlan.steal` under copies: `meshnode.mesh.claimfeed`) where the budget's copies
    were chosen and pinhole eye rays are claimed; else as it was, and why. A stolen chunk is
    traced with the engines its claimant would use, so it moves work and adds no pass: 3x3
    under a quarter share, the busiest node's frame CPU at once teapot 3.15 -> 4.60, the
    mountain 3.98 -> 4.45 (one run each)."""
    plan = spec.plan
    if plan.steal:
        return spec, {"chosen": True, "why": "asked for"}
    if not plan.holds:
        return spec, {"chosen": False, "why": "no copies: a cell's work stays on its node"}
    if spec.camera is not None or spec.adaptive:
        return spec, {"chosen": False, "why": "a lens or adaptive sampling: no eye claims"}
    why = "each copied cell's claimed chunks taken at run time by whichever holder runs out"
    return replace(spec, plan=replace(plan, steal=True)), {"chosen": True, "why": why}


def _copied(scene: SceneData, spec: RenderSpec, part, keep, load, primary, reserve=0, shares=True):
    """(spec, partition, holders, report) of the budget's copies (`with_replicas`) on the
    cells as cut, or where those are cut by the objects evened on the work and the
    simulated busiest node still carries UNEVEN times the mean or more, on cells cut for the
    fewest objects if the simulated busiest node carries less there: those leave every node
    room for copies of the hottest cells. The mountain 3x3 under a quarter share: its glass
    spheres' cell took 54% of the work, and with cells evened on the work only three nodes
    besides its owner had room for its copy (busiest frame 1.02 s against 0.73 cut for the
    fewest objects, the copy then on every node). `reserve`: simulations the copies keep
    for the claims' shares' check (`holder_shares.checked`); `shares`: the copies weighed
    with each copied cell's own work shared over its holders, as the plan will share it."""
    at, dealt, chosen = with_replicas(scene, spec, part, keep, load, reserve, shares, primary)
    simulated = chosen.get("simulated_load", [])
    top = chosen.get("simulated_busiest", 0.0)
    uneven = top / max(np.mean(simulated), 1e-300) if simulated else 0.0
    if spec.plan.balance != "objects" or uneven < UNEVEN:
        return at, dealt, keep, chosen
    if not allowance().affords("cells for the fewest objects", COPIES_LEAST):
        return at, dealt, keep, {**chosen, "cells": allowance().skipped[-1]}
    fewest, fewest_keep = partition(scene, spec)
    same = np.array_equal(np.asarray(fewest.cells), np.asarray(part.cells))
    if same or not within(spec.plan, holdings(scene, spec, fewest, fewest_keep)):
        return at, dealt, keep, chosen
    at2, dealt2, chosen2 = with_replicas(scene, spec, fewest, fewest_keep, shares=shares)
    busiest = {"evened on the work": chosen["simulated_busiest"]}
    busiest["fewest objects"] = chosen2["simulated_busiest"]
    cells = {"simulated_busiest": busiest, "uneven": float(uneven)}
    if busiest["fewest objects"] < busiest["evened on the work"]:
        cells["chosen"] = "fewest objects"
        return at2, dealt2, fewest_keep, {**chosen2, "cells": cells}
    return at, dealt, keep, {**chosen, "cells": {**cells, "chosen": "evened on the work"}}


def _objects_within(scene: SceneData, spec: RenderSpec):
    """(partition, holders, holdings) of cells cut by the objects: evened on the pre-pass's
    work within the budget's objects per node (`host.planning.objectwork`, the sky's tiles
    dealt against its loads), or where those still break the budget, cut for the fewest
    objects alone; so too where the pre-pass's allowance cannot afford the cut's
    simulation (the retreat's cut is a later simulation: tree 3x3 under a
    quarter share at 16x16 simulated a second first cut, 0.17 s of a 0.6 s plan)."""
    if allowance().affords("the retreat's cells evened on work"):
        cells, cost, _ = balanced_object_cells(scene, spec, object_limit(scene, spec.plan))
        part, keep = partition(scene, spec, cells=cells, loads=node_seconds(spec, cost))
        held = holdings(scene, spec, part, keep)
        if within(spec.plan, held):
            return part, keep, held
    part, keep = partition(scene, spec)
    return part, keep, holdings(scene, spec, part, keep)


def _difference(was: MeshPlan, now: MeshPlan) -> str:
    """What a retreat gave up, in the user's terms."""
    if was.balance != now.balance:
        return f"--balance {was.balance} (cells cut by the objects instead)"
    if was.shared != now.shared:
        return "shared cells"
    if was.copies != now.copies:
        return "--copies"
    return f"--overlap {was.overlap:g} (0 instead)"


def _probe_engine(scene: SceneData, image: ImageSpec, engine: EngineSpec):
    from host.camera.autofocus import probe_engine

    width, height = image.size
    return probe_engine(scene, width, height, engine)


def choose_mode(
    plan: MeshPlan,
    scene: SceneData,
    memories: list[int],
    asked: str = "auto",
    override: int | None = None,
) -> tuple[MeshPlan, str]:
    """The mode the nodes run, and why: what was asked, or (auto) image space when the
    whole scene's engine fits comfortably in the smallest node's memory (each node reports
    its memory at the handshake; `override` replaces the reports), object space when not or
    when the image cuts are cost-balanced (an object-space lever)."""
    if asked != "auto":
        return replace(plan, mode=asked), f"asked for with --mode {asked}"
    need = engine_bytes(scene)
    memory = smallest_memory(memories, override)
    size = f"the whole scene's engine (about {_size(need)})"
    if plan.balance != "even":
        return replace(plan, mode="object"), f"--balance {plan.balance} cuts object space"
    if plan.max_share < 1:
        return replace(plan, mode="object"), "--max-share divides the scene: object space"
    if plan.steal or plan.copies:
        lever = "--steal" if plan.steal else "--copies"
        return replace(plan, mode="object"), f"{lever} is object space's lever"
    if memory == 0:
        return replace(plan, mode="object"), "the nodes did not report their memory"
    where = "--node-memory" if override is not None else "the smallest node's free memory"
    if need <= FITS * memory:
        return replace(plan, mode="image"), (
            f"{size} fits in {where} ({_size(memory)}) many times over: no rays cross the network"
        )
    return replace(plan, mode="object"), (
        f"{size} would take over {FITS:.0%} of {where} ({_size(memory)}): each node holds its box"
    )


def smallest_memory(memories: list[int], override: int | None = None) -> int:
    """The memory to plan for: `override` (--node-memory), else the least any node reported
    at the handshake (0: none did)."""
    return override if override is not None else min((m for m in memories if m > 0), default=0)


def _size(n: int) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"
