"""A node's deposits for the host, gathered into packets (`DepositPackets`).

Kept apart from `session`: this decides only when a packet goes; the session says how one is
sent (`Sends.to_host`) and when the frame's end or a tile traced whole needs everything now.
"""

import asyncio
import time

import numpy as np

from protocols.records import joined

DEPOSIT_BATCH = 32768  # deposits per pixel packet, sent sooner once the oldest waited:
DEPOSIT_SECONDS = 0.25  # (a live view's frames come as often; they had waited for a third
# of a node's pixels: object space 2x2 at 640x640 showed its first at 65% of the eye rays)


class DepositPackets:
    """Deposits buffered for the host and sent by `to_host(deposits)` in packets of at most
    `batch`: once `batch` wait, once the oldest has waited `seconds` (a timer, so an idle
    node's last few go too), or when `send` is told. A node no longer sends what it holds
    each time it idles: balls 3x3 under a quarter share sent 20-70 packets a node and
    render so, most of a few hundred deposits, each a message for both ends' event loops."""

    def __init__(self, to_host, batch: int = DEPOSIT_BATCH, seconds: float = DEPOSIT_SECONDS):
        self.to_host, self.batch, self.seconds = to_host, batch, seconds
        self.parts: list[np.ndarray] = []
        self.held = 0
        self.since = 0.0  # when the oldest held came
        self.timer: asyncio.TimerHandle | None = None
        self.packets = 0  # posted this render

    def add(self, deposits: np.ndarray) -> None:
        """Hold `deposits`; post what is held once a packet's worth or an old one waits."""
        now = time.monotonic()
        if not self.parts:
            self.since = now
            self._arm()
        self.parts.append(deposits)
        self.held += len(deposits)
        if self.held >= self.batch or now - self.since >= self.seconds:
            self.send()

    def send(self) -> None:
        """Post everything held now, in packets of at most `batch`."""
        self._disarm()
        if not self.parts:
            return
        held = joined(self.parts)
        self.parts, self.held = [], 0
        for i in range(0, len(held), self.batch):
            self.to_host(held[i : i + self.batch])
            self.packets += 1

    def close(self) -> None:
        """The render is over or given up: no timer may post after it."""
        self._disarm()

    def _arm(self) -> None:
        if self.timer is None:
            self.timer = asyncio.get_running_loop().call_later(self.seconds, self._due)

    def _disarm(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None

    def _due(self) -> None:
        self.timer = None
        self.send()
