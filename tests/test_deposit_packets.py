"""A node's deposits for the host: every deposit reaches the host once, in order, in packets
of at most a batch; a few held while the node idles still go, by the timer."""

import asyncio
from functools import partial
from types import SimpleNamespace

import numpy as np

from meshnode.service.depositpackets import DepositPackets
from meshnode.service.sends import Sends
from protocols.dtypes import DEPOSIT
from protocols.messages import Kind


class Outbox:
    """The host's outbox as a session's `to_host` uses it: keeps what is posted, says when."""

    def __init__(self):
        self.posted: list[tuple[dict, int]] = []
        self.arrived = asyncio.Event()

    def post(self, message: dict, size: int = 0) -> None:
        self.posted.append((message, size))
        self.arrived.set()

    def deposits(self) -> np.ndarray:
        assert all(m["k"] == Kind.PIXELS and m["dest"] == -1 for m, _ in self.posted)
        parts = [m["deposits"] for m, _ in self.posted]
        return np.concatenate(parts) if parts else np.zeros(0, DEPOSIT)


def buffer(out: Outbox, **options) -> DepositPackets:
    """A node's packets, sent as its session sends them (`Sends.to_host`) onto `out`."""
    return DepositPackets(partial(Sends.to_host, SimpleNamespace(host_out=out)), **options)


def deposits(n: int, first: int) -> np.ndarray:
    d = np.zeros(n, DEPOSIT)
    d["pixel"] = np.arange(first, first + n)
    return d


async def test_full_packets_go_at_once_and_the_rest_when_told():
    out = Outbox()
    packets = buffer(out, batch=100, seconds=60.0)
    sent = [deposits(n, i * 1000) for i, n in enumerate((40, 50, 30, 7))]
    packets.add(sent[0])
    packets.add(sent[1])
    assert out.posted == []  # 90 held: under a packet, and none old
    packets.add(sent[2])  # 120: one packet of 100, then 20
    assert [len(m["deposits"]) for m, _ in out.posted] == [100, 20]
    assert [size for _, size in out.posted] == [100 * DEPOSIT.itemsize, 20 * DEPOSIT.itemsize]
    packets.add(sent[3])
    assert len(out.posted) == 2
    packets.send()  # the frame's end: what is held goes now
    assert packets.packets == 3 and packets.timer is None
    assert np.array_equal(out.deposits(), np.concatenate(sent))


async def test_an_idle_nodes_last_deposits_go_by_the_timer():
    out = Outbox()
    packets = buffer(out, batch=100, seconds=0.01)
    held = deposits(5, 0)
    packets.add(held)
    assert out.posted == []
    await asyncio.wait_for(out.arrived.wait(), 10.0)
    assert np.array_equal(out.deposits(), held) and packets.timer is None


async def test_closed_packets_set_no_timer_going():
    out = Outbox()
    packets = buffer(out, batch=100, seconds=60.0)
    packets.add(deposits(5, 0))
    timer = packets.timer
    packets.close()
    assert timer.cancelled() and packets.timer is None
