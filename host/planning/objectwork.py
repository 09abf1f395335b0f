"""Cells cut by the objects and evened on the work the cost pre-pass measures
(`MeshPlan.balance` "objects"): memory first, then work.

Cells that divide the objects evenly can still leave one node most of the work (gears on a
3x3: the busiest node's work 0.95 above the least's). So the cells are first cut where the
work is guessed to lie (`host.planning.seenwork`), the mesh is simulated on a coarse image
(`host.planning.prepass`) and the cells re-cut where the measured work says, each cut kept
within the objects a node may hold (`host.planning.objectcells`).
"""

import time

import numpy as np

from host.planning.cells import grown, scene_box, traced
from host.planning.clip import holders
from host.planning.objectcells import WorkGrid, object_cells
from host.planning.placement import MAX_CELLS, placed, sends
from host.planning.prepass import (
    allowance,
    coarse_pass,
    costs,
    per_coarse_sample,
    primary_costs,
    tracing_seconds,
    unaffordable,
)
from host.planning.replicas import PROMISED, cut_promise
from host.planning.seenwork import first_guess
from host.scene.derived import scene_tables
from protocols.render import RenderSpec
from protocols.scene import SceneData
from protocols.topology import Torus

# Re-cuts on the pre-pass's measured work, at most; as many as its allowance affords (the
# first guess alone can mislead: teapot 4x4 under 0.15, its busiest node 3.8 times the mean
# at 4 spp simulated, 1.8 after one round)
ROUNDS = 3
# Voxels along each axis of the grid the guessed and measured work is spread on: a cut can
# only even what the grid tells apart. 32 against 16, real nodes in turns (256x256 at 63 spp,
# a /tmp script, the busiest node's frame CPU, two pairs): 3x3 under a quarter share balls
# 0.79 / 0.81, gears 0.77 / 0.84, rings 0.95 / 1.03, teapot 1.02 / 1.03, tetra at 512 spp
# 1.00 / 1.00; 2x2 under a half rings 0.87 / 0.86, teapot 0.90 / 0.87, balls 1.10 / 1.08;
# 4x4 under 0.15 (one pair) balls 0.93, teapot 0.89, rings 0.98, gears 0.94, tetra at 668 spp
# 1.01 / 1.08 (its kernels 1.24 / 1.15; its frame is its sky's eye rays, docs/measurements)
GRID = 32
FITS = 3  # passes over every round's measurements fitting the grid to them all
# A node's tracing CPU a work unit (`meshnode.mesh.stats.work_units`), turning each node's
# simulated work into the seconds the sky's tiles are dealt against (`node_seconds`). It
# also estimated one node's tracing of the render for the pre-pass's allowance until session
# 54, on the coarse pass's mesh units: 0.56-0.95 of the measured tracing on five scenes,
# 1.11-1.49 on tetra and tetra_s8 (`prepass.tracing_seconds` now, on the rays' own walks).
NS_PER_UNIT = 2.5
# A re-cut whose fullest node breaks the limit (the cuts count objects per node as if every
# later cut divided them evenly, and the boxes grow by the overlap) is cut again under a cap
# lowered by the excess (to TIGHTEN of it, at least a tenth), up to TRIES times: teapot 3x3
# under a quarter share reached 28.5%, and the plan fell back to the cells of the fewest
# objects
TIGHTEN, LOWER, TRIES = 0.97, 0.9, 6


