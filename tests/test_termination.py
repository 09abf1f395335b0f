"""Termination waves never end a state while a message is on a link or a node is busy: nodes of
a torus passing messages with random delays while the waves run down and up the tree, checked
at every advance; and a state ends within a few tree depths of the last activity, not a ring of
the mesh."""

import numpy as np
import pytest

from meshnode.mesh.termination import Echo, Probe, Termination
from protocols.errors import BadFrame
from protocols.state import State, states_of
from protocols.topology import Torus


def simulate(rows, cols, seed, work=200, max_delay=30, wave_delay=1, steps=200_000):
    """Nodes hold work units; processing one may send a message (after a random delay of up
    to `max_delay`) to a random node. Probes and echoes take 1..`wave_delay` steps a hop.
    Returns (the step TRACE ended, the step of the last work), checking at the advance that
    nothing is left anywhere."""
    rng = np.random.default_rng(seed)
    torus = Torus(rows, cols)
    n = torus.size
    nodes = [Termination(i, torus.parent(i), torus.children(i)) for i in range(n)]
    queue = [0] * n
    queue[int(rng.integers(n))] = work
    in_flight = []  # (arrival step, destination)
    waves = [(0, 0, Probe(1, int(State.TRACE)))]  # (arrival step, node, Probe or (child, Echo))
    holding = [False] * n
    last_activity = 0
    for now in range(steps):
        for m in [m for m in in_flight if m[0] <= now]:
            in_flight.remove(m)
            queue[m[1]] += 1
            nodes[m[1]].on_received()
        for i in range(n):
            if queue[i]:
                queue[i] -= 1
                last_activity = now
                if rng.random() < 0.7:
                    dest = int(rng.integers(n))
                    in_flight.append((now + int(rng.integers(1, max_delay)), dest))
                    nodes[i].on_sent()
        for w in [w for w in waves if w[0] <= now]:
            waves.remove(w)
            _, i, what = w
            if isinstance(what, Probe):
                nodes[i].probe_in(what)
                holding[i] = True
                hop = now + int(rng.integers(1, wave_delay + 1))
                waves.extend((hop, c, what) for c in torus.children(i))
            else:
                nodes[i].echo_in(*what)
        for i in range(n):
            t = nodes[i]
            if not (holding[i] and t.ready and queue[i] == 0):
                continue
            holding[i] = False
            if t.root:
                probe = t.next_wave(int(State.TRACE))
                if probe.state != State.TRACE:
                    assert not in_flight and not any(queue), (now, in_flight, queue)
                    return now, last_activity
                waves.append((now, i, probe))
            else:
                hop = now + int(rng.integers(1, wave_delay + 1))
                waves.append((hop, t.parent, (i, t.answer())))
    raise AssertionError("never advanced")


@pytest.mark.parametrize("rows,cols", [(1, 1), (1, 2), (2, 2), (3, 3), (2, 4), (5, 4)])
@pytest.mark.parametrize("seed", range(6))
def test_state_advances_only_after_all_work_and_messages(rows, cols, seed):
    done, last = simulate(rows, cols, seed)
    assert done >= last
    # ...and soon: a wave down and up finishes the busy one, one more comes back clean
    # (each hop a step; a node answers the step the last of its children's echoes came)
    depth = Torus(rows, cols).tree_depth
    assert done - last <= 4 * depth + 4


def test_long_and_uneven_delays_are_not_mistaken_for_the_end():
    # Data messages delayed far longer than a wave, and waves whose hops take uneven times,
    # so echoes of one wave overtake data sent before them.
    for seed in range(6):
        done, last = simulate(2, 2, seed, work=20, max_delay=400, wave_delay=7)
        assert done >= last
        done, last = simulate(3, 4, seed, work=60, max_delay=50, wave_delay=5)
        assert done >= last


def test_the_tree_spans_the_torus_on_links_within_its_depth():
    for rows, cols in [(1, 1), (1, 2), (2, 1), (2, 2), (3, 3), (2, 5), (4, 4), (16, 16), (7, 3)]:
        t = Torus(rows, cols)
        assert t.parent(0) is None
        for node in range(1, t.size):
            hops, at = 0, node
            while at != 0:
                assert t.parent(at) in t.links(at)  # a tree edge is a torus link
                at, hops = t.parent(at), hops + 1
            assert hops <= t.tree_depth
            assert node in t.children(t.parent(node))
        assert sum(len(t.children(n)) for n in range(t.size)) == t.size - 1


def test_states_run_in_order_to_done_on_a_mesh_of_one():
    for adaptive in (False, True):
        want = list(states_of(adaptive))
        t = Termination(0, states=states_of(adaptive))
        state, seen = int(State.DOWNLOAD), []
        for wave in range(1, 12):
            t.probe_in(Probe(wave, state))
            seen.append(state)
            if state == State.DONE:
                break
            state = t.next_wave(state).state
        # one clean wave a state, as nothing happens between them
        assert seen == want and t.advances == want[1:]


def test_a_dirty_or_unbalanced_subtree_holds_the_state():
    root = Termination(0, None, (1, 3), states_of(adaptive=False))
    root.probe_in(Probe(1, int(State.TRACE)))
    root.echo_in(1, Echo(1, False, 5, 5))
    assert not root.ready
    root.echo_in(3, Echo(1, True, 0, 0))
    assert root.next_wave(int(State.TRACE)) == Probe(2, int(State.TRACE))  # dirty
    root.probe_in(Probe(2, int(State.TRACE)))
    root.echo_in(1, Echo(2, False, 5, 4))  # a message still on a link
    root.echo_in(3, Echo(2, False, 0, 0))
    assert root.next_wave(int(State.TRACE)) == Probe(3, int(State.TRACE))
    root.probe_in(Probe(3, int(State.TRACE)))
    root.echo_in(1, Echo(3, False, 5, 5))
    root.echo_in(3, Echo(3, False, 0, 0))
    assert root.next_wave(int(State.TRACE)) == Probe(4, int(State.DONE))


def test_echoes_out_of_turn_are_a_peers_error():
    t = Termination(1, 0, (2,))
    with pytest.raises(BadFrame, match="not the open one"):
        t.echo_in(2, Echo(1, False, 0, 0))  # no wave open yet
    t.probe_in(Probe(1, int(State.TRACE)))
    with pytest.raises(BadFrame, match="not a child"):
        t.echo_in(3, Echo(1, False, 0, 0))
    with pytest.raises(BadFrame, match="not the open one"):
        t.echo_in(2, Echo(2, False, 0, 0))
    t.echo_in(2, Echo(1, False, 0, 0))
    with pytest.raises(BadFrame, match="not the open one"):
        t.echo_in(2, Echo(1, False, 0, 0))  # twice
    with pytest.raises(BadFrame, match="wave 3 after wave 1"):
        t.probe_in(Probe(3, int(State.TRACE)))
