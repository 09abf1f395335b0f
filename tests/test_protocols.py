"""The wire without sockets: frames split at every byte, message checks, handshake, torus."""

import itertools

import numpy as np
import pytest

from protocols import dtypes
from protocols.errors import BadFrame, FrameTooLarge, ProtocolError, UnknownKind, VersionMismatch
from protocols.framing import (
    ALIGN,
    POOL_LEAST,
    FrameDecoder,
    Payloads,
    encode,
    frame_buffers,
)
from protocols.handshake import check_hello, hello
from protocols.messages import Kind, make, parse
from protocols.records import Parts, copied, joined, taken
from protocols.topology import Router, Torus


def ray_batch(n):
    rays = np.zeros(n, dtypes.RAY)
    rng = np.random.default_rng(n)
    rays["o"] = rng.normal(size=(n, 3))
    rays["d"] = rng.normal(size=(n, 3))
    rays["pixel"] = np.arange(n)
    rays["kind"] = n % 4
    return rays


def test_frames_survive_every_split_point():
    rays = ray_batch(5)
    msgs = [
        make(Kind.RAYS, rays=rays, dest=2, cell=2),
        make(Kind.SHUTDOWN),
        make(Kind.ERROR, reason="x" * 300),
    ]
    stream = b"".join(encode(m) for m in msgs)
    for cut in range(len(stream) + 1):
        dec = FrameDecoder()
        got = dec.feed(stream[:cut]) + dec.feed(stream[cut:])
        assert [m["k"] for m in got] == [Kind.RAYS, Kind.SHUTDOWN, Kind.ERROR]
        assert dec.pending == 0
        kind, fields = parse(got[0])
        np.testing.assert_array_equal(fields["rays"], rays)  # bit-exact records
    # Byte by byte too.
    dec = FrameDecoder()
    got = [m for b in stream for m in dec.feed(bytes([b]))]
    assert len(got) == 3


def test_oversized_frame_is_refused_before_buffering():
    dec = FrameDecoder(max_frame=1000)
    with pytest.raises(FrameTooLarge):
        dec.feed((10**6).to_bytes(4, "big") + b"\0" * 10)
    with pytest.raises(FrameTooLarge):
        encode(make(Kind.RAYS, rays=ray_batch(100), dest=0, cell=0), max_frame=1000)


@pytest.mark.parametrize(
    "payload", [b"\xc1", b"\x93\x01\x02\x03", b"\xd4\x07\x00", b"\x81\xa1k\xcd\xff\xff"]
)
def test_corrupt_payloads_are_protocol_errors(payload):
    frame = len(payload).to_bytes(4, "big") + payload
    with pytest.raises(ProtocolError):
        for m in FrameDecoder().feed(frame):
            parse(m)


def test_array_with_wrong_length_is_refused():
    frame = bytearray(encode(make(Kind.PIXELS, deposits=np.zeros(3, dtypes.DEPOSIT), dest=0)))
    frame[-1:] = b""  # drop one byte of the array, fix the prefix
    frame[:4] = (len(frame) - 4).to_bytes(4, "big")
    with pytest.raises(BadFrame):
        FrameDecoder().feed(bytes(frame))


def test_arrays_follow_the_map_aligned_and_arrive_as_writable_views():
    # Records travel after the map (copied once into the frame, once into the payload on
    # the other side): each starts ALIGN bytes in, whatever the map's length, and decodes to
    # an aligned, writable array the kernels can take as they are.
    for reason in ("", "x", "xyz" * 7):
        message = {
            "k": int(Kind.ERROR),
            "reason": reason,
            "a": ray_batch(3),
            "b": np.zeros(0, dtypes.DEPOSIT),
            "c": np.arange(5, dtype=dtypes.WIRE_DTYPES["i8"]),
        }
        (got,) = FrameDecoder().feed(encode(message))
        for key in "abc":
            a = got[key]
            np.testing.assert_array_equal(a, message[key])
            assert a.flags.aligned and a.flags.writeable
            assert a.ctypes.data % ALIGN == 0
    frame = bytearray(encode(make(Kind.RAYS, rays=ray_batch(2), dest=0, cell=0)))
    frame += b"\0" * 8  # bytes after the arrays: refused, never ignored
    frame[:4] = (len(frame) - 4).to_bytes(4, "big")
    with pytest.raises(BadFrame, match="bytes after the map's arrays"):
        FrameDecoder().feed(bytes(frame))


