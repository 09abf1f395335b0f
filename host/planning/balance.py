"""Where to cut the work between mesh nodes (DESIGN.md 6, "cut positions chosen from a cheap
pre-pass that estimates cost per region"): the search over families of cuts, each measured by
the simulated cost pre-pass (`host.planning.prepass`).

The column cuts move so that the columns of nodes share the measured cost evenly (cost spread
evenly over the pixels of each column band), the row cuts likewise, and the pass repeats; the
cuts with the smallest busiest node win. Two image families are tried: row cuts shared by every
column (boxes in a grid), and row cuts of each column's own (each column's nodes share that
column's work evenly: where the work gathers in one place, cuts common to all columns leave the
node over it with most of it). A third cuts object space itself where the work lies
(`host.planning.workmap`). On the cuts chosen, `host.planning.holding` picks the overlap and
the occupancy map, and `host.planning.shared_cells` the cells every node holds under copies.
Correctness never depends on the cuts, only the balance of work does.
"""

from typing import NamedTuple

import numpy as np

from host.planning.budget import budgeted, holdings, within
from host.planning.cells import scene_box
from host.planning.holding import at_overlap, choose_holding, overlap_report, too_big_for_memory
from host.planning.objectcells import object_cells
from host.planning.objectwork import balanced_object_cells, object_limit
from host.planning.partition import partition
from host.planning.prepass import (
    allowance,
    coarse_pass,
    costs,
    efficiency,
    node_costs,
    tracing_seconds,
)
from host.planning.rectangles import bands, column_rows, splits
from host.planning.shared_cells import busiest_vs_none, choose_shared
from host.planning.workmap import map_tries
from protocols.render import RenderSpec


class Cuts(NamedTuple):
    """Where the pre-pass cuts: the image (`xs`, `ys` as `host.planning.rectangles.rectangles` takes
    them; None: even), object space (`cells` (los, his), None: from the image cuts), whether
    the nodes get the scene's occupancy map (`occupancy`), the overlap they hold with
    (`overlap`, percent), and why (`report`, for the statistics)."""

    xs: list | None
    ys: list | None
    report: dict
    cells: tuple | None = None
    occupancy: bool = True
    overlap: float = 1.0
    shared: tuple = ()


def _even_out(seen: list, n: int) -> list[int]:
    """New boundaries giving each band an equal share of the cost, from every cut tried so far
    on this axis: `seen` holds (boundaries, cost of each band) pairs, each a measured point of
    the cost's cumulative share at every boundary; between the points the cost is taken as
    spread evenly. With the points of every round (not the last alone) the cuts close in on
    where the work lies instead of swinging across it (a teapot on a floor: 0.84 of the work
    in one node of a 2x2, and re-cuts from the last round alone never did better than even).
    Every band keeps at least one sample."""
    share = {0: 0.0, n: 1.0}
    for bounds, band_cost in seen:
        cum = np.cumsum(band_cost) / max(float(np.sum(band_cost)), 1e-300)
        share.update(zip(bounds[1:-1], cum[:-1], strict=True))
    at = sorted(share)
    cum = np.maximum.accumulate([share[b] for b in at])  # later rounds may disagree a little
    parts = len(seen[-1][1])
    return bands(
        np.searchsorted(np.interp(np.arange(n + 1), at, cum), np.arange(1, parts) / parts), n
    )


FAMILIES = ("shared rows", "rows per column", "work map", "objects")


def balanced_cuts(
    scene, spec: RenderSpec, rounds: int = 2, families=FAMILIES, overlaps=(), memory: int = 0
) -> Cuts:
    """The cuts whose simulated busiest node is the least loaded, of those each family tried
    in `rounds` re-cuts: image cuts from even ones with row cuts shared by all columns or
    with each column's own (`ys` is then a list per column), and cells cut on the work map
    (`host.planning.workmap`), corrected by each round's measured costs; at the plan's
    overlap, or at each of `overlaps` too, keeping the overlap whose best cuts simulate
    least among those whose largest node's engine takes at most FITS of `memory` (a wider
    overlap keeps rays longer on a node at the price of objects held twice, and moves where
    the cuts are best: the teapot 3x3 simulated 3.51 at overlap 2 and 5.73 at 60, each on
    its own cuts); then, on those cuts, whether the nodes get the occupancy map
    (`choose_holding`) and under copies which cells every node holds (`choose_shared`)."""
    plan = spec.plan
    work: dict = {}  # the work map, simulated once: it has no overlap
    found, too_big = {}, []
    for overlap in sorted({plan.overlap, *overlaps}):
        at = at_overlap(spec, overlap)
        if found and not allowance().affords(f"overlap {overlap:g}", 1 + rounds):
            continue
        tried = _tries(scene, at, rounds, families, work)
        # cuts that break the memory budget are no candidates (the even ones stay the base)
        fits = [t for t in tried if not budgeted(plan) or _within(scene, at, t)]
        if not fits:
            continue
        best = min(fits, key=lambda t: t[0])
        if overlap != plan.overlap and too_big_for_memory(
            scene, at, *best[1:3], best[5], memory, too_big
        ):
            continue
        found[overlap] = best, tried
    if not found:  # nothing within the budget: the plan's retreats decide (`plan_render`)
        cells = object_cells(scene, scene_box(scene), plan.rows, plan.cols)
        return Cuts(None, None, {"family": "objects", "within_budget": False}, cells)
    overlap = min(found, key=lambda o: (found[o][0][0], o))  # ties: the smaller overlap
    (best, bx, by, cost, family, cells), tried = found[overlap]
    base = tried[0][0] or 1.0
    _, occupancy, holding = choose_holding(scene, at_overlap(spec, overlap), bx, by, cells, best)
    report = {
        "columns": bx,
        "rows": by,
        "family": family,
        "simulated_busiest_vs_even": best / base,
        "simulated_busiest_vs_even_by_family": {  # the best of each: why this one
            f: min((t[0] for t in tried if t[4] == f), default=base) / base for f in families
        },
        "simulated_imbalance": float((cost.max() - cost.min()) / cost.max()) if best else 0.0,
        **holding,
    }
    if overlaps:
        report["overlap"] = overlap_report(
            overlap, {o: f[0][0] for o, f in found.items()}, too_big, memory
        )
    # the busiest node on these cuts with the map as chosen (`best` had the map)
    busiest = best if occupancy else best * holding["simulated_busiest_without_map_vs_with"]
    at = at_overlap(spec, overlap)
    shared, report["shared"] = choose_shared(
        scene, at, bx, by, cells, occupancy, busiest, memory, efficiency(cost)
    )
    if report["shared"].get("tried") and family != "even":  # maybe better on even cuts
        on_even = _shared_on_even(scene, at, tried[0], occupancy, memory, busiest, report["shared"])
        if on_even is not None:
            bx = by = cells = None
            shared, updates = on_even
            report.update(updates)
            report["shared"]["cuts"] = f"even: they do better shared than {family}'s"
    return Cuts(bx, by, report, cells, occupancy, overlap, shared)


