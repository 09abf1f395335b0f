"""The node's scheduler alone (no sockets, no clock): what it traces first, what it holds
back, when it passes the state packet, and that a ring of one walks every state once."""

import numpy as np

from meshnode.mesh import scheduler
from meshnode.mesh.feeds import Primaries
from meshnode.mesh.scheduler import Scheduler
from meshnode.mesh.steps import Enter, Flush, SendPacket, Trace
from meshnode.mesh.termination import Packet
from protocols.dtypes import RAY
from protocols.state import State


def rays(n: int) -> np.ndarray:
    return np.zeros(n, RAY)


def tracing(nodes: int = 2, threads: int = 1, high: int = 1000) -> Scheduler:
    """Node 1 of a ring of `nodes`, in TRACE with three primary batches of 10 rays."""
    s = Scheduler(1, 0, nodes, threads, high)
    s.packet_in(
        Packet(int(State.TRACE), 0, 1, np.zeros(nodes, np.int64), np.zeros(nodes, np.int64))
    )
    assert s.next() == Enter(State.TRACE)
    s.primaries = Primaries(rays(10) for _ in range(3))
    step = s.next()  # the packet goes on before any primary batch (next test)
    assert isinstance(step, SendPacket) and step.to == 0
    return s


def test_a_state_with_primaries_is_handed_on_before_this_node_traces_them():
    # Held until this node's primaries were done, the packet started the nodes after it on
    # the ring seconds late (2x2: nodes 1 and 3 idle ~1 s); passed on at once, marked busy,
    # it cannot end the state early: this node is still dirty when it comes back.
    s = Scheduler(1, 0, 2)
    s.packet_in(Packet(int(State.TRACE), 0, 1, np.zeros(2, np.int64), np.zeros(2, np.int64)))
    assert s.next() == Enter(State.TRACE)
    s.primaries = Primaries([rays(10)])
    step = s.next()
    assert isinstance(step, SendPacket) and step.packet.last_busy == 1
    assert step.packet.state == State.TRACE
    assert isinstance(s.next(), Trace) and s.term.dirty
    s.packet_in(step.packet)  # back round the ring while this node traces
    assert s.next() is None  # held while busy
    s.batch_done()
    assert s.next() == Flush()
    back = s.next()
    assert isinstance(back, SendPacket) and back.packet.last_busy == 1
    assert back.packet.state == State.TRACE  # no advance: this node worked since


def test_a_clean_node_marks_the_packet_it_hands_on_with_primaries_to_trace():
    # Node 0 advanced the ring to TRACE and has no primaries; node 1, clean since its last
    # visit, hands the packet on at once. Unmarked, the packet came back to node 0 as it left
    # (last busy 0, counts balanced) and TRACE ended while node 1 still traced its primaries.
    s = Scheduler(1, 0, 2)
    s.term.dirty = False
    s.packet_in(Packet(int(State.TRACE), 0, 1, np.zeros(2, np.int64), np.zeros(2, np.int64)))
    assert s.next() == Enter(State.TRACE)
    s.primaries = Primaries([rays(10)])
    step = s.next()
    assert isinstance(step, SendPacket) and step.packet.last_busy == 1
    assert s.term.dirty  # and it stays busy for the packet's next visit


def test_passed_rays_go_first_once_enough_wait_and_threads_bound_the_batches():
    # A few dozen passed rays wait behind a primary batch (traced as they came, each message
    # paid a kernel call for microseconds of tracing); PASSED_MIN of them go first, and any
    # go at once when no primary batch can start.
    s = tracing(threads=2, high=10 * scheduler.PASSED_MIN)
    s.rays_in(rays(7))
    first = s.next()
    assert isinstance(first, Trace) and first.primary
    s.rays_in(rays(scheduler.PASSED_MIN - 7))
    second = s.next()
    assert isinstance(second, Trace) and not second.primary
    assert len(second.rays) == scheduler.PASSED_MIN
    assert s.next() is None  # two threads, two batches in flight
    s.batch_done()
    assert s.next().primary
    s.batch_done()
    s.batch_done()
    s.rays_in(rays(5))
    assert s.next().primary  # the last primary batch
    s.rays_in(rays(3))
    last = s.next()  # no primaries left: the few passed rays go at once
    assert isinstance(last, Trace) and not last.primary and len(last.rays) == 8


