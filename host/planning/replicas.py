"""A memory budget's copies (`MeshPlan.holds`): the room a budget leaves each node filled with
copies of the cells where the work is, so rays stay on a node instead of being passed.

R2E2 (Fouladi et al. 2022) renders scenes no node can hold by replicating the most-traversed
parts onto lightly loaded nodes, within memory, from load estimates. Here the cost pre-pass
simulates the mesh the budget left (no copies) and measures each cell's work and the rays each
node passes to each other; then, hottest cell first (its work over the nodes already holding
it), one more node holds it: by one rule a node it passes rays to or takes them from (its copy
then traces those rays where they are), failing that the least loaded node with room for its
objects; by the other the least loaded with room (RULES). Tiles whose eye rays the cell takes
on are dealt over all its holders (`host.planning.rectangles.spread`). The mesh is simulated
again with each rule's copies, all of them or only the hottest (TRIES), the sets whose cells'
work promises the lightest busiest node first (`promise_of`), as many as the pre-pass's
allowance affords, and the lightest set is kept only where its busiest node carries less
than without (or as much, with fewer rays passed): a copy moves work onto its holder, and the
pre-pass says whether that pays. Then the
copies kept are simulated once more with each cell's rays handed to its nearest holder
(`MeshPlan.forward` "nearest") instead of its owner, and that is kept where the busiest node
carries less: measured on 3x3 under a quarter share, handing rays to the nearest holder
lightened gears' busiest node and loaded balls' and rings' more.
"""

import time
from dataclasses import replace

import numpy as np

from host.planning import holder_shares
from host.planning.budget import budgeted, cell_bytes, holdings, within
from host.planning.holding import ratio
from host.planning.placement import sends
from host.planning.prepass import (
    allowance,
    coarse_partition,
    costs,
    held_scenes,
    partition_pass,
    primary_costs,
    rays_passed,
    simulated,
)
from host.planning.rectangles import spread
from meshnode.mesh.adaptive import RectIndex
from protocols.partition import Partition
from protocols.render import RenderSpec
from protocols.scene import SceneData

TRIES = (1.0, 0.5, 0.25)  # shares of the copies chosen (hottest first) simulated, in turn
# How `choose_copies` picks a copy's holder among the nodes with room: the one its cell trades
# most rays with ("traffic"), or the least loaded ("load"). Neither wins everywhere (simulated
# 3x3 under a quarter share, busiest node against no copies, the better share of TRIES:
# teapot 0.69 / 0.61, rings 0.83 / 0.79, balls 0.88 / 0.87, gears 0.84 / 0.84), so both are
# simulated and the lighter kept.
RULES = ("traffic", "load")
# What a set of copies promises the busiest node (`promise_of`) is short of what its
# simulation then gives: simulated over promised 1.00-1.53, quartiles 1.03 / 1.07 / 1.15, for
# the 48 sets tried on the table's 3x3 and 4x4 plans of balls, gears, teapot and tetra_s8.
# Copies are taken on their promise alone (a cut for them, `objectwork._judged`; a set the
# allowance cannot simulate, `_unsimulated`) only where this times it is the lighter. 1.05
# against 1.1 (coarse estimates of the 21 rows' plans at 1.0 / 0.6 / 1.5 of the allowance):
# rings 4x4 7.24 -> 7.90 at each (15 copies promising 0.91), at 0.6 tetra 2x2 2.19 -> 2.29,
# tetra_s8 2x2 1.64 -> 1.58, no other row moved; 1.0 also took tetra_s8 3x3's (3.26 -> 3.01)
PROMISED = 1.05
# Simulations the copies need at least (the mesh without, one set with): the pre-pass's
# allowance keeps this many for them when it affords re-cut rounds (`host.planning.allowance`).
# Every copy simulation is of the plan's own cells, so it builds no engine: the cut's
# simulation built them, and the plan's cache keeps them (`prepass.MESHES_KEPT`)
COPIES_LEAST = 2
HOLDER = {
    "traffic": "the node with room that trades most rays with its cell",
    "load": "the least loaded node with room",
}


