"""Who may open a connection to a node, as hardened servers decide it (OpenSSH's MaxStartups,
nginx's limit_conn): a stranger without the secret must not be able to stop a render.

Connections still in the handshake (not yet proved the cluster secret) share a small pool,
at most a few from any one address, each with a short deadline; when the pool is full a
newcomer takes the place of the oldest (a real peer proves the secret in milliseconds, a
stalling one is what the pool is full of). Authenticated links have a capacity of their own
that unauthenticated sockets never take. Refusals are logged at a bounded rate. Pure
bookkeeping: the server (`meshnode.service.server`) opens and closes the connections.
"""

import logging
import time
from collections import Counter, OrderedDict

HANDSHAKING = 32  # connections proving the secret at once, from everyone
PER_ADDRESS = 8  # ... from one address (a local mesh's node may be dialled by its host and
# four neighbours at once, all from 127.0.0.1)
ADMIT_SECONDS = 5.0  # a connection that has not proved the secret by then is dropped
AUTHENTICATED = 64  # authenticated links at once (a node needs its host and four neighbours)
LOG_EVERY = 10.0  # seconds: refusals past the first in an interval are counted, then logged


class Admission:
    """The pool of connections still in the handshake (`waiting`: key -> address, oldest
    first) and the count of authenticated links."""

    def __init__(self, handshaking: int = HANDSHAKING, per_address: int = PER_ADDRESS):
        self.handshaking, self.per_address = handshaking, per_address
        self.waiting: OrderedDict = OrderedDict()
        self.from_address: Counter = Counter()
        self.authenticated = 0

    def arrive(self, key, address: str) -> tuple[bool, list]:
        """(admitted, keys to drop) for a new connection from `address`: refused when its
        address already has PER_ADDRESS in the handshake; else admitted, the oldest waiting
        connection dropped to make room when the pool is full."""
        if self.from_address[address] >= self.per_address:
            return False, []
        dropped = []
        while len(self.waiting) >= self.handshaking:
            old, _ = next(iter(self.waiting.items()))
            self.leave(old)
            dropped.append(old)
        self.waiting[key] = address
        self.from_address[address] += 1
        return True, dropped

    def leave(self, key) -> None:
        """A connection left the handshake (proved the secret, failed, or was dropped)."""
        address = self.waiting.pop(key, None)
        if address is not None:
            self.from_address[address] -= 1
            if not self.from_address[address]:
                del self.from_address[address]

    def authenticate(self) -> bool:
        """Whether an authenticated link may stay (counted until `closed`)."""
        if self.authenticated >= AUTHENTICATED:
            return False
        self.authenticated += 1
        return True

    def closed(self) -> None:
        """An authenticated link closed."""
        self.authenticated -= 1


class RefusalLog:
    """Refused connections logged at a bounded rate: the first of each LOG_EVERY seconds as
    it happens, the rest as one count when the next interval's first comes (a flood of
    strangers must not grow the log without bound)."""

    def __init__(self, log: logging.Logger, every: float = LOG_EVERY, clock=time.monotonic):
        self.log, self.every, self.clock = log, every, clock
        self.since = -float("inf")
        self.held = 0
        self.total = 0  # refusals since the node started

    def refused(self, peer: str, why: str) -> None:
        self.total += 1
        now = self.clock()
        if now - self.since < self.every:
            self.held += 1
            return
        more = (
            f" ({self.held} more refused in the last {now - self.since:.0f} s)" if self.held else ""
        )
        self.log.warning("refused %s: %s%s", peer, why, more)
        self.since, self.held = now, 0