def test_no_new_primaries_while_the_links_are_full_but_incoming_rays_still_run():
    s = tracing()
    assert s.next(room=False) is None
    s.rays_in(rays(3))
    step = s.next(room=False)
    assert isinstance(step, Trace) and not step.primary
    s.batch_done()
    assert s.next(room=False) == Flush()  # idle: buffered deposits go out
    assert s.next(room=False) is None  # primaries wait for room; the packet waits for them
    assert isinstance(s.next(room=True), Trace)


def test_output_is_flushed_before_the_packet_moves_and_the_packet_waits_for_work():
    s = tracing()
    s.packet_in(Packet(int(State.TRACE), 1, 2, np.zeros(2, np.int64), np.zeros(2, np.int64)))
    for _ in range(3):
        assert isinstance(s.next(), Trace)
        s.batch_done()
    assert s.next() == Flush()
    step = s.next()
    assert isinstance(step, SendPacket) and step.to == 0
    assert step.packet.last_busy == 1  # it worked since the packet's last visit
    assert s.next() is None


def test_reading_stops_above_the_high_water_mark_and_resumes_at_a_quarter():
    big = scheduler.PASSED_BATCH * 3 // 5  # two of them do not fit one batch
    s = tracing(high=scheduler.PASSED_BATCH)
    assert not s.rays_in(rays(big))
    assert s.rays_in(rays(big))  # 1.2 x the mark queued: stop reading
    assert not s.may_read
    s.next()  # one message taken to trace: the other left, above a quarter
    assert not s.may_read
    s.batch_done()
    s.next()
    assert s.may_read


def test_queued_incoming_messages_are_traced_together_in_order_up_to_a_batch():
    # A neighbour's batch sends a few dozen rays here; traced one message a batch, object
    # space paid a kernel call and its routing for each.
    s = tracing(high=10 * scheduler.PASSED_BATCH)
    sizes = [30, 50, scheduler.PASSED_BATCH - 50, 40]
    for i, n in enumerate(sizes):
        r = rays(n)
        r["pixel"] = i
        s.rays_in(r)
    first = s.next()
    assert isinstance(first, Trace) and not first.primary and first.taker is None
    assert first.rays["pixel"].tolist() == [0] * 30 + [1] * 50  # the third would not fit
    s.batch_done()
    second = s.next()
    assert second.rays["pixel"].tolist() == [2] * (scheduler.PASSED_BATCH - 50) + [3] * 40
    assert s.incoming_rays == 0 and not s.incoming


def test_rays_queued_for_held_engines_are_merged_per_engine_and_traced_with_it():
    # Under copies a batch hands back the segments that leave for engines held here: each
    # engine's parts merge into one call, never into another engine's.
    s = tracing(high=10 * scheduler.PASSED_BATCH)
    s.passed_min = 0  # queued rays go before primaries however few
    # None: a neighbour's RAYS message; s.node: this node's own engine, handed back
    parts = [(None, 20), (3, 5), (s.node, 7), (4, 9), (3, 11)]
    for i, (taker, n) in enumerate(parts):
        r = rays(n)
        r["pixel"] = i
        s.rays_in(r, message=taker is None, taker=taker)
    seen = []
    while s.incoming and len(seen) < len(parts):
        step = s.next()
        assert isinstance(step, Trace) and not step.primary
        seen.append((step.taker, step.rays["pixel"].tolist()))
        s.batch_done()
    assert seen == [(None, [0] * 20 + [2] * 7), (3, [1] * 5 + [4] * 11), (4, [3] * 9)]
    assert s.incoming_rays == 0 and not s.incoming


def test_a_ring_of_one_walks_every_state_once_and_stops():
    s = Scheduler(0, 0, 1)
    entered, steps = [], 0
    while (step := s.next()) is not None and steps < 100:
        steps += 1
        if isinstance(step, Enter):
            entered.append(step.state)
            if step.state == State.TRACE:
                s.primaries = Primaries([rays(5)])
        elif isinstance(step, Trace):
            s.batch_done()
    assert entered == [State.TRACE, State.REFINE, State.FLUSH, State.DONE]
    assert s.done and steps < 100