def with_replicas(
    scene: SceneData,
    spec: RenderSpec,
    part: Partition,
    keep: np.ndarray,
    load=None,
    reserve=0,
    shares: bool = True,
    primary=None,
) -> tuple[RenderSpec, Partition, dict]:
    """(spec, partition, report): the budgeted plan with copies of the hottest cells on the
    nodes with room for them (`MeshPlan.holds`): of the copies each rule of RULES chooses,
    all that fit or the hottest half or quarter (TRIES), the one whose simulated mesh's
    busiest node carries least, if less than without (or as much, with fewer rays passed);
    else the plan as it was, and why. Where the pre-pass's allowance affords no simulation
    of them, the set its cells' simulated `load` (the part in primary batches `primary`)
    promises most unsimulated (`_unsimulated`). `reserve`: simulations of
    these cells kept from the other sets, forwarding and dealing for a later stage (the
    claims' shares' check). `shares`: each set simulated with its copied cells' own work
    shared over their holders, as the plan will share it (`holder_shares.shared`): without,
    a copy traced only the rays passed to it, and a set that would lighten the busiest node
    once shared was turned down (simulated 256x256 at the table's samples, coarse estimates
    of the speedup: gears 4x4 9.29 -> 10.60, teapot 4x4 6.33 -> 6.73, the 65,536-triangle
    tetra 4x4 5.44 -> 5.68, no row of 21 lower)."""
    plan = spec.plan
    if not budgeted(plan) or plan.nodes < 2 or plan.copies:
        why = "the plan holds every neighbour's copy within the budget" if plan.copies else ""
        return spec, part, {"chosen": [], "why": why or "no memory budget on a mesh"}
    if not allowance().affords("copies", COPIES_LEAST, builds=0):
        why = "skipped: " + allowance().why
        return _unsimulated(scene, spec, part, keep, (load, primary), why)
    began = time.process_time()
    before = partition_pass(scene, spec, part, keep)
    busiest, passed = float(costs(before).max()), rays_passed(before)
    report = {
        "simulated_load": costs(before).tolist(),
        "simulated_primary_load": primary_costs(before).tolist(),
        "simulated_rays_passed": passed,
        "simulated_busiest": busiest,  # ... with the copies chosen, below
    }
    work, primary = costs(before), primary_costs(before)
    tries = _ranked(plan, _sets(scene, spec, part, keep, work, sends(before)), work, primary)
    if not tries:
        return spec, part, {**report, "chosen": [], "why": "no node has room for another cell"}
    tried = []
    for rule, share, holds, promise in tries:
        if tried and not allowance().affords("copies: the other sets", 1, reserve, builds=0):
            break
        at = replace(spec, plan=replace(plan, copies=True, holds=holds))
        if shares:
            at, _ = holder_shares.shared(at, work, primary)
        after = partition_pass(scene, at, part, keep)
        now = float(costs(after).max())
        tried.append((now, rays_passed(after), rule, share, at, after, promise))
    now, fewer, rule, share, at, after, _ = min(tried, key=lambda t: t[:2])
    report["tried"] = [_tried(busiest, *t[:5], t[6]) for t in tried]
    if not (now < busiest or (now == busiest and fewer < passed)):
        return (
            spec,
            part,
            {
                **report,
                "chosen": [],
                "why": "with any of them the simulated busiest node carried as much or more",
                "prepass_cpu_seconds": time.process_time() - began,
            },
        )
    if not within(at.plan, holdings(scene, at, part, keep)):  # choose_copies keeps it
        raise AssertionError("copies chosen past the memory budget")
    at, forward, counted = _forwarded(scene, at, part, keep, after, reserve)
    weights, dealing = _weighed(scene, at, part, keep, counted, reserve)
    return (
        at,
        _dealt(part, at, weights),
        {
            **report,
            "simulated_busiest": now,
            "chosen": [list(h) for h in at.plan.holds],
            "rule": rule,
            "why": f"the hottest {share:.0%} of the copies that fit, each on {HOLDER[rule]}: "
            f"the simulated busiest node carries {now / busiest:.2f} of what it "
            "does without",
            "forward": forward,
            "dealing": dealing,
            "prepass_cpu_seconds": time.process_time() - began,
        },
    )


