"""Every reader of untrusted input, fuzzed with hypothesis: the framer, the message checks, the
handshake, a node's CONFIG, the NFF reader and the camera readers take mutated valid input and
noise, and either succeed or raise their documented error, with a message that says something.

Documented errors: ProtocolError subclasses on the wire; SpecError, BadFrame or ValueError for
CONFIG; SceneError worded `source:line: ...` for NFF; CameraError naming the file for cameras.
Runs are deterministic (derandomize, no example database) and the file takes seconds.

KNOWN_BUGS lists failures found here that are reported and not fixed yet (none now): the
property tests tolerate exactly those (type and raising function) while a strict xfail test
reproduces each. The last section keeps the first bugs these tests found as regression tests.
"""

import functools
import json
import math
import struct
import tomllib
import traceback
from pathlib import Path

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, note, settings
from hypothesis import strategies as st

from host.camera.lens import Camera, CameraError
from host.camera.lensfile import read_camera, read_table, read_toml
from host.scene.nff import SceneError, parse_nff
from meshnode.service.config import Config
from protocols import dtypes
from protocols.camera import CameraSpec
from protocols.dtypes import WIRE_DTYPES
from protocols.errors import BadFrame, FrameTooLarge, ProtocolError
from protocols.framing import (
    HEADER,
    MAP,
    MAX_FRAME,
    POOL_LEAST,
    FrameDecoder,
    Payloads,
    decode_payload,
    encode,
)
from protocols.handshake import NONCE_BYTES, ROLES, auth, check_auth, check_hello, hello, proof
from protocols.messages import FIELDS, OBJECT_TABLES, PROTOCOL_VERSION, Kind, make, parse
from protocols.render import MeshPlan
from protocols.scene import SceneData
from protocols.spec import SpecError
from tests.test_node_service import config

ROOT = Path(__file__).resolve().parents[1]
CAMERAS = ROOT / "host" / "cameras"
FUZZ = settings(
    deadline=None,
    derandomize=True,
    database=None,
    print_blob=False,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.data_too_large,
        HealthCheck.function_scoped_fixture,
    ],
)


def fuzz(examples: int) -> settings:
    return settings(FUZZ, max_examples=examples)


# Reported bugs the property tests tolerate until fixed: (exception types, project file, the
# functions that raise them) -> the strict xfail test reproducing it.
KNOWN_BUGS: dict = {}


def known_bug(error: BaseException) -> str | None:
    """The xfail test of the reported bug `error` is an instance of, or None: matched on its
    type and the project function it was raised from."""
    frames = [
        f
        for f in traceback.extract_tb(error.__traceback__)
        if Path(f.filename).is_absolute() and Path(f.filename).resolve().is_relative_to(ROOT)
    ]
    if not frames:
        return None
    where = Path(frames[-1].filename).resolve().relative_to(ROOT).as_posix()
    for (types, file, functions), test in KNOWN_BUGS.items():
        if type(error) in types and where == file and frames[-1].name in functions:
            return test
    return None


def outcome(call, *documented):
    """call()'s result, or the documented error it raised (which must say something); any
    other exception fails the test unless it is a reported bug."""
    try:
        return call()
    except documented as e:
        assert str(e).strip(), f"{type(e).__name__} with an empty message"
        return e
    except Exception as e:
        if known_bug(e) is None:
            raise
        note(f"known bug {known_bug(e)}: {e!r}")
        return e


# ------------------------------------------------------------------ values a peer can send

