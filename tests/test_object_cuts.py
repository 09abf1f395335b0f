"""The objects family's cut search (`host.planning.objectcells`) against its rule written out
plainly: numpy's own quantiles, and the cut chosen by Python's `min` over every candidate,
as the search chose before it was vectorised."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from host.planning.objectcells import CANDIDATES, SLACK, WorkGrid, _cut, _sorted, sorted_quantile

FINITE = st.floats(-1e6, 1e6, allow_nan=False, allow_subnormal=False)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(FINITE, min_size=1, max_size=300),
    st.lists(st.floats(0.0, 1.0), min_size=1, max_size=70),
)
def test_quantiles_of_sorted_values_are_numpys_to_the_bit(values, q):
    values, q = np.sort(np.array(values)), np.array(q)
    assert np.array_equal(sorted_quantile(values, q), np.quantile(values, q))


def _cut_by_the_rule(sorted_, work, lo, hi, nodes, limit):
    """`_cut`'s choice by its docstring's rule: every candidate a tuple (objects held by the
    fuller side per node, work of the busier side per node or distance from the even
    share, axis, position), picked by `min`: the first of the least, in the order tried
    (axis by axis; quantiles, then even steps)."""
    los, his, centres = sorted_
    share = nodes[0] / sum(nodes)
    if work is None:
        q = np.clip(share + np.linspace(-0.5, 0.5, CANDIDATES) * min(share, 1 - share), 0, 1)
    else:
        q = np.linspace(0.0, 1.0, CANDIDATES + 2)[1:-1]
    scored = []
    for axis in range(3):
        cuts = np.quantile(centres[axis], q)
        if work is not None:
            cuts = np.concatenate([cuts, lo[axis] + q * (hi[axis] - lo[axis])])
        cuts = np.clip(cuts, lo[axis], hi[axis])
        if work is None:
            busier = np.abs(q - share).tolist()
        else:
            left, total = work.below(lo, hi, axis, cuts)
            busier = [max(w / nodes[0], (total - w) / nodes[1]) for w in left.tolist()]
        for c, b in zip(cuts.tolist(), busier, strict=True):
            below, above = int((los[axis] <= c).sum()), int((his[axis] >= c).sum())
            scored.append((max(below / nodes[0], above / nodes[1]), b, axis, c))
    if work is None:
        best = min(scored, key=lambda t: (t[0], t[1]))
    else:
        fewest = min(t[0] for t in scored)
        cap = max(fewest, SLACK * fewest if limit is None else min(limit, SLACK * fewest))
        best = min((t for t in scored if t[0] <= cap), key=lambda t: (t[1], t[0]))
    return best[2], best[3]


def _values(lo, hi):
    """`_Cutter.values` of every object: per kind and axis, the values sorted."""
    return tuple([v for _, v in per_axis] for per_axis in _sorted(lo, hi))


def test_each_cut_is_the_one_the_rule_picks():
    """Random objects (clustered, so ties and crossing objects abound), with and without a
    work grid and a limit, for 1:1, 1:2 and 3:1 node splits."""
    rng = np.random.default_rng(11)
    for trial in range(40):
        n = int(rng.integers(5, 400))
        centre = rng.normal(size=(n, 3)) * rng.choice([0.05, 1.0], size=(n, 1))
        size = rng.random((n, 3)) ** 3 * 0.5
        lo_o, hi_o = centre - size, centre + size
        if trial % 4 == 0:
            lo_o, hi_o = np.round(lo_o, 1), np.round(hi_o, 1) + 0.05  # ties on every axis
        lo, hi = lo_o.min(axis=0), hi_o.max(axis=0)
        work = None if trial % 2 else WorkGrid(lo, hi, rng.random((8, 8, 8)) ** 4)
        limit = None if trial % 3 else n / 3
        nodes = [(1, 1), (1, 2), (3, 1)][trial % 3]
        got = _cut(_values(lo_o, hi_o), work, lo, hi, nodes, limit)
        assert got == _cut_by_the_rule(_values(lo_o, hi_o), work, lo, hi, nodes, limit)
