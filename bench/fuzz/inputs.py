"""What a hostile peer sends: odd values, mutations of messages, trees and records, and the
well-formed messages they start from; random but seeded, so a failing run can be replayed."""

import math
import random

import numpy as np

from bench.fuzz.node import CLUSTER
from protocols import dtypes
from protocols.framing import encode
from protocols.handshake import hello, nonce
from protocols.messages import FIELDS, OBJECT_TABLES, Kind, make

ODD_NUMBERS = [
    0,
    1,
    -1,
    2,
    3,
    7,
    255,
    256,
    65535,
    65536,
    2**31 - 1,
    2**31,
    -(2**31) - 1,
    2**63 - 1,
    -(2**63),
    2**64 - 1,
    0.5,
    -0.0,
    5e-324,
    1e-300,
    1e300,
    1e308,
    -1e308,
    math.inf,
    -math.inf,
    math.nan,
    True,
    False,
]


def odd_scalar(rng: random.Random):
    """A value a hostile peer might send: odd numbers, strings, bytes, None, wire arrays."""
    r = rng.random()
    if r < 0.4:
        return rng.choice(ODD_NUMBERS)
    if r < 0.55:
        return rng.randint(-(2**63), 2**64 - 1)
    if r < 0.65:
        return rng.uniform(-1e6, 1e6)
    if r < 0.75:
        return rng.choice(["", "x", "auto", "even", "nan", "1", "\u00e9\u0000", "a" * 300])
    if r < 0.82:
        return rng.randbytes(rng.randint(0, 40))
    if r < 0.87:
        return None
    return wire_array(rng)


def odd_value(rng: random.Random, depth: int = 0):
    """An odd scalar, or lists and maps of them (two levels at most)."""
    r = rng.random()
    if depth < 2 and r < 0.1:
        return [odd_value(rng, depth + 1) for _ in range(rng.randint(0, 3))]
    if depth < 2 and r < 0.18:
        return {odd_key(rng): odd_value(rng, depth + 1) for _ in range(rng.randint(0, 3))}
    return odd_scalar(rng)


def odd_key(rng: random.Random):
    """A field name: a real one of some kind, "k", or text or bytes (bytes keys included)."""
    r = rng.random()
    if r < 0.5:
        return rng.choice(sorted({f for spec in FIELDS.values() for f in spec} | {"k"}))
    if r < 0.8:
        return rng.choice(["", "x", "node ", "K", "\u00e9"])
    return rng.randbytes(rng.randint(0, 4))


def wire_array(rng: random.Random, dtype=None, n=None) -> np.ndarray:
    """An array of a wire dtype with records of arbitrary bytes (NaN, huge, negative values)."""
    dtype = dtype if dtype is not None else rng.choice(list(dtypes.WIRE_DTYPES.values()))
    n = rng.randint(0, 4) if n is None else n
    return np.frombuffer(rng.randbytes(n * dtype.itemsize), dtype).copy()


def mutate_message(rng: random.Random, message: dict) -> dict:
    """1 to 3 top-level changes: a field dropped, added, retyped, an array of another dtype."""
    m = dict(message)
    for _ in range(rng.randint(1, 3)):
        op = rng.choice(["drop", "add", "retype", "array", "kind"])
        if op == "drop" and m:
            del m[rng.choice(list(m))]
        elif op == "add":
            m[odd_key(rng)] = odd_value(rng)
        elif op == "retype" and m:
            m[rng.choice(list(m))] = odd_value(rng)
        elif op == "array":
            arrays = [k for k, v in m.items() if isinstance(v, np.ndarray)]
            if arrays:
                m[rng.choice(arrays)] = wire_array(rng)
        elif op == "kind":
            m["k"] = rng.choice([*range(0, 16), -1, 2**40, None, "1", 1.0])
    return m


