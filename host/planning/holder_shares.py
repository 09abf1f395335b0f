"""How a cell's own work is shared among the nodes holding its engine (`MeshPlan.claim_shares`).

A budget's copies (`host.planning.replicas`) put a hot cell's engine on several nodes, but
the node that makes a block's eye rays was the one its rectangle's node hands that cell's
rays to: its owner where the rectangle is the owner's, so a copy traced only the rays passed
to it. On the busiest node of the 3x3 plans under a quarter share 78-89% of the work is
traced in its primary batches (balls, teapot, mount: its claimed eye rays and all they
spawn in the cell), so handing copies passed rays alone cannot even the load; a linear
program spreading each cell's work freely over its holders bounds what sharing the claims
can: the busiest node x1.32-1.76 lighter on 3x3, x2.10 on teapot 4x4 (`python -m
bench.holder_split`).

The shares fill the holders' loads in small equal quanta of each shared cell's primary work
(the rays passed into a cell stay with its owner), the
cells fewest nodes hold first, each quantum to its cell's least loaded holder (the cells one
node holds are that node's load from the start); then quanta move off the busiest node while
that lightens it: near the program's optimum, in plain arithmetic.
"""

import math
from dataclasses import replace

import numpy as np

from host.planning.holding import ratio
from host.planning.prepass import allowance, costs, partition_pass, unsimulated

QUANTA = 64  # parts of each shared cell's work dealt to its holders
# Simulations at most refining the shares after the one of the shares weighed (`refined`):
# simulated 256x256 at 16 spp, the busiest node against each cell's rays to its owner, balls
# 3x3 x1.07 -> 1.17 -> 1.20 -> 1.20, the mountain 4x4 x1.07 -> 1.20 -> 1.24 -> 1.25.
REFINE_ROUNDS = 3


def claim_shares(plan, cell_work, primary=None) -> tuple:
    """`MeshPlan.claim_shares` for `plan` (with holds) from each cell's work as simulated
    without copies (`cell_work[c]`: node c's load then) and the part of it in primary batches
    (`primary`; None: all of it), as the least busiest holder dealing quanta finds them: a
    cell's primary work moves with its claims, the rest (rays passed into the cell) stays
    with its owner. () where no cell has two holders or none has work."""
    work, moving = _parts(cell_work, primary)
    holders = plan.holders_table()
    if len(work) != plan.nodes or not work.sum() > 0:
        return ()
    shared = [c for c in range(plan.nodes) if len(holders[c]) > 1 and moving[c] > 0]
    if not shared:
        return ()
    load = np.where([len(h) == 1 for h in holders], work, work - moving)
    dealt = {c: np.zeros(len(holders[c]), np.int64) for c in shared}
    # the cells fewest nodes hold first: a cell every node holds fills what the others left
    for c in sorted(shared, key=lambda c: (len(holders[c]), -moving[c], c)):
        quantum = moving[c] / QUANTA
        for _ in range(QUANTA):
            i = min(range(len(holders[c])), key=lambda i: (load[holders[c][i]], i))
            load[holders[c][i]] += quantum
            dealt[c][i] += 1
    _evened(load, dealt, holders, moving)
    return tuple(
        tuple(float(x) for x in dealt[c] / QUANTA) if c in dealt else () for c in range(plan.nodes)
    )


def _parts(cell_work, primary):
    """(each cell's work, the part of it that moves with its claims), clipped to 0..work."""
    work = np.maximum(np.asarray(cell_work, float), 0.0)
    if primary is None or len(primary) != len(work):
        return work, work
    return work, np.clip(np.asarray(primary, float), 0.0, work)


def _evened(load, dealt: dict, holders: list, work) -> None:
    """Quanta moved off the busiest node, each to the least loaded other holder of its cell,
    while that leaves both below the busiest's load (the greedy dealing's order can leave a
    node that holds two shared cells over the rest)."""
    for _ in range(QUANTA * len(dealt)):
        top = int(np.argmax(load))
        best = None
        for c, given in dealt.items():
            if top not in holders[c] or not given[holders[c].index(top)]:
                continue
            i = min(range(len(holders[c])), key=lambda i: (load[holders[c][i]], i))
            quantum = work[c] / QUANTA
            if load[holders[c][i]] + quantum < load[top] and (best is None or quantum < best[2]):
                best = (c, i, quantum)
        if best is None:
            return
        c, i, quantum = best
        given = dealt[c]
        given[holders[c].index(top)] -= 1
        given[i] += 1
        load[top] -= quantum
        load[holders[c][i]] += quantum


def busiest(plan, cell_work, shares: tuple, primary=None) -> float:
    """The busiest node's load if each cell's primary work (`primary`; None: all its work)
    went to its holders in `shares` (a cell with none: all to its owner), the rest to its
    owner."""
    work, moving = _parts(cell_work, primary)
    load = work - moving
    for c, hs in enumerate(plan.holders_table()):
        got = shares[c] if shares and shares[c] else (1.0,) + (0.0,) * (len(hs) - 1)
        for h, w in zip(hs, got, strict=True):
            load[h] += moving[c] * w / sum(got)
    return float(load.max())