def balanced_object_cells(
    scene: SceneData, spec: RenderSpec, limit=None, rounds=None, reserve: int = 0, copies=False
):
    """(cells, costs, report): cells cut by the objects (`object_cells`) where a first guess
    puts the work (`host.planning.seenwork`; where those break the budget, for the fewest
    objects), then re-cut `rounds` times on the work the cost pre-pass measured
    (`coarse_pass`: the mesh simulated on a coarse image), the guess's grid (`WorkGrid`)
    fitted to every round's measured cells; the cuts whose simulated busiest node is least
    are kept. `limit`: the objects a node may hold (the budget's), else a little over the
    fewest (`objectcells.SLACK`); cuts that break it are made again further inside.
    `rounds` None: up to ROUNDS, as many as the pre-pass's allowance affords with `reserve`
    simulations kept for later stages (`host.planning.allowance`, which learns one node's
    tracing here from the first cut's simulation: the report says how many and why).
    `copies`: the budget's copies will fill the room the cells leave, so a cut is judged by
    the busiest node its copies promise (`_judged`)."""
    plan, box = spec.plan, scene_box(scene)
    began = time.process_time()
    guess = first_guess(scene, spec, box, GRID)
    allowed = allowance()
    if rounds is None and allowed.bounded and (why := unaffordable(spec)):
        allowed.refuse_all("the first cut", why)
        return _guessed(scene, spec, box, guess, limit, why, time.process_time() - began)
    # one first cut: on a square mesh, halving the rows first makes the same cells transposed
    # on the torus (each cut picks its own axis), and the simulated mesh sends straight to
    # the taker, so both simulated the same busiest node (18 of 18 scenes and meshes); where
    # the cells sit is `_placed`'s, and the simulation goes to a re-cut round instead
    cells, cap, excess, first = _first_cut(scene, spec, guess, limit)
    why = f"asked for {rounds}"
    # the first cut's simulation estimates the render's tracing: the pre-pass's allowance
    cost = costs(first)
    allowed.learn(tracing_seconds(spec, first))
    # each node's work and the part of it in its primary batches (`holder_shares`), together
    both = np.column_stack([cost, primary_costs(first)])
    tried, over = [(float(cost.max()), cells, both, sends(first))], [excess]
    made = 0
    for _ in range(ROUNDS if rounds is None else rounds):
        if rounds is None and not allowed.affords("re-cut rounds", 1, reserve):
            why = f"{made} of {ROUNDS}: " + allowed.why
            break
        grid = _fitted(WorkGrid(*box, guess), [(t[1], t[2][:, 0]) for t in tried])
        cut, cap, excess = _within(scene, spec, grid, cap, limit)
        if any(_same(cut, t[1]) for t in tried):  # measured already: so would the next be
            why = f"{made} of {ROUNDS}: the cut repeated one simulated"
            break
        made += 1
        over.append(excess)
        if excess > 1:  # the plan would refuse these cells: no round to learn from
            continue
        outcome = coarse_pass(scene, spec, None, None, cut)
        cost = costs(outcome)
        both = np.column_stack([cost, primary_costs(outcome)])
        tried.append((float(cost.max()), cut, both, sends(outcome)))
    judged = _judged(scene, spec, tried, copies)
    busiest, cells, both, traffic = tried[int(np.argmin(judged))]
    cells, both, placement = _placed(cells, both, traffic, plan)
    cost = both[:, 0]
    return (
        cells,
        cost,
        {
            "simulated_primary_load": both[:, 1].tolist(),
            "simulated_busiest_by_round": [t[0] for t in tried],
            "judged_busiest_by_round": judged,
            "fullest_vs_limit_by_round": over,
            "rounds": made,
            "rounds_reason": why
            if rounds is not None or made < ROUNDS
            else f"all {ROUNDS} within the pre-pass's allowance",
            "prepass_cpu_seconds": time.process_time() - began,
            "simulated_busiest_vs_first_cut": busiest / tried[0][0] if tried[0][0] else 1.0,
            "placement": placement,
        },
    )


def _judged(scene: SceneData, spec: RenderSpec, tried: list, copies: bool) -> list[float]:
    """What each tried cut is chosen by, the least first: its simulated busiest node's load,
    or with `copies` the least of it and PROMISED times the busiest node a set of copies
    promises on that cut (`replicas.cut_promise`). Chosen without regard to copies, the cut
    kept was the one whose busiest node was lightest without, and copies then did less for
    it than for another (simulated 256x256 at the table's samples, coarse estimates of the
    speedup: the mountain 3x3 4.23 -> 5.22, teapot 2x2 and 3x3 2.38 -> 2.62 and 4.78 ->
    5.03, balls 3x3 4.82 -> 5.23; teapot 4x4 6.73 -> 6.64, the rest as they were)."""
    if not copies or len(tried) < 2:
        return [t[0] for t in tried]
    out = []
    for busiest, cells, both, traffic in tried:
        promise = cut_promise(scene, spec, _holders(scene, spec, cells), *both.T, traffic)
        out.append(min(busiest, PROMISED * promise))
    return out


def _same(cells, other) -> bool:
    """Whether two cuts' cells are the same: a round's cut, fitted to every measurement so
    far, repeats one measured (gears 2x2 under a half share and teapot 3x3 under a quarter:
    the second and third rounds the same cut), and the grid it is fitted to then learns
    nothing more from it."""
    return all(np.array_equal(a, b) for a, b in zip(cells, other, strict=True))


def _guessed(scene: SceneData, spec: RenderSpec, box, guess, limit, why: str, seconds: float):
    """(cells, None, report) of the cuts evening the first guess's work, or where those
    break the budget, cut for the fewest objects: no simulation, so no measured work."""
    cells, _, excess = _within(scene, spec, WorkGrid(*box, guess), limit, limit)
    if excess > 1:
        cells = object_cells(scene, box, spec.plan.rows, spec.plan.cols, limit=limit)
    return (
        cells,
        None,
        {
            "first_cut": "not simulated",
            "rounds": 0,
            "rounds_reason": why,
            "prepass_cpu_seconds": seconds,
        },
    )