def mutate_tree(rng: random.Random, tree, changes: int = 3):
    """Changes anywhere inside a tree of dicts and lists: a value replaced by an odd one,
    removed, wrapped in a list, a list grown, a key added, an array swapped."""
    for _ in range(rng.randint(1, changes)):
        parent, key, node = None, None, tree
        while isinstance(node, dict | list) and node and (parent is None or rng.random() < 0.7):
            parent, key = (
                node,
                rng.choice(list(node) if isinstance(node, dict) else range(len(node))),
            )
            node = parent[key]
        if parent is None:
            return tree
        op = rng.choice(["replace", "replace", "replace", "drop", "wrap", "grow", "add"])
        if op == "replace":
            parent[key] = odd_value(rng)
        elif op == "drop":
            del parent[key]
        elif op == "wrap":
            parent[key] = [node]
        elif op == "grow" and isinstance(node, list) and node:
            node.extend([node[0]] * rng.choice([1, 2, 1023, 1024, 5000]))
        elif isinstance(parent, dict):
            parent[odd_key(rng)] = odd_value(rng)
        else:
            parent.insert(rng.randint(0, len(parent)), odd_value(rng))
    return tree


def mutate_records(rng: random.Random, records: np.ndarray, tame: bool = False) -> np.ndarray:
    """Records with some fields set to odd values (NaN, infinite, huge, negative, out of any
    table's range), or some bytes replaced; `tame`: floats stay finite and within 1e6 (the
    known wedges come from non-finite and overflowing geometry)."""
    out = np.array(records)
    if len(out) == 0:
        return out
    for _ in range(rng.randint(1, 4)):
        i = rng.randrange(len(out))
        if out.dtype.names is None or (rng.random() < 0.2 and not tame):
            raw = bytearray(out.tobytes())
            at = rng.randrange(len(raw))
            raw[at : at + 8] = rng.randbytes(min(8, len(raw) - at))
            out = np.frombuffer(bytes(raw), out.dtype).copy()
            continue
        name = rng.choice(out.dtype.names)
        kind = out.dtype[name].base.kind
        if kind == "f":
            value = rng.choice(
                [0.0, -1.0, 1e-300, 1e6, -1e6, 0.5]
                if tame
                else [math.nan, math.inf, -math.inf, 1e300, -1e300, 0.0, -1.0, 1e-300]
            )
        else:
            info = np.iinfo(out.dtype[name].base)
            value = rng.choice([info.min, info.max, -1, 0, 1, 2, 3, 7, 1000, 2**31 - 1])
            value = min(max(value, info.min), info.max)
        out[name][i] = value
    return out


def framed(message: dict) -> bytes | None:
    """The message as a frame, or None when a mutation made it unframeable (too big, a
    value msgpack cannot hold): such a case is skipped, it never reaches the node."""
    try:
        return encode(message)
    except (TypeError, ValueError, OverflowError):
        return None


def kind_of(message: dict):
    """The "k" of a message we made, when it is an int (mutations put anything there)."""
    k = message.get("k")
    return k if isinstance(k, int) else None


def valid_message(kind: Kind, rng: random.Random) -> dict:
    """A well-formed message of `kind`: HELLO and OBJECTS as senders make them, others from
    FIELDS."""
    n = rng.randint(0, 3)
    if kind is Kind.HELLO:
        return hello(CLUSTER, "host", -1, nonce())
    if kind is Kind.OBJECTS:
        table = rng.choice(sorted(OBJECT_TABLES))
        return make(
            kind, node=0, table=table, records=np.zeros(n, OBJECT_TABLES[table]), last=False
        )
    plain = {
        int: n,
        str: "boom",
        bytes: b"\2" * 32,
        bool: False,
        dict: {"a": n},
        list: list(range(n)),
    }
    return make(
        kind,
        **{
            name: np.zeros(n, want) if isinstance(want, np.dtype) else plain[want]
            for name, want in FIELDS[kind].items()
        },
    )
