"""Rays relayed through a node (`Driver.relay`): they wait with the node's own leaving rays
for its next send over their link, at most one batch, and are flushed before the node idles
or answers a wave (`test_ray_sets`: a mesh that relays renders one node's image and counts)."""

import numpy as np

from meshnode.mesh.driver import Driver
from meshnode.mesh.node import Batch
from meshnode.mesh.scheduler import Scheduler
from meshnode.mesh.steps import Enter, Flush, SendEcho, Trace
from meshnode.mesh.termination import Probe
from protocols.dtypes import RAY
from protocols.state import State


class _Core:
    takers = list(range(9))  # each cell's rays go to its owner


class _Sent(Driver):
    """A driver that records what it sends instead of sending."""

    def __init__(self, sched):
        super().__init__(1, sched, _Core())
        self.sent: list[list] = []

    def post_rays_set(self, sends: list) -> None:
        self.sent.append([(d, len(r), c) for d, r, c in sends])

    def start(self, step: Trace) -> None:
        pass


def _in_trace() -> tuple[Scheduler, _Sent]:
    s = Scheduler(1, 0)
    s.probe_in(Probe(1, int(State.TRACE)))
    assert s.next() == Enter(State.TRACE)
    return s, _Sent(s)


def _done(d: _Sent, outgoing: dict) -> None:
    d.sched.batch_done()
    d.deliver(Batch({}, outgoing, {}, {}))


def test_relayed_rays_go_with_the_next_batchs_rays_over_their_link():
    s, d = _in_trace()
    s.rays_in(np.zeros(5, RAY))
    step = s.next()
    assert isinstance(step, Trace)
    d.relay([(4, np.zeros(3, RAY), 4), (7, np.zeros(2, RAY), 6)])
    assert d.sent == []  # a batch is being traced: they wait for its end
    _done(d, {4: [np.zeros(6, RAY)]})
    # due at the batch's end, with the batch's own rays for the same node and cell
    assert sorted(sum(d.sent, [])) == [(4, 9, 4), (7, 2, 6)]
    assert d.leaving == {}


def test_a_node_flushes_relayed_rays_before_it_answers_a_wave():
    s, d = _in_trace()
    d.relay([(4, np.zeros(3, RAY), 4)])
    step = s.next()
    assert step == Flush()  # nothing traced here: they go at once
    d.act(step)
    assert d.sent == [[(4, 3, 4)]]
    assert isinstance(s.next(), SendEcho)
