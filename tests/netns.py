"""Network namespaces for tests: every mesh node on its own network stack, joined by a bridge
through veth pairs, so rays cross real (virtual) network devices with their own addresses,
MTUs and rate limits, and a node can be cut off by taking its link down.

Needs root and iproute2 (`ip`, `tc`); `available()` says whether this machine has them.
"""

import os
import secrets
import subprocess
from contextlib import contextmanager

from host.run.localmesh import LocalMesh


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


def available() -> bool:
    """Whether namespaces can be made here (root, iproute2, a kernel that allows it)."""
    if os.geteuid() != 0:
        return False
    name = f"mtprobe{os.getpid() % 100000}"
    try:
        _ip("netns", "add", name)
        _ip("netns", "del", name)
        return True
    except (OSError, subprocess.CalledProcessError):
        return False


class Network:
    """A bridge in this namespace and one namespace per node on it, at 10.213.X.(10 + i)."""

    def __init__(self, n: int):
        tag = os.getpid() % 100000
        self.n, self.tag = n, tag
        self.bridge = f"mt{tag}br"
        self.subnet = f"10.213.{tag % 250}"
        self.spaces = [f"mt{tag}n{i}" for i in range(n)]
        self.outer = [f"mt{tag}o{i}" for i in range(n)]  # bridge side of node i's cable
        self.inner = [f"mt{tag}i{i}" for i in range(n)]  # node side

    def address(self, i: int, port: int = 7700) -> str:
        return f"{self.subnet}.{10 + i}:{port}"

    def up(self) -> None:
        self.down()  # leftovers of a killed run with the same pid
        _ip("link", "add", self.bridge, "type", "bridge")
        _ip("addr", "add", f"{self.subnet}.1/24", "dev", self.bridge)
        _ip("link", "set", self.bridge, "up")
        for i, ns in enumerate(self.spaces):
            _ip("netns", "add", ns)
            _ip("link", "add", self.outer[i], "type", "veth", "peer", "name", self.inner[i])
            _ip("link", "set", self.outer[i], "master", self.bridge)
            _ip("link", "set", self.outer[i], "up")
            _ip("link", "set", self.inner[i], "netns", ns)
            _ip("-n", ns, "addr", "add", f"{self.subnet}.{10 + i}/24", "dev", self.inner[i])
            _ip("-n", ns, "link", "set", self.inner[i], "up")
            _ip("-n", ns, "link", "set", "lo", "up")

    def shape(self, i: int, mtu: int | None = None, rate: str | None = None) -> None:
        """Node i's cable: a smaller MTU, and/or a token-bucket rate limit (e.g. '200mbit').
        (Delays need the netem qdisc, which kernels here lack: tests.faultnode delays a link
        in the node instead.)"""
        if mtu:
            _ip("-n", self.spaces[i], "link", "set", self.inner[i], "mtu", str(mtu))
        if rate:
            subprocess.run(
                [
                    "ip",
                    "netns",
                    "exec",
                    self.spaces[i],
                    "tc",
                    "qdisc",
                    "add",
                    "dev",
                    self.inner[i],
                    "root",
                    "tbf",
                    "rate",
                    rate,
                    "burst",
                    "64kb",
                    "latency",
                    "100ms",
                ],
                check=True,
                capture_output=True,
            )

    def cut(self, i: int) -> None:
        """Take node i's cable down: the node lives on, unreachable."""
        _ip("link", "set", self.outer[i], "down")

    def down(self) -> None:
        """Delete the cables (a namespace outlives its processes while sockets close, and
        keeps its cable up with it), the namespaces and the bridge."""
        for outer in self.outer:
            subprocess.run(["ip", "link", "del", outer], capture_output=True)
        for ns in self.spaces:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        subprocess.run(["ip", "link", "del", self.bridge], capture_output=True)


@contextmanager
def namespaced_mesh(n: int, shape=None, **node_options):
    """(network, mesh, addresses): n meshnode processes, node i in namespace i, sharing the
    secret `mesh.secret`; `shape(net)` may shape the cables before the nodes start;
    `node_options` go to LocalMesh (module, options, env: nodes with injected faults)."""
    net = Network(n)
    try:
        net.up()
        if shape:
            shape(net)
        wrap = lambda i: ["ip", "netns", "exec", net.spaces[i]]  # noqa: E731
        # Beyond loopback every node needs the cluster secret: the real, authenticated setup.
        mesh = LocalMesh(
            n,
            listen=[net.address(i) for i in range(n)],
            wrap=wrap,
            secret=secrets.token_hex(16).encode(),
            **node_options,
        )
        with mesh as addresses:
            yield net, mesh, addresses
    finally:
        net.down()
