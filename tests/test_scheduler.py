"""The node's scheduler alone (no sockets, no clock): what it traces first, what it holds
back, when it passes a termination wave on and answers it, and that a mesh of one walks every
state once."""

import numpy as np
import pytest

from meshnode.mesh import scheduler
from meshnode.mesh.feeds import Primaries
from meshnode.mesh.scheduler import Scheduler
from meshnode.mesh.steps import Enter, Flush, SendEcho, SendProbe, Trace
from meshnode.mesh.termination import Echo, Probe
from protocols.dtypes import RAY
from protocols.errors import BadFrame
from protocols.state import State


def rays(n: int) -> np.ndarray:
    return np.zeros(n, RAY)


def tracing(threads: int = 1, high: int = 1000, children=()) -> Scheduler:
    """Node 1, child of node 0, in TRACE with three primary batches of 10 rays."""
    s = Scheduler(1, 0, children, threads, high)
    s.probe_in(Probe(1, int(State.TRACE)))
    assert s.next() == Enter(State.TRACE)
    s.primaries = Primaries(rays(10) for _ in range(3))
    return s


def test_a_wave_goes_on_to_the_children_before_this_node_enters_its_state():
    # Held until this node's primaries were done, a wave bringing TRACE started the nodes
    # below it seconds late; passed on at once, it cannot end the state early: this node
    # answers only once idle.
    s = Scheduler(1, 0, (2, 5))
    s.probe_in(Probe(1, int(State.TRACE)))
    trace = Probe(1, int(State.TRACE))
    assert [s.next(), s.next()] == [SendProbe(trace, 2), SendProbe(trace, 5)]
    assert s.next() == Enter(State.TRACE)
    s.primaries = Primaries([rays(10)])
    assert isinstance(s.next(), Trace)
    s.echo_in(2, Echo(1, False, 0, 0))
    s.echo_in(5, Echo(1, False, 3, 1))
    assert s.next() is None  # busy: the wave waits
    s.batch_done()
    assert s.next() == Flush()
    assert s.next() == SendEcho(Echo(1, False, 3, 1), 0)  # its children's counts and its own
    assert s.next() is None
    s.probe_in(Probe(2, int(State.TRACE)))
    s.next(), s.next()  # on to the children
    assert s.next() is None  # the children have not answered wave 2
    s.echo_in(2, Echo(2, False, 0, 0))
    s.rays_in(rays(4))  # a message came: the wave waits, and this node is dirty
    assert isinstance(s.next(), Trace)
    s.batch_done()
    assert s.next() == Flush()
    s.echo_in(5, Echo(2, False, 3, 3))
    assert s.next() == SendEcho(Echo(2, True, 3, 4), 0)
    assert not s.term.dirty


def test_the_root_judges_each_wave_and_starts_the_next():
    s = Scheduler(0, None, (1,), states=(State.DOWNLOAD, State.TRACE, State.DONE))
    assert s.next() == SendProbe(Probe(1, int(State.DOWNLOAD)), 1)  # its own first wave
    assert s.next() is None
    s.echo_in(1, Echo(1, False, 0, 0))
    assert s.next() == SendProbe(Probe(2, int(State.TRACE)), 1)  # clean: TRACE
    assert s.next() == Enter(State.TRACE)
    s.echo_in(1, Echo(2, True, 4, 2))
    assert s.next() == SendProbe(Probe(3, int(State.TRACE)), 1)  # dirty: once more
    s.echo_in(1, Echo(3, False, 4, 2))
    assert s.next() == SendProbe(Probe(4, int(State.TRACE)), 1)  # two messages in flight
    s.message_in()
    s.message_in()
    s.echo_in(1, Echo(4, False, 4, 2))
    assert s.next() == SendProbe(Probe(5, int(State.TRACE)), 1)  # the root took them: dirty
    s.echo_in(1, Echo(5, False, 4, 2))
    assert s.next() == SendProbe(Probe(6, int(State.DONE)), 1)
    assert s.next() == Enter(State.DONE)
    assert s.next() is None and s.done


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
    assert s.next(room=False) is None  # primaries wait for room; the wave waits for them
    assert isinstance(s.next(room=True), Trace)


def test_output_is_flushed_before_the_node_answers_and_the_wave_waits_for_work():
    s = tracing()
    for _ in range(3):
        assert isinstance(s.next(), Trace)
        s.batch_done()
    assert s.next() == Flush()
    # its own primaries done, nothing received: its work cannot wake another node
    assert s.next() == SendEcho(Echo(1, False, 0, 0), 0)
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


def test_a_mesh_of_one_walks_every_state_once_and_stops():
    s = Scheduler(0)
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


def test_a_probe_out_of_turn_is_refused_as_it_arrives():
    # The fuzzer's neighbour sent STATE with wave 3 first: refused in the work loop, it was
    # a traceback there; refused as it arrives, it fails the parent's link by name.
    s = Scheduler(1, 0)
    for wave in (0, 2, 3, 1 << 40):
        with pytest.raises(BadFrame, match=f"STATE: wave {wave} in state"):
            s.probe_in(Probe(wave, int(State.TRACE)))
    s.probe_in(Probe(1, int(State.TRACE)))
    with pytest.raises(BadFrame):
        s.probe_in(Probe(2, int(State.TRACE)))  # the first is not taken yet
