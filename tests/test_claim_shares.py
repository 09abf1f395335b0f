"""A copied cell's own work shared over its holders (`MeshPlan.claim_shares`): the shares are
checked as a peer sends them, even the holders' loads as a linear program would (brute force
over a fine grid of splits), deal each shared cell's blocks to its holders in their shares,
and leave the image and ray counts the single node's."""

import itertools
import math
from unittest import mock

import numpy as np
import pytest

import meshnode.mesh.node
from host.planning import allowance
from host.planning.holder_shares import busiest, claim_shares, rescaled
from host.planning.plan import plan_render
from host.planning.request import Auto, Request
from host.scene.nff import read_nff
from meshnode.mesh.claims import SHARED_RUN, shared_claims
from protocols.render import ImageSpec, MeshPlan
from protocols.spec import SpecError
from tests.conftest import spd_scene
from tests.test_budget import ONE, copied_render

HOLDS = ((), (0,), (0, 1), ())  # cell 0 held by nodes 0, 1, 2; cell 1 by 1, 2


def _plan(**fields) -> MeshPlan:
    return MeshPlan(2, 2, copies=True, holds=HOLDS, **fields)


def test_shares_are_checked_as_a_peer_sends_them():
    good = _plan(claim_shares=((0.5, 0.25, 0.25), (1, 0), (), ()))
    assert MeshPlan.decode(good.to_wire())["claim_shares"] == good.claim_shares
    bad = [
        ((0.5, 0.5), (), (), ()),  # cell 0 has three holders
        ((), (), ()),  # a cell missing
        ((0.5, float("nan"), 0.5), (), (), ()),
        ((0.5, -0.1, 0.6), (), (), ()),
        ((0, 0, 0), (), (), ()),
        ((True, 1, 1), (), (), ()),
        ((1, 1, float("inf")), (), (), ()),
    ]
    for shares in bad:
        with pytest.raises(SpecError, match="claim_shares"):
            _plan(claim_shares=shares)
    with pytest.raises(SpecError, match="claim_shares"):
        MeshPlan(2, 2, claim_shares=((1,), (1,), (1,), (1,)))  # no copies to share over


def _least_busiest(plan, work, primary=None, steps: int = 40) -> float:
    """The least busiest node over every split of the shared cells' primary work on a grid
    of `steps` parts (brute force, for the small plan of HOLDS)."""
    holders = plan.holders_table()
    shared = [c for c in range(plan.nodes) if len(holders[c]) > 1]
    options = []
    for c in shared:
        n = len(holders[c])
        parts = [p for p in itertools.product(range(steps + 1), repeat=n) if sum(p) == steps]
        options.append([(c, tuple(x / steps for x in p)) for p in parts])
    best = np.inf
    for pick in itertools.product(*options):
        shares = [()] * plan.nodes
        for c, s in pick:
            shares[c] = s
        best = min(best, busiest(plan, work, tuple(shares), primary))
    return best


@pytest.mark.parametrize(
    "work,primary",
    [
        ((8, 3, 1, 2), None),
        ((1, 9, 1, 1), None),
        ((5, 5, 0, 4), None),
        ((30, 1, 1, 1), None),
        ((8, 3, 1, 2), (6, 1, 1, 2)),  # cell 0's 2 passed units stay with node 0
        ((12, 6, 1, 2), (4, 6, 1, 1)),
    ],
)
def test_shares_even_the_holders_loads_as_the_best_split_does(work, primary):
    plan = _plan()
    shares = claim_shares(plan, work, primary)
    holders = plan.holders_table()
    for c, s in enumerate(shares):
        moves = work[c] if primary is None else primary[c]
        assert (len(s) == len(holders[c])) if len(holders[c]) > 1 and moves else s == ()
        assert not s or sum(s) == pytest.approx(1.0)
    got = busiest(plan, work, shares, primary)
    quantum = max(work) / 64
    assert got <= busiest(plan, work, (), primary) + 1e-12
    assert got <= _least_busiest(plan, work, primary) + 2 * quantum
    if primary is not None:  # what does not move stays with the owner
        assert got >= max(w - p for w, p in zip(work, primary, strict=True))


def test_no_shares_without_a_cell_held_twice_or_without_work():
    assert claim_shares(MeshPlan(2, 2, copies=True, holds=((), (), (), ())), (1, 2, 3, 4)) == ()
    assert claim_shares(_plan(), (0, 0, 0, 0)) == ()


def test_a_shared_cells_blocks_go_to_its_holders_in_their_shares():
    plan = _plan(claim_shares=((0.5, 0.25, 0.25), (0.0, 1.0), (), ()))
    rng = np.random.default_rng(3)
    blocks = rng.integers(-1, 4, (64, 48))
    dealt = shared_claims(blocks, plan)
    assert np.array_equal(dealt, shared_claims(blocks, plan))  # every node deals alike
    assert (dealt[blocks >= 2] == -1).all() and (dealt[blocks == -1] == -1).all()
    assert set(np.unique(dealt[blocks == 1])) == {2}  # cell 1's all to its second holder
    zero = dealt[blocks == 0]
    for holder, share in zip((0, 1, 2), (0.5, 0.25, 0.25), strict=True):
        assert abs(np.count_nonzero(zero == holder) - share * zero.size) <= SHARED_RUN
    # runs of SHARED_RUN of a cell's blocks in rows go to one holder
    first = dealt.reshape(-1)[np.flatnonzero(blocks.reshape(-1) == 0)[:SHARED_RUN]]
    assert len(set(first.tolist())) == 1
    assert (shared_claims(blocks, _plan()) == -1).all()