ODD_NUMBERS = [
    0,
    1,
    -1,
    2,
    7,
    255,
    65536,
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


@st.composite
def wire_arrays(draw, names=tuple(WIRE_DTYPES)):
    """An array of a wire dtype with 0 to 3 records of arbitrary bytes (NaNs, huge values)."""
    dtype = WIRE_DTYPES[draw(st.sampled_from(names))]
    n = draw(st.integers(0, 3))
    raw = draw(st.binary(min_size=n * dtype.itemsize, max_size=n * dtype.itemsize))
    return np.frombuffer(raw, dtype).copy()


SCALARS = st.one_of(
    st.sampled_from(ODD_NUMBERS),
    st.none(),
    st.integers(-(2**63), 2**64 - 1),
    st.floats(),
    st.text(max_size=6),
    st.binary(max_size=6),
    wire_arrays(),
)
KEYS = st.one_of(
    st.sampled_from(sorted({f for spec in FIELDS.values() for f in spec} | {"k"})),
    st.text(max_size=4),
    st.binary(max_size=3),
)
VALUES = st.recursive(
    SCALARS,
    lambda kids: st.lists(kids, max_size=3) | st.dictionaries(KEYS, kids, max_size=3),
    max_leaves=6,
)


def wire(message: dict) -> dict:
    """`message` as the receiving side sees it: encoded and decoded by the framer."""
    (received,) = FrameDecoder().feed(encode(message))
    return received


def _valid(kind: Kind, n: int, flag: bool, table: str) -> dict:
    """One well-formed message of `kind` (n records, a flag, an OBJECTS table): HELLO, CONFIG
    and OBJECTS as their senders make them, any other kind from its FIELDS."""
    if kind is Kind.HELLO:
        return hello("meshtrace", "host" if flag else "node", n, b"\1" * 32)
    if kind is Kind.CONFIG:
        return config()
    if kind is Kind.OBJECTS:
        return make(kind, node=0, table=table, records=np.zeros(n, OBJECT_TABLES[table]), last=flag)
    plain = {
        int: n,
        str: "node 0: boom",
        bytes: b"\2" * 32,
        bool: flag,
        dict: {"eye": n},
        list: list(range(n)),
    }
    return make(
        kind,
        **{
            name: np.zeros(n, want) if isinstance(want, np.dtype) else plain[want]
            for name, want in FIELDS[kind].items()
        },
    )


VALID_MESSAGES = st.builds(
    _valid,
    st.sampled_from(list(Kind)),
    st.integers(0, 3),
    st.booleans(),
    st.sampled_from(sorted(OBJECT_TABLES)),
)


@st.composite
def mutated_message(draw, message: dict) -> dict:
    """`message` with 1 to 3 top-level changes: a field dropped, added (a real field name of
    any kind, text or bytes), retyped, an array swapped for another dtype, or a new kind."""
    m = dict(message)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["drop", "add", "retype", "array", "kind"]))
        if op == "drop" and m:
            del m[draw(st.sampled_from(sorted(m, key=repr)))]
        elif op == "add":
            m[draw(KEYS)] = draw(VALUES)
        elif op == "retype" and m:
            m[draw(st.sampled_from(sorted(m, key=repr)))] = draw(VALUES)
        elif op == "array":
            names = [k for k, v in m.items() if isinstance(v, np.ndarray)]
            if names:
                m[draw(st.sampled_from(names))] = draw(wire_arrays())
        else:
            m["k"] = draw(st.one_of(st.sampled_from([int(k) for k in Kind] + [0, 13, -1]), VALUES))
    return m


def assert_well_formed(kind: Kind, fields: dict) -> None:
    """What parse promises handlers: exactly the kind's fields, each of its declared type."""
    spec = FIELDS[kind]
    assert set(fields) == set(spec)
    for name, want in spec.items():
        value = fields[name]
        if isinstance(want, np.dtype):
            assert isinstance(value, np.ndarray) and value.dtype == want
        elif want is int:
            assert isinstance(value, int) and not isinstance(value, bool)
        elif want is not None:
            assert isinstance(value, want if want is not float else (int, float))
    if kind is Kind.OBJECTS:
        assert fields["records"].dtype == OBJECT_TABLES[fields["table"]]


# ------------------------------------------------------------------ framing


@st.composite
def streams(draw):
    """Bytes a peer might send: whole frames, frames of arbitrary payload, arbitrary length
    prefixes (small or huge) and raw noise, in any order."""
    parts = draw(
        st.lists(
            st.one_of(
                st.builds(
                    lambda m: encode(m), st.dictionaries(st.text(max_size=4), VALUES, max_size=3)
                ),
                st.builds(lambda p: HEADER.pack(len(p)) + p, st.binary(max_size=40)),
                st.builds(
                    lambda n, p: HEADER.pack(n) + p,
                    st.one_of(st.integers(0, 64), st.integers(0, 2**32 - 1)),
                    st.binary(max_size=40),
                ),
                st.binary(max_size=12),
            ),
            max_size=6,
        )
    )
    return b"".join(parts)


def reference(stream: bytes, max_frame: int):
    """What any split of `stream` must decode to: the messages of its leading whole frames, and
    (error type, the byte count at which it becomes detectable) or None."""
    at, messages = 0, []
    while len(stream) - at >= HEADER.size:
        (size,) = HEADER.unpack_from(stream, at)
        if size > max_frame:
            return messages, (FrameTooLarge, at + HEADER.size)
        end = at + HEADER.size + size
        if end > len(stream):
            break
        try:
            messages.append(decode_payload(stream[at + HEADER.size : end]))
        except BadFrame:
            return messages, (BadFrame, end)
        at = end
    return messages, None