def _large(seed):
    """A ray batch whose frame is over POOL_LEAST (received into a reused buffer)."""
    rays = ray_batch(POOL_LEAST // dtypes.RAY.itemsize + 1000)
    rays["pixel"] += seed
    return rays


def _address(array):
    return array.__array_interface__["data"][0]


def test_a_payload_buffer_is_reused_only_once_nothing_views_its_frame():
    dec = FrameDecoder()
    first, second = _large(0), _large(7)
    (kept,) = dec.feed(encode(make(Kind.RAYS, rays=first, dest=1, cell=1)))
    where = _address(kept["rays"])
    view = kept["rays"][10:20]  # a slice of the frame's records keeps the buffer lent
    del kept
    (got,) = dec.feed(encode(make(Kind.RAYS, rays=second, dest=1, cell=1)))
    assert _address(got["rays"]) != where
    np.testing.assert_array_equal(view, first[10:20])  # not overwritten
    np.testing.assert_array_equal(got["rays"], second)
    there = _address(got["rays"])
    del view, got
    (again,) = dec.feed(encode(make(Kind.RAYS, rays=first, dest=1, cell=1)))
    assert _address(again["rays"]) in (where, there)  # a freed buffer, reused
    np.testing.assert_array_equal(again["rays"], first)


def test_payloads_kept_for_reuse_stay_within_their_bound():
    pool = Payloads(limit=4 * POOL_LEAST)
    held = [pool.take(POOL_LEAST + k) for k in range(8)]  # all lent at once
    assert sum(len(b) for b in held) == sum(POOL_LEAST + k for k in range(8))
    assert pool._held() <= pool.limit
    assert len({_address(b) for b in held}) == len(held)  # no buffer lent twice
    del held
    small = pool.take(100)
    assert len(small) == 100 and pool._held() <= pool.limit


def test_free_payload_buffers_too_small_give_their_room_to_a_larger_one():
    mb = POOL_LEAST
    pool = Payloads(limit=5 * mb)
    large, small = pool.take(2 * mb), pool.take(mb)
    del large, small  # both free: 3 of the 5 MB kept
    bigger = pool.take(3 * mb)  # 3 more: the smallest free buffer gives its room, not both
    assert sorted(len(k[0]) for k in pool._kept) == [2 * mb, 3 * mb]
    again = pool.take(2 * mb)  # the free 2 MB buffer, lent again
    assert any(again.base is k[0] for k in pool._kept)
    assert len(bigger) == 3 * mb and pool._held() <= pool.limit
    extra = pool.take(2 * mb)  # every kept buffer lent: one of its own, not kept
    assert not any(extra.base is k[0] for k in pool._kept) and pool._held() <= pool.limit


def test_message_fields_are_checked():
    with pytest.raises(TypeError):
        make(Kind.RAYS, rays=ray_batch(1))  # missing dest
    with pytest.raises(BadFrame):
        make(Kind.RAYS, rays=np.zeros(2, dtypes.DEPOSIT), dest=0, cell=0)
    with pytest.raises(UnknownKind):
        parse({"k": 99})
    with pytest.raises(BadFrame):
        parse({"k": int(Kind.ERROR)})
    with pytest.raises(BadFrame):
        parse({"k": int(Kind.STATS), "node": True, "stats": {}})
    objs = make(
        Kind.OBJECTS, node=0, table="spheres", records=np.zeros(2, dtypes.SPHERE), last=True
    )
    kind, fields = parse(FrameDecoder().feed(encode(objs))[0])
    assert kind is Kind.OBJECTS and len(fields["records"]) == 2
    bad = dict(objs, table="teapots")
    with pytest.raises(BadFrame):
        parse(bad)
    bad = dict(objs, records=np.zeros(2, dtypes.CONE))
    with pytest.raises(BadFrame):
        parse(bad)


def progress(**change):
    """A PROGRESS as a node sends it, with `change`d fields, through the framer."""
    fields = {
        "node": 1,
        "rays": 5,
        "work": 2,
        "ready": True,
        "state": 1,
        "busy_ms": 9,
        "elapsed_ms": 10,
        "traced": 50,
        "objects": 3,
        "links": np.array([(0, 4, 400), (2, 0, 0)], dtypes.LINK_TRAFFIC),
        "setup": 5,
    } | change
    return FrameDecoder().feed(encode(make(Kind.PROGRESS, **fields)))[0]


def test_progress_counters_and_links_are_checked():
    kind, f = parse(progress())
    assert kind is Kind.PROGRESS and f["links"]["rays"].tolist() == [4, 0]
    for name in ("rays", "work", "state", "busy_ms", "elapsed_ms", "traced", "objects", "setup"):
        with pytest.raises(BadFrame, match=f"PROGRESS: {name} out of range"):
            parse(progress(**{name: -1}))
    with pytest.raises(BadFrame, match="PROGRESS: setup out of range"):
        parse(progress(setup=6))  # past SETUP_STEPS
    too_many = np.zeros(5, dtypes.LINK_TRAFFIC)
    negative = np.array([(0, -1, 0)], dtypes.LINK_TRAFFIC)
    for links in (too_many, negative):
        with pytest.raises(BadFrame, match="PROGRESS: links out of range"):
            parse(progress(links=links))
    with pytest.raises(BadFrame, match="PROGRESS.links must be an array"):
        parse(progress() | {"links": np.zeros(1, dtypes.DEPOSIT)})


def test_handshake_checks_version_and_cluster():
    me = check_hello(hello("c1", "node", 3), "c1")
    assert me["node"] == 3 and me["role"] == "node"
    with pytest.raises(VersionMismatch, match="cluster"):
        check_hello(hello("c2", "host"), "c1")
    old = dict(hello("c1", "host"), version=0)
    with pytest.raises(VersionMismatch, match="protocol 0"):
        check_hello(old, "c1")
    with pytest.raises(VersionMismatch, match="HELLO"):
        check_hello(make(Kind.SHUTDOWN), "c1")


SHAPES = [(1, 1), (1, 2), (2, 1), (2, 2), (3, 3), (2, 4), (2, 3), (4, 5), (1, 7)]


@pytest.mark.parametrize("rows,cols", SHAPES)
def test_torus_neighbours_and_links(rows, cols):
    t = Torus(rows, cols)
    for n in range(t.size):
        nb = t.neighbours(n)
        # Neighbourhood is symmetric: my east's west is me, my south's north is me.
        assert t.neighbours(nb["east"])["west"] == n
        assert t.neighbours(nb["south"])["north"] == n
        for m in t.links(n):
            assert n in t.links(m)
        assert n not in t.links(n)
        assert len(t.links(n)) <= 4
    if cols == 2 and rows == 1:
        assert t.links(0) == [1]


@pytest.mark.parametrize("rows,cols", SHAPES)
def test_routes_are_shortest_and_alternate(rows, cols):
    t = Torus(rows, cols)
    for a, b in itertools.product(range(t.size), repeat=2):
        hops = t.next_hops(a, b)
        if a == b:
            assert hops == ()
            continue
        assert hops, (a, b)
        for h in hops:
            assert t.distance(h, b) == t.distance(a, b) - 1
            assert h in t.links(a)
        # Following the router always arrives in exactly distance(a, b) hops.
        node, steps = a, 0
        routers = {n: Router(t, n) for n in range(t.size)}
        while node != b:
            node = routers[node].next_hop(b)
            steps += 1
        assert steps == t.distance(a, b)
    # On a 3x3 torus node 4 reaches node 0 by two equal first hops; the router alternates.
    if (rows, cols) == (3, 3):
        r = Router(t, 4)
        firsts = [r.next_hop(0) for _ in range(4)]
        assert sorted(set(firsts)) == [1, 3] and firsts[0] != firsts[1]


def test_torus_rejects_empty_and_foreign_nodes():
    with pytest.raises(ValueError):
        Torus(0, 3)
    with pytest.raises(ValueError):
        Torus(2, 2).coords(4)


def test_error_descriptions_are_never_empty():
    from protocols.errors import describe

    assert describe(TimeoutError()) == "TimeoutError (no message)"
    assert describe(ValueError("bad depth")) == "ValueError: bad depth"
    try:
        try:
            raise ConnectionResetError("peer reset")
        except ConnectionResetError as e:
            raise TimeoutError() from e
    except TimeoutError as e:
        assert describe(e) == "TimeoutError (ConnectionResetError: peer reset)"


@pytest.mark.parametrize(
    "counts",
    [
        {"eye_rays": -1},
        {"eye_rays": 1.5},
        {"eye_rays": True},
        {1: 2},
        {f"k{i}": 1 for i in range(65)},
    ],
)
def test_traced_tiles_counts_a_host_adds_up_are_checked(counts):
    good = make(Kind.TILES_TRACED, node=1, tiles=[0, 3], counts={"eye_rays": 5})
    assert parse(good)[1]["counts"] == {"eye_rays": 5}
    with pytest.raises(BadFrame, match="TILES_TRACED.counts"):
        parse({**good, "counts": counts})


def test_a_scene_travels_as_its_header_and_tables_and_comes_back_whole():
    # The one wire form of a scene: CONFIG carries the header (view, background), OBJECTS
    # every table by name; put back together on the node they are the host's scene.
    from protocols.scene import SCENE_TABLES, SceneData, SceneHeader
    from tests.conftest import make_scene

    scene = make_scene(
        spheres=[((0, 0, 5), 1.0, 0), ((1, 0, 6), 0.5, 0)],
        lights=[(0, 5, 0)],
        background=(0.1, 0.2, 0.3),
    )
    wire = parse(make(Kind.CONFIG, **_config_fields(scene.header.to_wire())))[1]["scene"]
    tables = {
        name: parse(make(Kind.OBJECTS, table=name, records=records, node=0, last=False))[1][
            "records"
        ]
        for name, records in scene.tables().items()
    }
    assert set(tables) == set(SCENE_TABLES)
    back = SceneData.from_tables(SceneHeader.from_wire(wire), tables)
    assert back.header == scene.header
    for name in SCENE_TABLES:
        assert np.array_equal(getattr(back, name), getattr(scene, name)), name


@pytest.mark.parametrize(
    "change,message",
    [
        ({"background": [0, 0]}, "scene.background must be three finite numbers"),
        ({"background": [0, float("nan"), 0]}, "scene.background must be three finite"),
        ({"background": [True, 0, 0]}, "scene.background must be three finite"),
        ({"view": {"eye": [0, 0, 0]}}, "scene.view: "),
        ({"view": []}, "scene.view: want a map"),
        ({"extra": 1}, "scene: want a map of view and background"),
    ],
)
def test_a_scene_header_from_a_peer_is_checked_by_field(change, message):
    from protocols.scene import SceneHeader, View

    wire = SceneHeader(View((0, 0, -5), (0, 0, 0), (0, 1, 0), 45.0)).to_wire() | change
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        SceneHeader.from_wire(wire)
    coincide = SceneHeader(View((0, 0, -5), (0, 0, 0), (0, 1, 0), 45.0)).to_wire()
    coincide["view"]["at"] = [0, 0, -5]
    with pytest.raises(ValueError, match=r"scene\.view: 'from' .* coincide"):
        SceneHeader.from_wire(coincide)


def _config_fields(scene: dict) -> dict:
    return dict(node=0, neighbours={}, render={}, partition={}, scene=scene, render_id=b"r" * 16)


@pytest.mark.parametrize("dtype", [dtypes.RAY, dtypes.DEPOSIT])
def test_records_joined_and_copied_as_bytes_are_numpys_records(dtype):
    # `protocols.records` copies rays and deposits as raw bytes (NumPy copies a structured
    # dtype field by field, 15 times slower): the same records, padding and all, a new
    # array, from contiguous parts and from strided ones.
    rng = np.random.default_rng(1)
    parts = [np.frombuffer(rng.bytes(n * dtype.itemsize), dtype).copy() for n in (0, 3, 1, 17)]
    parts.append(parts[3][::2])  # strided
    got = joined(parts)
    assert got.dtype == dtype and got.tobytes() == np.concatenate(parts).tobytes()
    assert not np.shares_memory(got, parts[3]) and joined(parts[1:2]) is parts[1]
    own = copied(parts[4])
    assert own.tobytes() == parts[4].tobytes() and not np.shares_memory(own, parts[3])
    index = rng.integers(0, 17, 40)
    assert taken(parts[3], index).tobytes() == parts[3][index].tobytes()
    assert taken(parts[4], index % 9).tobytes() == parts[4][index % 9].tobytes()


@pytest.mark.parametrize("dtype", [dtypes.RAY, dtypes.TRIANGLE])
def test_parts_travel_as_their_join_written_from_where_they_lie(dtype):
    # Rays gathered from several batches leave in one frame without being joined: the frame
    # of `Parts` is the frame of their join, byte for byte (an unaligned record size too,
    # and an array after them still aligned), and its buffers are the parts' own memory, so
    # the socket's is the one copy on the sender's side.
    rng = np.random.default_rng(2)
    parts = [np.frombuffer(rng.bytes(n * dtype.itemsize), dtype).copy() for n in (3, 0, 5, 1)]
    after = np.arange(3, dtype=dtypes.WIRE_DTYPES["i8"])
    whole = {"k": int(Kind.ERROR), "reason": "r", "a": joined(parts), "b": after}
    split = {**whole, "a": Parts.of(parts)}
    assert encode(split) == encode(whole)
    (got,) = FrameDecoder().feed(encode(split))
    assert got["a"].tobytes() == whole["a"].tobytes() and got["b"].ctypes.data % ALIGN == 0
    buffers = frame_buffers(split)
    for p in (p for p in parts if len(p)):
        assert any(np.shares_memory(np.frombuffer(b, np.uint8), p) for b in buffers[1:])
    assert len(Parts.of(parts)) == 9 and Parts.of(parts).nbytes == 9 * dtype.itemsize
    with pytest.raises(ValueError, match="one dtype"):
        Parts.of([parts[0], np.zeros(1, dtypes.DEPOSIT)])