@pytest.mark.parametrize("shape", [(1, 2), (2, 2), (3, 3), (2, 3)])
def test_shared_claims_give_the_single_node_image(shape, monkeypatch):
    made, own = [], meshnode.mesh.node.node_claims
    monkeypatch.setattr(
        meshnode.mesh.node, "node_claims", lambda *a: made.append(own(*a)) or made[-1]
    )
    scene = read_nff(spd_scene("balls_s2.nff"))
    nodes = shape[0] * shape[1]
    holds = tuple(tuple(c for c in (0, 1) if c != n) for n in range(nodes))  # 0, 1 everywhere
    rng = np.random.default_rng(nodes)
    shares = tuple(
        tuple(float(w) for w in rng.random(nodes)) if c < 2 else () for c in range(nodes)
    )
    copied_render(scene, shape, holds=holds, claim_shares=shares)
    dealt = [float(why.split("; ")[-1].split("%")[0]) for _, why in made if "holders" in why]
    assert dealt and min(dealt) > 0, [why for _, why in made]


@pytest.mark.parametrize("share", [True, False])
def test_the_plan_shares_copied_cells_only_when_asked(share):
    scene = read_nff(spd_scene("teapot.nff"))
    plan = MeshPlan(3, 3, max_share=0.25, balance="objects")
    image = ImageSpec(width=48, height=48, spp=2)
    with mock.patch.object(allowance, "PREPASS_SHARE", math.inf):
        planned = plan_render(Request(scene, image, ONE, plan=plan, auto=Auto(share_claims=share)))
    copies = planned.balance["budget"]["copies"]
    assert planned.spec.plan.holds, copies  # the hot spout's cell is copied
    claims = copies["claims"]
    assert claims["why"]
    if not share:
        assert planned.spec.plan.claim_shares == () and claims["chosen"] == "owner"
        return
    assert claims["chosen"] == "shared", claims
    assert claims["busiest_cells_work_shared_vs_owner"] < 1
    shares = planned.spec.plan.claim_shares
    assert [list(s) for s in shares] == claims["shares"]
    # refined on the simulated mesh: the lightest simulated kept, each round lighter
    seen, kept = claims["refined"]["simulated_busiest"], claims["refined"]["rounds"]
    assert seen and seen[kept] == min(seen), claims["refined"]
    assert all(a > b for a, b in zip(seen[:kept], seen[1 : kept + 1], strict=True))
    holders = planned.spec.plan.holders_table()
    assert all(not s or len(s) == len(holders[c]) > 1 for c, s in enumerate(shares))


def test_rescaled_shares_move_from_holders_over_the_mean_to_those_under():
    plan = _plan(claim_shares=((0.5, 0.25, 0.25), (0.5, 0.5), (), ()))
    out = rescaled(plan, (10.0, 5.0, 5.0, 4.0))  # node 0 over the mean (6), 1 and 2 under
    assert out[2:] == ((), ())
    assert out[0][0] < 0.5 and out[0][1] > 0.25 and out[0][2] > 0.25
    assert out[1] == pytest.approx((0.5, 0.5))  # its holders 1, 2 carry alike
    assert all(sum(s) == pytest.approx(1.0) for s in out[:2])


def test_shares_are_kept_only_where_the_simulated_mesh_finds_them_lighter():
    from dataclasses import replace

    from host.planning.holder_shares import checked
    from host.planning.partition import partition
    from host.planning.prepass import costs, partition_pass, planning
    from protocols.render import RenderSpec

    scene = read_nff(spd_scene("teapot_s1.nff"))
    plan = _plan(balance="objects")
    spec = RenderSpec(ImageSpec(width=32, height=32).sized(scene.view), plan=plan)
    part, keep = partition(scene, spec)
    # each shared cell's eye rays all to one of its holders, or spread alike
    tries = [((1.0, 0.0, 0.0), (1.0, 0.0)), ((0.0, 0.0, 1.0), (0.0, 1.0))]
    tries += [((0.0, 1.0, 0.0), (1.0, 0.0)), ((1 / 3, 1 / 3, 1 / 3), (0.5, 0.5))]
    kept = set()
    with planning(plan.nodes):
        without = costs(partition_pass(scene, spec, part, keep)).max()
        for first, second in tries:
            shared = replace(spec, plan=replace(plan, claim_shares=(first, second, (), ())))
            out, report = checked(scene, shared, part, keep)
            busiest = costs(partition_pass(scene, shared, part, keep)).max()
            assert report["why"] and report["chosen"] in ("shared", "owner")
            if busiest < without:
                assert out is shared and report["chosen"] == "shared", report
            else:
                assert out.plan.claim_shares == () and report["chosen"] == "owner", report
            kept.add(report["chosen"])
    assert kept == {"shared", "owner"}  # both ways are tried here