@fuzz(200)
@given(
    stream=streams(),
    cuts=st.lists(st.integers(0, 400), max_size=8),
    max_frame=st.sampled_from([0, 1, 16, 64, 4096, MAX_FRAME]),
)
def test_framer_is_split_invariant_and_bounded(stream, cuts, max_frame):
    """However the bytes are split, FrameDecoder.feed yields the same messages as one walk over
    the stream and raises the same error at the chunk that makes it detectable (FrameTooLarge
    as soon as a too-large length prefix is in, before its payload); between feeds it never
    holds more than one unfinished frame (pending < header + max_frame)."""
    want, error = reference(stream, max_frame)
    bounds = sorted({c for c in cuts if c < len(stream)} | {len(stream)})
    decoder, got, fed, start = FrameDecoder(max_frame), [], 0, 0
    raised = None
    for end in bounds:
        chunk, start = stream[start:end], end
        fed += len(chunk)
        try:
            got += decoder.feed(chunk)
        except ProtocolError as e:
            raised = e
            assert str(e).strip()
            break
        assert decoder.pending < HEADER.size + max_frame or decoder.pending < HEADER.size
    if error is None or error[1] > len(stream):
        assert raised is None and [repr(m) for m in got] == [repr(m) for m in want]
    else:
        assert type(raised) is error[0] and fed - len(chunk) < error[1] <= fed
        assert [repr(m) for m in got] == [repr(m) for m in want[: len(got)]]
    assert all(isinstance(m, dict) for m in got)


@fuzz(150)
@given(
    steps=st.lists(
        st.tuples(
            st.booleans(),
            st.one_of(
                st.sampled_from([k * POOL_LEAST for k in (0.5, 1, 2, 3, 5)]).map(int),
                st.integers(0, 5 * POOL_LEAST),
            ),
            st.integers(0, 7),
        ),
        max_size=24,
    ),
    limit=st.sampled_from([0, POOL_LEAST, 3 * POOL_LEAST, 8 * POOL_LEAST]),
)
def test_payload_buffers_are_never_lent_twice_and_stay_within_their_bound(steps, limit):
    """Payloads taken and dropped in any order, of any sizes: a buffer still viewed is never
    lent again (every live buffer keeps what was written into it), and the pool keeps at most
    its limit."""
    pool, live = Payloads(limit), []
    for i, (take, size, drop) in enumerate(steps):
        if take:
            buf = pool.take(size)
            assert len(buf) == size
            buf[:] = i % 251
            live.append((buf, i % 251))
        elif live:
            live.pop(drop % len(live))
        assert all((buf == mark).all() for buf, mark in live)
        assert pool._held() <= limit


@fuzz(200)
@given(
    size=st.one_of(
        st.integers(0, 2**32 - 1),
        st.sampled_from([0, 1, 4095, 4096, 4097, MAX_FRAME, MAX_FRAME + 1]),
    ),
    max_frame=st.sampled_from([4096, MAX_FRAME]),
    body=st.binary(max_size=64),
)
def test_length_prefix_over_the_limit_is_refused_on_its_last_byte(size, max_frame, body):
    """Fed one byte at a time, a prefix announcing more than max_frame raises FrameTooLarge on
    its fourth byte with nothing else buffered; a smaller one waits for its payload (holding
    only what arrived) or decodes it, or raises BadFrame."""
    decoder = FrameDecoder(max_frame)
    data = HEADER.pack(size) + body
    for i in range(len(data)):
        try:
            decoder.feed(data[i : i + 1])
        except FrameTooLarge as e:
            assert size > max_frame and i == HEADER.size - 1 and decoder.pending == HEADER.size
            assert str(size) in str(e)
            return
        except BadFrame:
            assert i == HEADER.size + size - 1
            return
    assert size <= max_frame
    assert decoder.pending == (0 if size <= len(body) else len(data))


