"""The state packet never ends a state while a message is on a link or a node is busy: a
simulated ring of nodes passing messages with random delays, checked at every advance."""

import numpy as np
import pytest

from meshnode.mesh.termination import Packet, Termination
from protocols.state import State
from protocols.topology import Torus


def simulate(rows, cols, seed, work=200, max_delay=30, steps=200_000):
    """Nodes hold work units; processing one may send a message (after a random delay) to a
    random node. Returns the time the packet reached TRACE -> FLUSH and the time the last
    message was processed, and checks the invariant at each advance."""
    rng = np.random.default_rng(seed)
    torus = Torus(rows, cols)
    n = torus.size
    nodes = [Termination(i) for i in range(n)]
    queue = [0] * n
    in_flight = []  # (arrival time, destination)
    queue[0] = work
    packet, holder, arrive = Packet.start(n), 0, 0
    packet.state = State.TRACE
    last_activity = 0
    for now in range(steps):
        # Deliver messages that have arrived.
        for m in [m for m in in_flight if m[0] <= now]:
            in_flight.remove(m)
            queue[m[1]] += 1
            nodes[m[1]].on_received()
        # Each node processes one unit; with some chance it spawns a message.
        for i in range(n):
            if queue[i]:
                queue[i] -= 1
                nodes[i].on_work()
                last_activity = now
                if rng.random() < 0.7:
                    dest = int(rng.integers(n))
                    in_flight.append((now + int(rng.integers(1, max_delay)), dest))
                    nodes[i].on_sent()
        # The packet moves one hop per step; an idle holder passes it on.
        if now >= arrive and queue[holder] == 0:
            state = packet.state
            packet = nodes[holder].pass_on(packet)
            if packet.state != state:
                # Advancing is only right when nothing is left anywhere.
                assert not in_flight and not any(queue), (now, in_flight, queue)
                return now, last_activity
            holder, arrive = torus.ring_next(holder), now + 1
    raise AssertionError("never advanced")


@pytest.mark.parametrize("rows,cols", [(1, 1), (1, 2), (2, 2), (3, 3), (2, 4)])
@pytest.mark.parametrize("seed", range(6))
def test_state_advances_only_after_all_work_and_messages(rows, cols, seed):
    done, last = simulate(rows, cols, seed)
    assert done >= last
    # ...and not absurdly late: at most three rounds of the ring after the last activity.
    assert done - last <= 3 * rows * cols + 3


def test_long_delays_are_not_mistaken_for_the_end():
    # Messages delayed far longer than a whole turn of the ring.
    for seed in range(4):
        done, last = simulate(2, 2, seed, work=20, max_delay=400)
        assert done >= last


def test_states_run_in_order_to_done():
    t = Termination(0)
    p = Packet.start(1)
    seen = []
    for _ in range(12):
        p = t.pass_on(p)
        seen.append(p.state)
    assert [s for s in dict.fromkeys(seen)] == [
        State.DOWNLOAD,
        State.TRACE,
        State.REFINE,
        State.FLUSH,
        State.DONE,
    ]
    assert t.advances == [State.TRACE, State.REFINE, State.FLUSH, State.DONE]


def test_a_render_without_adaptive_sampling_goes_from_trace_to_done():
    # REFINE and FLUSH hold nothing without adaptive sampling; each cost the packet its
    # rounds of the ring (simulated 16x16 image space: wall 39 against 204 on the busiest
    # node, 56 without them). With adaptive sampling every state is kept, in order.
    from protocols.state import states_of

    for adaptive, want in (
        (False, [State.DOWNLOAD, State.TRACE, State.DONE]),
        (True, list(State)),
    ):
        t = Termination(0, states_of(adaptive))
        p = Packet.start(1)
        seen = []
        for _ in range(12):
            p = t.pass_on(p)
            seen.append(p.state)
        assert list(dict.fromkeys(seen)) == want
        assert t.advances == want[1:]
