"""The opening of every link: protocol version, cluster id, and mutual proof of the secret.

    dialler  -> HELLO  version, cluster, role, node, nonce_d, render
    listener -> HELLO  version, cluster, "node", its node, nonce_l, b"", its free memory
    listener -> AUTH   HMAC-SHA256(secret, "listener" | cluster | role | node | nonce_d | nonce_l)
    dialler  -> AUTH   HMAC-SHA256(secret, "dialler"  | cluster | role | node | nonce_d | nonce_l)

Each side proves it holds the cluster secret over both fresh nonces, so a recorded handshake
cannot be replayed and neither side learns anything it could use without the secret; the
dialler's claimed role and node index are inside both proofs, so nobody in between can change
them. A node dialling a neighbour names the render the link is for (CONFIG.render_id), also
inside both proofs: a node still busy with a given-up render cannot pass for a neighbour in
the next one. Nothing but these messages is accepted before the listener has checked the dialler's
proof. A cluster without a secret (loopback development) proves with the empty key: the same
code path, and a side with a secret refuses a side without one.
"""

import hashlib
import hmac
import os
import secrets

from protocols.errors import AuthFailed, VersionMismatch
from protocols.messages import PROTOCOL_VERSION, Kind, make, parse

ROLES = ("host", "node")
NONCE_BYTES = 32
RENDER_ID_BYTES = 16


def nonce() -> bytes:
    return secrets.token_bytes(NONCE_BYTES)


def hello(
    cluster: str,
    role: str,
    node: int = -1,
    nonce: bytes = b"\0" * NONCE_BYTES,
    render: bytes = b"",
    memory: int = 0,
) -> dict:
    """What a side says first: who it is (role host or node, node index, and for a node's
    link to a neighbour the render it is for), what it speaks, its fresh nonce, and (a
    listening node) the memory it can give a render."""
    if role not in ROLES:
        raise ValueError(f"role must be one of {ROLES}")
    return make(
        Kind.HELLO,
        version=PROTOCOL_VERSION,
        cluster=cluster,
        role=role,
        node=node,
        nonce=nonce,
        render=render,
        memory=memory,
    )


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
    if len(fields["nonce"]) != NONCE_BYTES:
        raise VersionMismatch(f"peer's nonce has {len(fields['nonce'])} bytes, not {NONCE_BYTES}")
    if not 0 <= fields["memory"] < 1 << 62:
        raise VersionMismatch(f"peer reports {fields['memory']} bytes of memory")
    if len(fields["render"]) not in (0, RENDER_ID_BYTES):
        raise VersionMismatch(
            f"peer's render id has {len(fields['render'])} bytes, not {RENDER_ID_BYTES}"
        )
    return fields


def proof(secret: bytes, speaker: str, dialler: dict, listener_nonce: bytes) -> bytes:
    """HMAC-SHA256 over who speaks and everything the dialler claimed, both nonces."""
    parts = [
        b"meshtrace-auth",
        speaker.encode(),
        dialler["cluster"].encode(),
        dialler["role"].encode(),
        str(dialler["node"]).encode(),
        dialler["nonce"],
        dialler["render"],
        listener_nonce,
    ]
    body = b"|".join(len(p).to_bytes(4, "big") + p for p in parts)
    return hmac.new(secret, body, hashlib.sha256).digest()


def auth(secret: bytes, speaker: str, dialler: dict, listener_nonce: bytes) -> dict:
    return make(Kind.AUTH, proof=proof(secret, speaker, dialler, listener_nonce))


def check_auth(
    message: dict, secret: bytes, speaker: str, dialler: dict, listener_nonce: bytes
) -> None:
    """AuthFailed unless the message is `speaker`'s AUTH proving the cluster secret."""
    kind, fields = parse(message)
    if kind is not Kind.AUTH:
        raise AuthFailed(f"expected AUTH from the {speaker}, got {kind.name}")
    want = proof(secret, speaker, dialler, listener_nonce)
    if not hmac.compare_digest(fields["proof"], want):
        # Each side knows only that the proofs differ, and whether it has a secret itself:
        # with none here, the other side proves one (two empty keys would agree).
        if not secret:
            raise AuthFailed(
                f"this side has no cluster secret and the {speaker} proves one (set "
                "MESHTRACE_SECRET or --secret-file here)"
            )
        raise AuthFailed(
            f"the {speaker} does not hold this side's secret: it has another one or none "
            "(the two sides' MESHTRACE_SECRET / --secret-file differ)"
        )


# The shortest cluster secret taken: a short one can be guessed offline from one recorded
# handshake (its proofs are HMACs of public nonces). `openssl rand -hex 32` gives 64.
MIN_SECRET = 32


def read_secret(path=None, environ=None) -> bytes | None:
    """The cluster secret: the file at `path` (surrounding white space dropped), else the
    MESHTRACE_SECRET environment variable, else None (no secret: loopback only). A secret
    under MIN_SECRET characters is refused, naming where it came from (a compose file or a
    Kubernetes Secret passes it on as it is)."""
    if path is not None:
        with open(path, "rb") as f:
            secret = f.read().strip()
        if not secret:
            raise ValueError(f"{path}: the secret file is empty")
        return _long_enough(secret, str(path))
    value = (os.environ if environ is None else environ).get("MESHTRACE_SECRET", "")
    return _long_enough(value.encode(), "MESHTRACE_SECRET") if value else None


def _long_enough(secret: bytes, where: str) -> bytes:
    if len(secret) < MIN_SECRET:
        raise ValueError(
            f"{where}: the cluster secret has {len(secret)} characters, at least {MIN_SECRET} "
            "are needed (openssl rand -hex 32 makes one)"
        )
    return secret