@st.composite
def payloads(draw):
    """Payloads of msgpack documents (maps or not, ARRAY_EXT and other extensions, bad array
    headers, non-string keys) with a right or wrong map length and bytes for arrays after
    them, truncated or with a byte flipped, or plain noise."""
    ext = st.builds(
        msgpack.ExtType,
        st.sampled_from([1, 1, 0, 2, 127]),
        st.one_of(
            st.binary(max_size=40),
            st.builds(
                lambda n, c, b: n + b"\0" + struct.pack("<Q", c) + b,
                st.sampled_from([k.encode() for k in WIRE_DTYPES] + [b"", b"x", b"ray\xff"]),
                st.sampled_from([0, 1, 2, 2**63, 2**64 - 1]),
                st.binary(max_size=96),
            ),
        ),
    )
    stamp = st.builds(msgpack.Timestamp, st.integers(0, 2**40), st.integers(0, 10**9 - 1))
    keys = st.one_of(KEYS, st.integers(-(2**63), 2**64 - 1), st.none())
    doc = st.recursive(
        st.one_of(SCALARS, ext, stamp),
        lambda kids: st.lists(kids, max_size=3) | st.dictionaries(keys, kids, max_size=3),
        max_leaves=6,
    )
    raw = msgpack.packb(draw(doc), use_bin_type=True, default=lambda a: a.tobytes())
    # a payload: the map's length, the map, then the bytes its arrays' records would be
    raw = MAP.pack(draw(st.sampled_from([len(raw), len(raw), 0, 2**32 - 1]))) + raw
    raw += draw(st.binary(max_size=96))
    how = draw(st.sampled_from(["as is", "cut", "flip", "noise"]))
    if how == "cut":
        raw = raw[: draw(st.integers(0, len(raw)))]
    elif how == "flip" and raw:
        i = draw(st.integers(0, len(raw) - 1))
        raw = raw[:i] + bytes([raw[i] ^ draw(st.integers(1, 255))]) + raw[i + 1 :]
    elif how == "noise":
        raw = draw(st.binary(max_size=64))
    return raw


@fuzz(200)
@given(payload=payloads())
def test_decode_payload_returns_a_map_or_raises_bad_frame(payload):
    """Any payload decodes to a dict (arrays only of wire dtypes, sized to their bytes) or
    raises BadFrame, never msgpack's or numpy's own errors."""
    message = outcome(lambda: decode_payload(payload), BadFrame)
    if not isinstance(message, Exception):
        assert isinstance(message, dict)

        def arrays(v):
            if isinstance(v, np.ndarray):
                yield v
            for x in v.values() if isinstance(v, dict) else v if isinstance(v, list) else ():
                yield from arrays(x)

        assert all(a.dtype in WIRE_DTYPES.values() and a.ndim == 1 for a in arrays(message))


# ------------------------------------------------------------------ messages and handshake


@fuzz(400)
@given(message=VALID_MESSAGES.flatmap(mutated_message))
def test_parse_checks_every_kind_against_its_fields(message):
    """parse on any mutated message, as received from a frame, returns exactly the kind's
    fields with their declared types (arrays of the declared dtype), or raises a
    ProtocolError that says what was wrong."""
    received = wire(message)
    result = outcome(lambda: parse(received), ProtocolError)
    if not isinstance(result, Exception):
        assert_well_formed(*result)


@fuzz(200)
@given(
    base=st.builds(
        hello,
        st.sampled_from(["meshtrace", "other", ""]),
        st.sampled_from(ROLES),
        st.integers(-1, 4),
        st.binary(min_size=32, max_size=32),
    ),
    data=st.data(),
)
def test_check_hello_accepts_only_a_matching_hello(base, data):
    """check_hello on a (mutated) HELLO returns fields only for this protocol version, this
    cluster, a known role and a full nonce; anything else is a ProtocolError."""
    message = data.draw(st.one_of(st.just(base), mutated_message(base), VALID_MESSAGES))
    fields = outcome(lambda: check_hello(wire(message), "meshtrace"), ProtocolError)
    if not isinstance(fields, Exception):
        assert fields["version"] == PROTOCOL_VERSION and fields["cluster"] == "meshtrace"
        assert fields["role"] in ROLES and len(fields["nonce"]) == NONCE_BYTES


SECRET = b"fuzz secret, as long as a cluster needs it"
DIALLER = parse(hello("meshtrace", "host", -1, b"\3" * 32))[1]
LISTENER_NONCE = b"\4" * 32


@st.composite
def auth_messages(draw):
    """The right AUTH, AUTH with another secret, speaker or nonce, a proof cut, grown or with a
    bit flipped, or any mutated message."""
    right = proof(SECRET, "dialler", DIALLER, LISTENER_NONCE)
    p = draw(
        st.sampled_from(["right", "secret", "speaker", "nonce", "cut", "grow", "flip", "mutate"])
    )
    if p == "right":
        return make(Kind.AUTH, proof=right)
    if p == "secret":
        return auth(draw(st.binary(max_size=16)), "dialler", DIALLER, LISTENER_NONCE)
    if p == "speaker":
        return auth(SECRET, "listener", DIALLER, LISTENER_NONCE)
    if p == "nonce":
        return auth(SECRET, "dialler", DIALLER, draw(st.binary(max_size=40)))
    if p == "cut":
        return make(Kind.AUTH, proof=right[: draw(st.integers(0, 31))])
    if p == "grow":
        return make(Kind.AUTH, proof=right + draw(st.binary(min_size=1, max_size=8)))
    if p == "flip":
        i, bit = draw(st.integers(0, 31)), draw(st.integers(0, 7))
        return make(Kind.AUTH, proof=right[:i] + bytes([right[i] ^ (1 << bit)]) + right[i + 1 :])
    return draw(mutated_message(make(Kind.AUTH, proof=right)))