def _first_cut(scene: SceneData, spec: RenderSpec, guess, limit):
    """(cells, cap, fullest node's objects over the limit, their coarse pass's Outcome) of
    the cuts evening the first guess's work (`guess`, on GRID), or where those break the
    budget, cut for the fewest objects."""
    plan, box = spec.plan, scene_box(scene)
    cells, cap, excess = _within(scene, spec, WorkGrid(*box, guess), limit, limit)
    if excess > 1:  # the guess's cuts break the budget: the fewest objects
        cells = object_cells(scene, box, plan.rows, plan.cols, limit=limit)
        cap = limit
    return cells, cap, excess, coarse_pass(scene, spec, None, None, cells)


def _within(scene: SceneData, spec: RenderSpec, grid, cap, limit):
    """(cells, cap, fullest node's objects over the limit) of cuts evening the work on
    `grid`: a cut whose fullest node breaks the limit is made again under a lower cap, at
    most TRIES times."""
    plan, box = spec.plan, scene_box(scene)
    for _ in range(TRIES):
        cells = object_cells(scene, box, plan.rows, plan.cols, grid, cap)
        excess = _fullest(scene, spec, cells) / limit if limit else 0.0
        if excess <= 1:
            break
        cap *= min(TIGHTEN / excess, LOWER)
    return cells, cap, excess


def _fullest(scene: SceneData, spec: RenderSpec, cells) -> int:
    """The most objects a node holds with these cells, counted as the budget counts them:
    its box grown by the overlap and padded as its engine pads it, each object tested
    exactly (`host.planning.clip.holders`)."""
    return int(_holders(scene, spec, cells).sum(axis=1).max())


def _holders(scene: SceneData, spec: RenderSpec, cells) -> np.ndarray:
    """(nodes, objects) bool: the objects each node's box holds with these cells, grown by
    the overlap and padded as its engine pads it (`host.planning.clip.holders`)."""
    return holders(scene, *traced(*grown(*cells, spec.plan.overlap)))


def _placed(cells, cost, traffic, plan):
    """(cells, costs, report): the cells moved to the nodes `placement.placed` finds, where
    fewer of the rays they pass each other are relayed."""
    node, before, after = placed(traffic, Torus(plan.rows, plan.cols))
    report = {
        "relayed_share_before": before / max(traffic.sum(), 1.0),
        "relayed_share_after": after / max(traffic.sum(), 1.0),
    }
    if after >= before:
        why = (
            f"more than {MAX_CELLS} cells: left where the cuts put them"
            if plan.nodes > MAX_CELLS
            else "no trade of cells between nodes relays fewer"
        )
        return cells, cost, {**report, "why": why}
    order = np.argsort(node)  # the cell each node now holds
    los, his = (np.asarray(c)[order] for c in cells)
    return (
        (los, his),
        np.asarray(cost)[order],
        {
            **report,
            "node_of_cell": node,
            "why": "the cells that pass each other most rays moved onto linked nodes: of the "
            f"rays passed in the pre-pass, {after / max(traffic.sum(), 1.0):.0%} relayed "
            f"instead of {before / max(traffic.sum(), 1.0):.0%}",
        },
    )


def node_seconds(spec: RenderSpec, units):
    """Each node's tracing CPU seconds of the render for the work `units` measured on the
    coarse pass: scaled by the render's samples over the coarse pass's, at NS_PER_UNIT a
    unit; None where nothing was measured (no simulation afforded)."""
    if units is None:
        return None
    return np.asarray(units, float) * per_coarse_sample(spec) * NS_PER_UNIT * 1e-9


def _fitted(grid: WorkGrid, measured: list) -> WorkGrid:
    """`grid` made to agree with every round's measured (cells, costs), FITS times over each
    in turn (iterative proportional fitting): one round's cells alone say only how much work
    each holds, the rounds together also where inside them it lies."""
    for _ in range(FITS if len(measured) > 1 else 1):
        for cells, cost in measured:
            grid = WorkGrid(grid.lo, grid.hi, _measured(grid, cells, cost))
    return grid


def _measured(grid: WorkGrid, cells, cost) -> np.ndarray:
    """Work per voxel with each node's measured `cost` spread over its cell in proportion
    to the work the grid put there (so what earlier rounds learnt of where inside a cell
    the work lies is kept)."""
    out = np.zeros_like(grid.density)
    for lo, hi, c in zip(*cells, cost, strict=True):
        mass = grid.density * grid.fractions(lo, hi)
        total = float(mass.sum())
        if total > 0:
            out += mass * (c / total)
    return np.maximum(out, 1e-9 * max(float(out.max()), 1e-300))


def object_limit(scene: SceneData, plan) -> float | None:
    """The objects a node may hold under the plan's `max_share` (None: no bound)."""
    return plan.max_share * scene_tables(scene).n if plan.max_share < 1 else None