def shared(spec, cell_work, primary=None) -> tuple:
    """(spec, report): the plan (a RenderSpec's, with holds) with each copied cell's eye
    rays shared over its holders (`claim_shares`), from each cell's work simulated without
    copies (None: not known) and the part of it in primary batches (`primary`), where that
    leaves the busiest node lighter by the cells' work than each cell's work on its owner;
    else as it was, and why."""
    if cell_work is None or len(cell_work) != spec.plan.nodes:
        return spec, {"chosen": "owner", "why": "no cell's work was simulated"}
    shares = claim_shares(spec.plan, cell_work, primary)
    if not shares:
        return spec, {"chosen": "owner", "why": "no copied cell has work"}
    before = busiest(spec.plan, cell_work, (), primary)
    after = busiest(spec.plan, cell_work, shares, primary)
    if not after < before:
        why = "sharing the claims leaves the busiest node's cells' work as it was"
        return spec, {"chosen": "owner", "why": why}
    plan = replace(spec.plan, claim_shares=shares)
    return replace(spec, plan=plan), {
        "chosen": "shared",
        "busiest_cells_work_shared_vs_owner": ratio(after, before),
        "why": "each copied cell's eye rays made by its holders in these shares: by the "
        f"cells' simulated work the busiest node carries {ratio(after, before):.2f} of what "
        "it does with each cell's work on its owner",
    }


def checked(scene, spec, part, keep) -> tuple:
    """(spec, report): the plan's shares (weighed from the cells' work, `shared`) kept where
    its simulated mesh's busiest node carries less with them than with each copied cell's
    eye rays made by its owner (that plan's simulation is the copies' own, kept:
    `prepass.partition_pass`); else the plan with no shares. The cells' work leaves out the
    rays passed into a cell and where in it the work lies: teapot 3x3 under a quarter share,
    its shares weighed lighter, carried 1.04 times the busiest node's load without them."""
    owner = replace(spec, plan=replace(spec.plan, claim_shares=()))
    new = unsimulated(scene, (spec, owner), part, keep)  # the copies' own, if simulated, kept
    if new and not allowance().affords("claims: checked", new, builds=0):
        return spec, {"chosen": "shared", "why": "not simulated: " + allowance().why}
    with_shares = float(costs(partition_pass(scene, spec, part, keep)).max())
    without = float(costs(partition_pass(scene, owner, part, keep)).max())
    figure = {"simulated_busiest_shared_vs_owner": ratio(with_shares, without)}
    if with_shares < without:
        why = f"the simulated busiest node carries {ratio(with_shares, without):.2f} of its load"
        return spec, {"chosen": "shared", **figure, "why": why + " with each cell's owner"}
    why = "with the shares the simulated busiest node carried as much or more"
    return owner, {"chosen": "owner", **figure, "why": why}


def rescaled(plan, load) -> tuple:
    """The plan's shares with each holder's scaled by the mean node's simulated `load` over
    its own: a holder carrying more than the mean hands part of its share to those under."""
    load = np.asarray(load, float)
    out = []
    for shares, hs in zip(plan.claim_shares, plan.holders_table(), strict=True):
        if not shares:
            out.append(())
            continue
        w = np.asarray(shares, float) * load.mean() / np.maximum(load[hs], 1e-300)
        w = w if w.sum() > 0 else np.ones(len(hs))
        out.append(tuple(float(x) for x in w / w.sum()))
    return tuple(out)


def refined(scene, spec, part, keep) -> tuple:
    """(spec, report): the plan's shares refined on its simulated mesh (`partition_pass`, on
    its own cells: no engine built) while the pre-pass's allowance affords a simulation and
    the busiest node lightens (`rescaled`); the lightest simulated kept. The shares weighed
    from the cells' work leave out the rays passed into a cell, which stay with its owner
    or nearest holder, and that a cell's blocks differ in cost."""
    if not spec.plan.claim_shares:
        return spec, {"rounds": 0, "why": "no shares"}
    best, lightest, seen = spec, math.inf, []
    for _ in range(REFINE_ROUNDS + 1):
        if not allowance().affords("claims: refined", builds=0):
            break
        load = costs(partition_pass(scene, spec, part, keep))
        seen.append(float(load.max()))
        if not load.max() < lightest:
            break
        best, lightest = spec, float(load.max())
        spec = replace(spec, plan=replace(spec.plan, claim_shares=rescaled(spec.plan, load)))
    kept = seen.index(lightest) if seen else 0
    why = (
        f"{kept} round(s) kept of {len(seen) - 1} simulated"
        if seen
        else "not simulated: " + allowance().why
    )
    return best, {"rounds": kept, "simulated_busiest": seen, "why": why}