def _within(scene, spec: RenderSpec, attempt: tuple) -> bool:
    """Whether the cuts of a try (busiest, xs, ys, costs, family, cells) keep every node
    within the plan's memory budget (`host.planning.budget`)."""
    _, xs, ys, _, _, cells = attempt
    part, keep = partition(scene, spec, xs, ys, cells)
    return within(spec.plan, holdings(scene, spec, part, keep))


def _shared_on_even(
    scene, spec: RenderSpec, even_try: tuple, occupancy: bool, memory: int, busiest, chosen
) -> tuple[tuple, dict] | None:
    """(shared cells, report updates) on even cuts where sharing does better there than on
    the chosen cuts (their shared report `chosen`, their busiest node `busiest`), else None:
    a cell shared by every node may even out the work better than cuts moved to it."""
    even_busiest, _, _, cost, _, _ = even_try  # simulated with the map
    if not occupancy:
        cost = node_costs(scene, spec, None, None, None, occupancy)
    base = float(cost.max())
    even, on_even = choose_shared(
        scene, spec, None, None, None, occupancy, base, memory, efficiency(cost)
    )
    if not (even and busiest_vs_none(on_even) * base < busiest_vs_none(chosen) * busiest):
        return None
    return even, {
        "columns": None,
        "rows": None,
        "family": "even",
        "simulated_busiest_vs_even": base / even_busiest if even_busiest else 1.0,
        "simulated_imbalance": float((cost.max() - cost.min()) / cost.max()) if base else 0.0,
        "shared": on_even,
    }


def _tries(scene, spec: RenderSpec, rounds: int, families, work: dict) -> list[tuple]:
    """(busiest, xs, ys, costs, family, cells) of even cuts and of every family's re-cuts,
    each family only where the pre-pass's allowance affords its rounds (the even cuts'
    simulation estimates the render's tracing: `host.planning.allowance`)."""
    plan, allowed = spec.plan, allowance()
    first = coarse_pass(scene, spec, None, None)
    even = costs(first)
    allowed.learn(tracing_seconds(spec, first))  # the even cuts estimate the render
    tried = [(float(even.max()), None, None, even, "even", None)]
    for family in families:
        if not allowed.affords(f"cuts: {family}", 1 if family == "objects" else rounds):
            continue
        if family == "work map":
            tried += map_tries(scene, spec, rounds, work)
        elif family == "objects":  # cells that divide the objects, then the work
            cells, cost, _ = balanced_object_cells(scene, spec, object_limit(scene, plan))
            tried.append((float(cost.max()), None, None, cost, "objects", cells))
        elif family == "shared rows" or plan.rows > 1 and plan.cols > 1:
            tried += _image_tries(scene, spec, rounds, family == "rows per column", even)
    return tried


def _image_tries(scene, spec: RenderSpec, rounds: int, own_rows: bool, cost) -> list[tuple]:
    """(busiest, xs, ys, costs, family, None) of each re-cut of the image from even cuts
    (whose node costs are `cost`)."""
    (width, height), plan = spec.sample_grid, spec.plan
    family = "rows per column" if own_rows else "shared rows"
    xs, ys = splits(width, plan.cols), splits(height, plan.rows)
    seen_x: list = []
    seen_y: list = [[] for _ in range(plan.cols)] if own_rows else []
    tried = []
    for _ in range(rounds):
        grid = cost.reshape(plan.rows, plan.cols)
        seen_x.append((xs, grid.sum(axis=0)))
        if own_rows:
            rows = column_rows(ys, height, plan.rows, plan.cols)
            for c in range(plan.cols):
                seen_y[c].append((rows[c], grid[:, c]))
            ys = [_even_out(seen_y[c], height) for c in range(plan.cols)]
        else:
            seen_y.append((ys, grid.sum(axis=1)))
            ys = _even_out(seen_y, height)
        xs = _even_out(seen_x, width)
        cost = node_costs(scene, spec, xs, ys)
        tried.append((float(cost.max()), xs, ys, cost, family, None))
    return tried