@fuzz(200)
@given(message=auth_messages())
def test_check_auth_passes_only_the_right_proof(message):
    """check_auth returns only for an AUTH carrying exactly HMAC(secret, dialler, both nonces);
    every other message, proof or secret is refused with a ProtocolError (AuthFailed when it
    is a well-formed AUTH)."""
    received = wire(message)
    result = outcome(
        lambda: check_auth(received, SECRET, "dialler", DIALLER, LISTENER_NONCE), ProtocolError
    )
    right = make(Kind.AUTH, proof=proof(SECRET, "dialler", DIALLER, LISTENER_NONCE))
    assert (result is None) == (repr(received) == repr(right))


# ------------------------------------------------------------------ a node's CONFIG

LENS = np.zeros(1, dtypes.ELEMENT)
LENS["kind"], LENS["focal"], LENS["ax"], LENS["ay"] = dtypes.THIN_LENS, 0.05, 0.01, 0.01
CAMERA = CameraSpec(LENS, 0.036, 0.024, -0.051).to_wire()
NUMBERS = st.one_of(st.sampled_from(ODD_NUMBERS), st.integers(-(2**63), 2**64 - 1), st.floats())
ODD = st.one_of(NUMBERS, NUMBERS, SCALARS, VALUES)


@st.composite
def _position(draw, tree) -> tuple:
    """A position inside a tree of dicts and lists (arrays are leaves), found by walking down
    from the root and stopping anywhere; () only when the tree is empty."""
    at, node = (), tree
    while isinstance(node, dict | list) and node and (not at or draw(st.integers(0, 2))):
        key = draw(st.sampled_from(list(node) if isinstance(node, dict) else range(len(node))))
        at, node = (*at, key), node[key]
    return at


@st.composite
def mutated_tree(draw, tree, keys=KEYS, odd=ODD, max_changes=3):
    """`tree` with 1 to max_changes changes anywhere inside: a value replaced (by a negative,
    huge, NaN, infinite or wrongly typed one), removed, wrapped in a list, a list grown
    (copies of its first entry), an unknown key added, an array swapped or corrupted."""
    for _ in range(draw(st.integers(1, max_changes))):
        at = draw(_position(tree))
        if not at:
            break
        parent = tree
        for k in at[:-1]:
            parent = parent[k]
        key, value = at[-1], parent[at[-1]]
        op = draw(st.sampled_from(["replace", "replace", "drop", "wrap", "grow", "add"]))
        if op == "replace":
            parent[key] = draw(odd)
        elif op == "drop":
            del parent[key]
        elif op == "wrap":
            parent[key] = [value]
        elif op == "grow" and isinstance(value, list) and value:
            value.extend([value[0]] * draw(st.sampled_from([1, 2, 1023, 1024, 5000])))
        elif op == "grow" and isinstance(value, np.ndarray):
            parent[key] = draw(wire_arrays())
        elif isinstance(parent, dict):
            parent[draw(keys)] = draw(odd)
        else:
            parent.insert(draw(st.integers(0, len(parent))), draw(odd))
    return tree


@st.composite
def config_fields(draw):
    """A valid CONFIG (as tests/test_node_service.py makes it; a 1x1 to 32x32 mesh, with or
    without a camera) after the wire, then mutated anywhere inside."""
    rows, cols = draw(st.sampled_from([(1, 1), (1, 2), (2, 2), (3, 5), (32, 32), (1, 1024)]))
    fields = FrameDecoder().feed(_config_frame(rows, cols, draw(st.booleans())))[0]
    del fields["k"]
    fields["node"] = draw(st.integers(0, rows * cols - 1))
    return draw(mutated_tree(fields))


@functools.cache
def _config_frame(rows: int, cols: int, camera: bool) -> bytes:
    message = config(plan=MeshPlan(rows, cols))
    if camera:
        message["render"]["camera"] = CAMERA
    return encode(message)