def _unsimulated(scene, spec: RenderSpec, part: Partition, keep, loads, skipped: str):
    """(spec, partition, report) with copies the pre-pass could not afford to simulate: of
    the load rule's sets (`_sets`), the one promising the busiest node least (`promise_of`,
    from `loads`: each cell's simulated work, the first cut's, and its part in primary
    batches) where PROMISED times that is under the busiest node's load; its tiles dealt by
    count; else none. Unsimulated copies can cost where they do not pay (teapot 3x3, busiest
    frame 0.56 s with copies against 0.52 without), and skipping them costs most where one
    cell holds most of the work (the SPD mountain 4x4 under 0.15, its glass spheres' cell:
    frame CPU speedup 0.94 without). Chosen on the cells' load alone (all the load rule's
    copies where it was 1.5 times the mean), at 0.6 of the allowance the table's plans took
    fewer that paid (coarse estimates of the speedup: balls 3x3 4.32 -> 4.82, gears 2x2 2.62
    -> 3.41, gears 4x4 9.29 -> 10.70; no row of 21 lower)."""
    load, primary = (None if x is None else np.asarray(x, float) for x in loads)
    nodes = spec.plan.nodes
    if load is None or primary is None or len(load) != nodes or len(primary) != nodes:
        return spec, part, {"chosen": [], "why": skipped + "; no cell's work known"}
    sets = _ranked(spec.plan, _sets(scene, spec, part, keep, load, None, ("load",)), load, primary)
    if not sets:
        return spec, part, {"chosen": [], "why": skipped + "; no node has room for a copy"}
    _, share, holds, promise = sets[0]
    report = {"simulated": False, "estimated_busiest_vs_none": ratio(promise, load.max())}
    if not PROMISED * promise < load.max():
        why = f"{skipped}; unsimulated, no set of copies promises the busiest node less"
        return spec, part, {**report, "chosen": [], "why": why}
    at = replace(spec, plan=replace(spec.plan, copies=True, holds=holds))
    return (
        at,
        _dealt(part, at),
        {
            **report,
            "chosen": [list(h) for h in at.plan.holds],
            "rule": "load",
            "simulated_load": load.tolist(),  # the first cut's: each cell's work, no copies
            "simulated_primary_load": primary.tolist(),
            "why": f"{skipped}; unsimulated, the hottest {share:.0%} of the copies "
            f"that fit, each on {HOLDER['load']}: estimated, the busiest node carries "
            f"{report['estimated_busiest_vs_none']:.2f} of its load",
        },
    )


def _ranked(plan, sets: list, work, primary) -> list:
    """(rule, share, holds, promise) of `sets` (`_sets`), the most promising first
    (`promise_of`, from each cell's `work` and its `primary` part): the allowance often
    affords one simulation of them, or none."""
    promise = [promise_of(plan, holds, work, primary) for _, _, holds in sets]
    order = sorted(range(len(sets)), key=lambda i: (promise[i], i))
    return [(*sets[i], promise[i]) for i in order]


def _sets(scene: SceneData, spec: RenderSpec, part, keep, work, passes, rules=RULES) -> list:
    """(rule, share, holds) of every distinct set of copies: each rule's choice
    (`choose_copies`, from each cell's `work` and the rays cells pass each other, `passes`),
    cut to each share of TRIES."""
    out, seen = [], set()
    for rule in rules:
        added = choose_copies(scene, spec, part, keep, work, passes if rule == "traffic" else None)
        for share in TRIES if added else ():
            holds = _holds(spec.plan.nodes, added[: max(1, round(share * len(added)))])
            if holds not in seen:
                seen.add(holds)
                out.append((rule, share, holds))
    return out


def cut_promise(scene: SceneData, spec: RenderSpec, keep, work, primary, passes) -> float:
    """The lightest busiest node any set of copies (`_sets`) promises on cells whose nodes
    hold `keep`, from each cell's simulated `work`, its `primary` part and the rays cells
    pass each other (`promise_of`; no simulation), or the busiest's `work` with none; a plan
    under a byte budget (`MeshPlan.node_bytes`) counts no copies here."""
    work = np.asarray(work, float)
    if spec.plan.node_bytes:
        return float(work.max())
    ranked = _ranked(spec.plan, _sets(scene, spec, None, keep, work, passes), work, primary)
    return min([float(work.max())] + [t[3] for t in ranked[:1]])


