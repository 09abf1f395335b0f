"""A kernel bound to its calls' argument types (`meshnode.engine.bound`) gives what numba's
dispatcher gives, and never calls one overload with another's types."""

import numba
import numpy as np

from meshnode.engine.bound import Bound, array_key
from protocols.dtypes import RAY
from tests.conftest import spd_scene


@numba.njit(cache=False)
def _scaled_sum(a, scale, table):
    return a.sum() * scale + table[0]


def test_each_key_gets_its_own_overload_and_the_dispatchers_result():
    table = np.array([0.5])
    bound = Bound(_scaled_sum)
    ints = np.arange(10, dtype=np.int64)
    floats = np.linspace(0.0, 1.0, 7)
    readonly = floats.copy()
    readonly.flags.writeable = False
    strided = np.arange(20, dtype=np.float64)[::2]
    for a in (ints, floats, readonly, strided, ints, floats, readonly, strided):
        assert bound(array_key(a), a, 3, table) == _scaled_sum(a, 3, table)
    # four kinds of array, four entry points: an int64 array is never read as float64
    assert len(bound.entries) == 4
    entries = set(map(id, bound.entries.values()))
    assert len(entries) == 4 and id(_scaled_sum) not in entries


def test_an_engine_traces_network_bytes_and_its_own_arrays_alike():
    # rays decoded from a message are read-only views of its bytes: another numba type, so
    # another key; the colours, counts and rays passed on must not depend on which
    from host.scene.nff import read_nff
    from meshnode.engine import Engine
    from meshnode.engine.camera import eye_rays
    from protocols.render import ImageSpec

    scene = read_nff(spd_scene("balls_s1.nff"))
    whole = Engine(scene)
    lo, hi = whole.scene_lo, whole.scene_hi
    half = Engine(scene, box=(lo, (lo + hi) / 2), scene_box=(lo, hi))
    rays = eye_rays(scene.view, ImageSpec(width=24, height=24), rows=(0, 24), cols=(0, 24))
    wire = np.frombuffer(rays.tobytes(), RAY)
    assert not wire.flags.writeable
    for engine in (whole, half):
        rgb, counts, passed = engine.trace_node(rays)
        rgb_w, counts_w, passed_w = engine.trace_node(wire)
        rgb_again, _, _ = engine.trace_node(rays)
        np.testing.assert_array_equal(rgb_w, rgb)
        np.testing.assert_array_equal(rgb_again, rgb)
        assert counts_w == counts and passed_w.tobytes() == passed.tobytes()
        assert len(engine._trace_batch.entries) == 2
    assert len(half.trace_node(rays)[2]) > 0 and len(whole.trace_node(rays)[2]) == 0


def _values():
    """Arguments of many numba types, some of them equal types from other objects."""
    from collections import namedtuple

    pair = namedtuple("pair", "a b")
    floats = np.linspace(0.0, 1.0, 6)
    readonly = floats.copy()
    readonly.flags.writeable = False
    rays = np.zeros(3, RAY)
    return [
        floats,
        np.ones(4),
        readonly,
        floats[::2],
        floats.reshape(2, 3),
        floats.reshape(2, 3).T,
        np.arange(4, dtype=np.int32),
        np.arange(4, dtype=np.int64),
        rays,
        np.zeros(5, RAY),
        rays[::2],
        np.zeros(2, np.dtype([("x", "<f8"), ("k", "u1")], align=True)),
        np.zeros(2, np.dtype([("x", "<f8"), ("k", "u1")])),
        None,
        True,
        3,
        2**63 + 5,
        -7,
        2.5,
        np.float64(2.0),
        np.int32(4),
        (floats, 3),
        (np.ones(2), 4),
        (floats, 2.0),
        pair(floats, 1),
        pair(np.ones(3), 2),
        (floats, floats),
        (floats, readonly),
        (),
    ]


def test_equal_type_keys_are_equal_numba_types():
    # a shared overload is called on another engine's arguments only where its key equals
    # theirs: that must mean numba types them alike (a key may tell apart what numba does
    # not, a Python float from numpy's: that only shares less)
    values = _values()
    types = [numba.typeof(v) for v in values]
    keys = [type_of_key(v) for v in values]
    pairs = [(i, j) for i in range(len(values)) for j in range(len(values))]
    for i, j in pairs:
        assert keys[i] != keys[j] or types[i] == types[j], (values[i], values[j])
    alike = sum(keys[i] == keys[j] for i, j in pairs if i != j)
    assert alike >= 8  # arrays, records and tuples of one type from other objects share


def type_of_key(value):
    from meshnode.engine.bound import type_key

    key = type_key(value)
    assert key is not None and hash(key) is not None
    return key


def test_engines_of_one_variant_share_the_overload_their_first_calls_find():
    from host.scene.nff import read_nff
    from meshnode.engine import Engine, bound
    from meshnode.engine.camera import eye_rays
    from protocols.render import ImageSpec

    scene = read_nff(spd_scene("balls_s1.nff"))
    whole = Engine(scene)
    lo, hi = whole.scene_lo, whole.scene_hi
    rays = eye_rays(scene.view, ImageSpec(width=8, height=8), rows=(0, 8), cols=(0, 8))
    halves = [
        Engine(scene, box=box, scene_box=(lo, hi))
        for box in ((lo, (lo + hi) / 2), ((lo + hi) / 2, hi))
    ]
    halves[0].trace_passing(rays)
    shared = len(bound._SHARED)
    typed = []
    real = halves[1]._trace_batch.dispatcher.typeof_pyval
    halves[1]._trace_batch.dispatcher.typeof_pyval = lambda v: typed.append(v) or real(v)
    try:
        rgb, counts, passed = halves[1].trace_passing(rays)
    finally:
        del halves[1]._trace_batch.dispatcher.typeof_pyval
    assert typed == [] and len(bound._SHARED) == shared  # no argument typed, none added
    (entry,) = halves[1]._trace_batch.entries.values()
    assert entry is next(iter(halves[0]._trace_batch.entries.values()))
    # the shared entry traces as the dispatcher typing every call does
    plain = Engine(scene, box=((lo + hi) / 2, hi), scene_box=(lo, hi))
    dispatcher = plain._trace_batch.dispatcher
    plain._trace_batch = lambda key, *args: dispatcher(*args)
    rgb_d, counts_d, passed_d = plain.trace_passing(rays)
    np.testing.assert_array_equal(rgb, rgb_d)
    assert counts == counts_d and passed.tobytes() == passed_d.tobytes()
