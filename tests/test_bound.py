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