@fuzz(300)
@given(fields=config_fields())
def test_config_refuses_bad_fields_with_spec_error_bad_frame_or_value_error(fields):
    """A mutated CONFIG goes through parse and then Config as on a node: parse raises a
    ProtocolError, Config raises SpecError, BadFrame or ValueError (the view's), each saying
    what is wrong; or the configuration holds together (node in the plan, a rectangle and a
    box per node, an address for every linked neighbour)."""
    checked = outcome(lambda: parse(wire({"k": int(Kind.CONFIG), **fields})), ProtocolError)
    if isinstance(checked, Exception):
        return
    cfg = outcome(lambda: Config(checked[1]), SpecError, BadFrame, ValueError)
    if isinstance(cfg, Exception):
        return
    plan = cfg.render.plan
    assert 0 <= cfg.node < plan.nodes == cfg.partition.nodes == cfg.torus.size
    assert all(isinstance(cfg.neighbours[str(m)], str) for m in cfg.torus.links(cfg.node))
    view = cfg.scene.view
    assert all(math.isfinite(x) for v in (view.eye, view.at, view.up) for x in v)
    assert len(cfg.scene.background) == 3 and all(map(math.isfinite, cfg.scene.background))


# ------------------------------------------------------------------ NFF

VALID_NFF = """v
from 0 0 -10
at 0 0 0
up 0 1 0
angle 45
hither 0.1
resolution 16 12
b 0.1 0.2 0.3
l 0 5 -5
l 1 1 1 0.5 0.5 0.5
f 1 0 0 0.8 0.2 10 0 1
s 0 0 0 1
s 2 0 0 -0.5
f 0.2 0.2 1 0.1 0.1 100 0.9 1.5
p 3
-1 -1 1
1 -1 1
0 1 1
p 4 -2 -2 2  2 -2 2  2 2 2  -2 2 2
pp 3
0 0 3 0 0 1
1 0 3 0 0 1
0 1 3 0 1 1
c
0 -1 0 0.5
0 1 0 0.2
"""
NFF_TOKENS = [
    "v",
    "from",
    "at",
    "up",
    "angle",
    "hither",
    "yon",
    "resolution",
    "b",
    "l",
    "f",
    "s",
    "p",
    "pp",
    "c",
    "#",
    "0",
    "1",
    "-1",
    "3",
    "4",
    "2.5",
    "1e3",
    "-0",
    "+3",
    ".5",
    "5.",
    "1e999",
    "-1e999",
    "nan",
    "inf",
    "-inf",
    "Infinity",
    "1_0",
    "0x10",
    "\u0663",
    "\uff13",
    "99999999999999999999",
    "1e-320",
    "180",
    "0.0001",
    "\n",
    "\r\n",
    "\t",
    "\x0b",
    "\x1c",
    "\u2028",
    "\x85",
    "\x00",
    "é",
    "#c\n",
]


@st.composite
def nff_texts(draw):
    """The valid scene above with token edits (dropped, repeated, replaced, inserted,
    swapped) or cut short, or a soup of NFF keywords, numbers and odd spellings."""
    if draw(st.integers(0, 4)) == 0:
        toks = draw(st.lists(st.sampled_from(NFF_TOKENS), max_size=60))
        return " ".join(toks)
    lines = [line.split(" ") for line in VALID_NFF.splitlines()]
    for _ in range(draw(st.integers(1, 4))):
        r = draw(st.integers(0, len(lines) - 1))
        line = lines[r]
        c = draw(st.integers(0, max(0, len(line) - 1)))
        op = draw(st.sampled_from(["drop", "repeat", "replace", "insert", "swap", "line"]))
        if op == "drop" and line:
            del line[c]
        elif op == "repeat" and line:
            line.insert(c, line[c])
        elif op == "replace" and line:
            line[c] = draw(st.one_of(st.sampled_from(NFF_TOKENS), st.text(max_size=4)))
        elif op == "insert":
            line.insert(c, draw(st.sampled_from(NFF_TOKENS)))
        elif op == "swap":
            r2 = draw(st.integers(0, len(lines) - 1))
            lines[r], lines[r2] = lines[r2], lines[r]
        else:
            lines.insert(r, list(lines[r]))
    text = "\n".join(" ".join(line) for line in lines)
    if draw(st.integers(0, 5)) == 0:
        text = text[: draw(st.integers(0, len(text)))]
    return text


