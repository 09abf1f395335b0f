"""The opening message of every link: protocol version and cluster id must match."""

from protocols.errors import VersionMismatch
from protocols.messages import PROTOCOL_VERSION, Kind, make, parse

ROLES = ("host", "node")


def hello(cluster: str, role: str, node: int = -1) -> dict:
    """What a side says first: who it is (role host or node, node index) and what it speaks."""
    if role not in ROLES:
        raise ValueError(f"role must be one of {ROLES}")
    return make(Kind.HELLO, version=PROTOCOL_VERSION, cluster=cluster, role=role, node=node)


def check_hello(message: dict, cluster: str) -> dict:
    """The peer's HELLO fields, or VersionMismatch naming what differs."""
    kind, fields = parse(message)
    if kind is not Kind.HELLO:
        raise VersionMismatch(f"expected HELLO first, got {kind.name}")
    if fields["version"] != PROTOCOL_VERSION:
        raise VersionMismatch(
            f"peer speaks protocol {fields['version']}, this side {PROTOCOL_VERSION}"
        )
    if fields["cluster"] != cluster:
        raise VersionMismatch(f"peer is in cluster {fields['cluster']!r}, not {cluster!r}")
    if fields["role"] not in ROLES:
        raise VersionMismatch(f"peer claims unknown role {fields['role']!r}")
    return fields