def promise_of(plan, holds: tuple, work, primary) -> float:
    """The busiest node's load with copies `holds`, estimated without a simulation: each
    copied cell's primary work (`primary`, of each cell's `work` in the copies-free mesh)
    shared over its holders as the claims' shares would share it (`holder_shares`), the
    rays passed into it left with its owner. Where the allowance affords one set of copies
    (most renders of a few seconds), the rules' order tried the traffic rule's first:
    balls 3x3 and 4x4 kept no copies where the load rule's, tried first, would have been
    kept (estimated 0.82 and 0.69 of the busiest node's load; simulated 256x256 at the
    table's samples, coarse estimates of the speedup 4.32 -> 4.82 and 5.99 -> 7.88, the
    mountain 3x3 3.99 -> 4.23, no row of 21 lower)."""
    plan = replace(plan, copies=True, holds=holds)
    shares = holder_shares.claim_shares(plan, work, primary)
    return holder_shares.busiest(plan, work, shares, primary)


def _forwarded(scene: SceneData, spec: RenderSpec, part: Partition, keep, owners, reserve=0):
    """(spec, report, its simulated Outcome): the plan with its copies' rays handed to each
    cell's nearest holder where the simulated busiest node then carries less than in
    `owners` (the plan's Outcome, handed to the owners), else as it was."""
    nearest = replace(spec, plan=replace(spec.plan, forward="nearest"))
    if all(nearest.plan.takers(n) == spec.plan.takers(n) for n in range(spec.plan.nodes)):
        why = "every nearest holder is the owner"
        return spec, {"chosen": spec.plan.forward, "why": why}, owners
    if not allowance().affords("copies: forwarding", 1, reserve, builds=0):
        why = "not simulated: " + allowance().why
        return spec, {"chosen": spec.plan.forward, "why": why}, owners
    handed = partition_pass(scene, nearest, part, keep)
    now, busiest = float(costs(handed).max()), float(costs(owners).max())
    better = now < busiest
    return (
        (nearest if better else spec),
        {
            "chosen": "nearest" if better else spec.plan.forward,
            "simulated_busiest_nearest_vs_owner": ratio(now, busiest),
            "why": "handed to the nearest holder, the simulated busiest node carries "
            f"{ratio(now, busiest):.2f} of what it does handed to the owner",
        },
        (handed if better else owners),
    )


def choose_copies(
    scene: SceneData, spec: RenderSpec, part: Partition, keep: np.ndarray, load, passes
) -> list[tuple[int, int]]:
    """(node, cell) copies in the order chosen: while some node has room, the cell with the
    most work per holder (`load[c]` shared evenly by its holders) gets one more holder, a
    node with room for its objects and bytes: of those, the one it passes most rays to or
    takes most from (`passes`, nodes x nodes; None: none), else the least loaded (each
    holder's load its cells' shares). `part`: for the cells' bytes, None where no byte
    budget bounds them."""
    plan, nodes = spec.plan, spec.plan.nodes
    own = np.asarray(cell_bytes(scene, part, keep) if part is not None else [0] * nodes)
    held = [{n} for n in range(nodes)]  # sets, as `carried` sums them (the same bits)
    holds = np.eye(nodes, dtype=bool)  # holds[n, c]: node n holds cell c
    mask = np.array(keep[:nodes], bool)  # the objects each node holds
    count = np.count_nonzero(mask, axis=1)
    size = own.copy()
    limit = plan.max_share * keep.shape[1] + 1e-9
    traffic = np.zeros((nodes, nodes)) if passes is None else np.asarray(passes, float)
    traffic = traffic + traffic.T
    full = np.zeros(nodes, bool)  # cells no node has room for: so they stay (holdings grow)
    cells = [np.flatnonzero(keep[c]) for c in range(nodes)]

    def room(c: int) -> np.ndarray:
        """The nodes not holding cell c with room for its objects and bytes."""
        new = np.count_nonzero(~mask[:, cells[c]], axis=1)
        fits = ~holds[:, c] & (count + new <= limit)
        if plan.node_bytes:
            fits &= size + own[c] <= plan.node_bytes
        return np.flatnonzero(fits)

    def carried(n: int, share) -> float:
        return sum(share[c] for c in held[n])

    added = []
    while True:
        share = [float(load[c]) / h for c, h in enumerate(holds.sum(axis=0).tolist())]
        for c in sorted(range(nodes), key=lambda c: (-share[c], c)):
            if full[c]:
                continue
            some = room(c).tolist()
            if not some:
                full[c] = True
                continue
            n = min(some, key=lambda n: (-traffic[n, c], carried(n, share), n))
            held[n].add(c)
            holds[n, c] = True
            count[n] += np.count_nonzero(~mask[n, cells[c]])
            mask[n, cells[c]] = True
            size[n] += own[c]
            added.append((n, c))
            break
        else:
            return added