@fuzz(300)
@given(text=nff_texts(), source=st.sampled_from(["scene.nff", "<string>", "dir/ü ber:1.nff"]))
def test_nff_reader_raises_only_scene_errors_that_name_the_line(text, source):
    """parse_nff on mutated scenes and token soup returns a consistent scene (materials,
    vertex slices and lights all in range) or raises SceneError reading `source:line: what`
    with a line of the text."""
    scene = outcome(lambda: parse_nff(text, source), SceneError)
    if isinstance(scene, SceneError):
        n_lines = max(1, text.count("\n") + 1)
        assert str(scene).startswith(f"{source}:{scene.line}: ") and scene.what.strip()
        assert 1 <= scene.line <= n_lines
        return
    assert isinstance(scene, SceneData) and scene.source == source
    for table in (scene.spheres, scene.triangles, scene.polygons, scene.cones):
        assert np.all((0 <= table["mat"]) & (table["mat"] < len(scene.materials)))
    p = scene.polygons
    assert np.all(
        (p["start"] >= 0) & (p["count"] >= 4) & (p["start"] + p["count"] <= len(scene.vertices))
    )
    assert np.all(np.isfinite(scene.lights["pos"]))


# ------------------------------------------------------------------ cameras


def toml_text(tree: dict) -> str:
    """A TOML document of `tree` (tables and arrays of them inline; any key quoted)."""

    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return (
                "nan"
                if math.isnan(v)
                else ("inf" if v > 0 else "-inf")
                if math.isinf(v)
                else repr(v)
            )
        if isinstance(v, int):
            return str(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return "{" + ", ".join(f"{json.dumps(str(k))} = {value(x)}" for k, x in v.items()) + "}"

    return "".join(f"{json.dumps(str(k))} = {value(v)}\n" for k, v in tree.items())


TOML_SCALARS = st.one_of(
    st.sampled_from([x for x in ODD_NUMBERS if not isinstance(x, bool)] + [10**400, -(10**30)]),
    st.integers(),
    st.floats(),
    st.booleans(),
    st.sampled_from(
        [
            "infinity",
            "cap",
            "plane",
            "thin_lens",
            "diaphragm",
            "ellipse",
            "rectangle",
            "polygon",
            "hexagon",
            "",
            "1.0",
        ]
    ),
    st.text(max_size=5),
)
TOML_VALUES = st.recursive(
    TOML_SCALARS,
    lambda kids: (
        st.lists(kids, max_size=3) | st.dictionaries(st.text(max_size=5), kids, max_size=3)
    ),
    max_leaves=5,
)
TOML_KEYS = st.one_of(
    st.sampled_from(
        [
            "type",
            "z",
            "radius",
            "n_after",
            "focal",
            "diameter",
            "semi_x",
            "semi_y",
            "shape",
            "sides",
            "rotation_deg",
            "width",
            "height",
            "distance",
            "film",
            "focus",
            "element",
        ]
    ),
    st.text(max_size=5),
)
BASE_CAMERAS = [tomllib.loads(p.read_text()) for p in sorted(CAMERAS.glob("*.toml"))]


@st.composite
def camera_files(draw):
    """A bundled TOML camera with changes anywhere (values retyped, negative, huge, NaN,
    infinite, keys dropped or added), written out; sometimes with its text then cut or a
    character replaced, so the TOML itself breaks."""
    tree = json.loads(json.dumps(draw(st.sampled_from(BASE_CAMERAS))))
    text = toml_text(draw(mutated_tree(tree, TOML_KEYS, TOML_VALUES)))
    how = draw(st.sampled_from(["as is", "as is", "as is", "cut", "char"]))
    if how == "cut":
        text = text[: draw(st.integers(0, len(text)))]
    elif how == "char" and text:
        i = draw(st.integers(0, len(text) - 1))
        text = text[:i] + draw(st.sampled_from(list("[]{}=\"'#\n,.x0"))) + text[i + 1 :]
    return text


def _assert_camera(result, path: Path) -> None:
    """A CameraError starts with the file's path; a camera has at least one element."""
    if isinstance(result, CameraError):
        assert str(result).startswith(str(path))
    elif not isinstance(result, Exception):
        assert isinstance(result, Camera) and result.source == str(path)
        assert result.elements.dtype == dtypes.ELEMENT and len(result.elements) >= 1


@fuzz(150)
@given(text=camera_files())
def test_toml_camera_reader_raises_only_camera_errors_naming_the_file(tmp_path, text):
    """read_camera on a mutated .toml camera returns a camera of ELEMENT records, or raises
    CameraError whose message starts with the file's path."""
    path = tmp_path / "camera.toml"
    path.write_text(text, encoding="utf-8")
    _assert_camera(outcome(lambda: read_camera(path), CameraError), path)


TABLE = """# r t n aperture
 40.0   2.0  1.62   40.0
 12.0  12.0  0      22.0
  0.0   3.0  0       8.0
 30.0   4.0  1.70   14.0
-30.0  42.8  0      14.0
"""
TABLE_TOKENS = [
    "0",
    "0.0",
    "-0",
    "1",
    "-30",
    "1.5",
    "1e-9",
    "1e300",
    "1e999",
    "-1e999",
    "nan",
    "inf",
    "-inf",
    "x",
    "#",
    "1_0",
    "\u0663",
    "\x00",
    "\n",
    "",
]


@st.composite
def lens_tables(draw):
    """The bundled wide-angle table with numbers dropped, added or replaced (zero, negative,
    huge, NaN, infinite, not numbers), rows repeated or removed; sometimes as bytes that are
    not UTF-8."""
    rows = [line.split() for line in TABLE.splitlines()]
    for _ in range(draw(st.integers(1, 4))):
        r = draw(st.integers(0, len(rows) - 1))
        op = draw(st.sampled_from(["replace", "replace", "drop", "add", "row", "norow"]))
        c = draw(st.integers(0, max(0, len(rows[r]) - 1)))
        tok = draw(st.one_of(st.sampled_from(TABLE_TOKENS), st.floats().map(repr)))
        if op == "replace" and rows[r]:
            rows[r][c] = tok
        elif op == "drop" and rows[r]:
            del rows[r][c]
        elif op == "add":
            rows[r].insert(c, tok)
        elif op == "row":
            rows.insert(r, list(rows[r]))
        elif len(rows) > 1:
            del rows[r]
    data = "\n".join(" ".join(row) for row in rows).encode()
    if draw(st.integers(0, 9)) == 0:
        data += draw(st.sampled_from([b"\xff", b"\xe9", b"\x80 1 2 3"]))
    return data


@fuzz(150)
@given(data=lens_tables())
def test_lens_table_reader_raises_only_camera_errors_naming_the_file(tmp_path, data):
    """read_camera on a mutated lens table returns a camera or raises CameraError whose
    message starts with the file's path (and its line, for a bad row)."""
    path = tmp_path / "lens.txt"
    path.write_bytes(data)
    _assert_camera(outcome(lambda: read_camera(path), CameraError), path)


# ------------------------------------------------------------------ bugs found here


def test_bug_parse_sorts_mixed_key_types():
    """A map with a bytes key and another unknown text key is a BadFrame, like any unknown
    field (parse once sorted the unknown keys together and raised TypeError, which escaped a
    node's handshake and host-link handlers)."""
    with pytest.raises(BadFrame):
        parse(wire({"k": int(Kind.ERROR), "reason": "x", b"a": 1, "b": 2}))


def test_bug_choice_field_holding_an_array():
    """A choice field (EngineSpec.storage, MeshPlan.balance, ...) holding a wire array of
    records is a SpecError (`value in choices` once compared the array elementwise and raised
    TypeError, which escaped the node's CONFIG handler)."""
    fields = wire(config())
    fields["render"]["engine"]["storage"] = np.zeros(1, dtypes.RAY)
    with pytest.raises(SpecError):
        Config(parse(fields)[1])


@pytest.mark.parametrize(
    "text",
    [
        'film = 0\n[[element]]\ntype = "thin_lens"\nfocal = 0.05\ndiameter = 0.03\n',
        "element = 7\n",
        '[[element]]\ntype = "thin_lens"\nfocal = [0.05]\ndiameter = 0.03\n',
        '[[element]]\ntype = "thin_lens"\nz = "near"\nfocal = 0.05\ndiameter = 0.03\n',
        '[[element]]\ntype = "diaphragm"\nshape = "polygon"\nsides = 70000\ndiameter = 0.03\n',
        "[focus]\ndistance = 1" + "0" * 400 + '\n[[element]]\ntype = "thin_lens"\nfocal = 0.05\n'
        "diameter = 0.03\n",
    ],
)
def test_bug_toml_camera_value_of_another_type(tmp_path, text):
    """A camera file value of the wrong TOML type (a table that is a number, a number that is a
    list or a word, an integer too large) is a CameraError naming the file (read_toml once
    raised AttributeError, TypeError, ValueError or OverflowError with no file named)."""
    path = tmp_path / "camera.toml"
    path.write_text(text)
    with pytest.raises(CameraError, match=str(path)):
        read_toml(path)


def test_bug_lens_table_not_utf8(tmp_path):
    """A lens table with a byte that is not UTF-8 is a CameraError naming the file (read_table
    once raised UnicodeDecodeError, naming neither file nor line)."""
    path = tmp_path / "lens.txt"
    path.write_bytes(b"50 5 1.5 30\n-50 49 0 30 \xff\n")
    with pytest.raises(CameraError, match=str(path)):
        read_table(path)