def _holds(nodes: int, added: list[tuple[int, int]]) -> tuple:
    """MeshPlan.holds from (node, cell) copies."""
    return tuple(tuple(sorted(c for m, c in added if m == n)) for n in range(nodes))


def _tried(busiest, now: float, passed: int, rule: str, share: float, at, promise) -> dict:
    return {
        "rule": rule,
        "share": share,
        "holds": [list(h) for h in at.plan.holds],
        "estimated_busiest_vs_none": ratio(promise, busiest),
        "simulated_busiest_vs_none": ratio(now, busiest),
        "simulated_rays_passed": passed,
    }


def _weighed(scene: SceneData, spec: RenderSpec, part: Partition, keep, counted, reserve=0):
    """(weights, report): each tile's work as the simulated mesh measured it where the
    tiles were dealt by count (`counted`, its Outcome: `Outcome.tile_work`), kept where
    dealing by it leaves the simulated busiest node lighter (else None: by count)."""
    if spec.adaptive:
        return None, {"chosen": "count", "why": "adaptive sampling's rectangles stay put"}
    if not allowance().affords("copies: dealing", 1, reserve, builds=0):
        return None, {"chosen": "count", "why": "not simulated: " + allowance().why}
    coarse, cpart = coarse_partition(scene, spec, part)
    weights = counted.tile_work + 1.0  # a tile with nothing traced still makes its rays
    dealt = replace(cpart, owner=tuple(spread(list(cpart.takers), spec.plan, weights)))
    weighed = simulated(held_scenes(scene, keep[: part.nodes]), coarse, dealt)
    now, before = float(costs(weighed).max()), float(costs(counted).max())
    better = now < before
    full = _tile_weights(part, spec, coarse, cpart, weights) if better else None
    return full, {
        "chosen": "work" if better else "count",
        "simulated_busiest_by_work_vs_count": ratio(now, before),
        "why": "a cell's tiles dealt over its holders by their simulated work, the busiest "
        f"node carries {ratio(now, before):.2f} of what it does dealt by count",
    }


def _dealt(part: Partition, spec: RenderSpec, weights=None) -> Partition:
    """The partition with its tiles dealt over every holder of the cell taking their eye
    rays on (adaptive sampling's rectangles, one a node, stay with their nodes); by count,
    or by `weights` (each tile's estimated work, `_weighed`)."""
    if spec.adaptive:
        return part
    takers = list(part.takers or part.owner)
    return replace(part, takers=tuple(takers), owner=tuple(spread(takers, spec.plan, weights)))


def _tile_weights(part: Partition, spec: RenderSpec, coarse, cpart, coarse_weights):
    """Each of `part`'s tiles' share of the work of the coarse tile under its centre (of
    `cpart`, the coarse render `coarse`'s partition), shared evenly by the tiles under one."""
    (gw, gh), (cw, ch) = spec.sample_grid, coarse.sample_grid
    r = np.asarray(part.rects, np.int64).reshape(-1, 4)
    x = np.minimum(((r[:, 0] + r[:, 1]) / 2 * cw / gw).astype(np.int64), cw - 1)
    y = np.minimum(((r[:, 2] + r[:, 3]) / 2 * ch / gh).astype(np.int64), ch - 1)
    under = RectIndex(cpart.rects, cw)(y * cw + x)
    w = np.asarray(coarse_weights, float)
    known = under >= 0
    out = np.full(len(r), w.mean())
    out[known] = w[under[known]] / np.bincount(under[known], minlength=len(w))[under[known]]
    return out
