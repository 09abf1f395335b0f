"""What bounds seen from a point (the eye's, `meshnode.engine.sightlines`; a light's,
`meshnode.engine.lightmaps`) are made on: each occupied voxel's box of marked sub-voxels,
padded (`padded_voxel`), the maps a bound is made on (`bound_maps`: the map, or its outer and
inner maps), and what is made once a map for every engine on it (`per_map`).
"""

import math
from collections.abc import Callable
from contextlib import contextmanager
from contextvars import ContextVar

import numpy as np

from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.loading import cpu_less_loads
from meshnode.engine.occupancy import SUB, SUB_RANGES, Occupancy

PAD = 1e-6  # of a voxel, each way, around every box of marked sub-voxels


def marked_box(voxels: int, fine: np.ndarray) -> np.ndarray:
    """(6, voxels) float: per voxel of a map, the box of its marked sub-voxels (`fine`, as
    `Occupancy.fine`), as the fractions of the voxel its low and high walls lie at on each
    axis (x, y, z low, then high); the whole voxel where there are no sub-voxel masks."""
    out = np.empty((6, voxels))
    out[:3], out[3:] = 0.0, 1.0
    if fine.shape[0]:
        _mask_boxes(fine, out)
    return out


@kernel
def _mask_boxes(fine, out):
    """`marked_box` of every voxel with a mask, into `out`: per axis the first and one past
    the last layer of sub-voxels its mask sets (NumPy over the masks took 6-26 ms on the
    SPD scenes' maps, each time a plan's first simulation made its tables)."""
    for v in range(fine.shape[0]):
        mask = fine[v]
        if mask == 0:
            continue
        for a in range(3):
            first, last = SUB, 0
            for c in range(SUB):
                if mask & SUB_RANGES[a, c, c] != 0:
                    first = min(first, c)
                    last = c + 1
            out[a, v] = first / SUB
            out[3 + a, v] = last / SUB


def bound_maps(occ: Occupancy) -> list[tuple]:
    """The maps a bound seen from a point is made on, each as `_near` and the lights' maps
    take it (a row of `Occupancy.clear`, 0 where a voxel is occupied; the boxes of marked
    sub-voxels; corner, voxel size, voxels per axis): the map; or the outer map with its
    voxels wholly inside the inner map's box left out, and the inner map (balls' sphereflake:
    its 13 x 13 x 9 outer voxels, 72 x 72 x 50 inner ones)."""
    inner = occ.inner
    if inner is None:
        return [(occ.clear[0], marked_boxes(occ), occ.lo, occ.cell, occ.res)]
    outer = occ.outer
    occupied = outer.clear[0].copy()
    occupied[occ.inside_inner()] = 1  # empty, as far as these bounds go
    return [
        (occupied, marked_boxes(outer), outer.lo, outer.cell, outer.res),
        (inner.clear[0], marked_boxes(inner), inner.lo, inner.cell, inner.res),
    ]


def marked_boxes(occ: Occupancy) -> np.ndarray:
    """`marked_box` of the map `occ`, made once a map (`per_map`): the eye's map and the
    lights' read it for every simulated mesh the cost pre-pass runs (balls: 5 ms a time)."""
    return per_map(occ, ("marked",), lambda: marked_box(occ.clear.shape[1], occ.fine))


# `per_map`'s entries: (map's clear, map's fine, value) by the map's identity and a key
_PER_MAP: dict = {}
PER_MAP_KEPT = 8
_MADE = [0.0]  # CPU seconds `per_map` spent making entries, loads left out (`per_map_seconds`)
# a set `per_map` adds each key asked for to, while one is given (`asked_in`): a context
# variable, so another thread's engines (a node traced in the host's process) add nothing
_ASKED: ContextVar[set | None] = ContextVar("per_map_asked", default=None)


def per_map(occ: Occupancy, key: tuple, make: Callable):
    """`make()` once for the map `occ` and `key`. Every engine built on one packed map
    shares its arrays (`occupancy.occupancy_arrays`), so their identity names the map: no
    hashing of its megabytes per engine (the lights' maps keyed on the map's bytes took 1 ms
    an engine, 9 ms of a 3x3 simulation's 90). Each entry holds the arrays it is keyed by,
    so no other map's can take their ids while it stays; the newest PER_MAP_KEPT stay."""
    full, asked = (*map_key(occ), *key), _ASKED.get()
    entry = _PER_MAP.get(full)
    if entry is None:
        began, inner = cpu_less_loads(), set()
        with asked_in(inner):  # the entries making it asks for: asked again with it
            value = make()
        entry = _PER_MAP[full] = (occ.clear, occ.fine, value, frozenset(inner))
        _MADE[0] += cpu_less_loads() - began
        while len(_PER_MAP) > PER_MAP_KEPT:
            del _PER_MAP[next(iter(_PER_MAP))]
    if asked is not None:
        asked.add(full)
        asked.update(entry[3])
    return entry[2]


def map_key(occ: Occupancy) -> tuple:
    """What names the map `occ` among those alive: where its shared arrays' memory lies and
    their shapes (an outer map is a view of its inner map's arrays, made anew each time; a
    cache keyed so must hold them, so no other map's can take that memory) and where it lies."""
    return (
        *(a.__array_interface__["data"][0] for a in (occ.clear, occ.fine)),
        occ.clear.shape,
        occ.fine.shape,
        occ.lo.tobytes(),
        occ.cell.tobytes(),
        occ.res.tobytes(),
    )


def per_map_seconds() -> float:
    """CPU seconds `per_map` has spent making its entries in this process: work done once a
    map, which the cost pre-pass's first simulation pays and its later ones do not (so it
    is kept out of what a simulation is expected to cost, `host.planning.allowance`)."""
    return _MADE[0]


@contextmanager
def asked_in(keys: set):
    """While inside, every key `per_map` is asked for is added to `keys`: the cost pre-pass
    charges a plan for the tables its simulations read, made now or kept from an earlier
    plan, so the plan is the same whatever this process planned before."""
    token = _ASKED.set(keys)
    try:
        yield keys
    finally:
        _ASKED.reset(token)


@leaf
def padded_voxel(v, lo, cell, res, point, b_lo, b_hi, marked):
    """The box of voxel v's marked sub-voxels (`marked_box`; x fastest), padded by PAD of a
    voxel and far above round-off, as b_lo..b_hi relative to `point`; returns the distance
    from the point to it."""
    nx, ny = res[0], res[1]
    index = (v % nx, (v // nx) % ny, v // (nx * ny))
    for a in range(3):
        pad = PAD * cell[a] + 1e-12 * (abs(lo[a]) + abs(point[a]) + res[a] * cell[a])
        b_lo[a] = lo[a] + (index[a] + marked[a, v]) * cell[a] - pad - point[a]
        b_hi[a] = lo[a] + (index[a] + marked[3 + a, v]) * cell[a] + pad - point[a]
    return box_distance(b_lo, b_hi)


@inline
def box_distance(b_lo, b_hi):
    """The distance from the origin to the box b_lo..b_hi."""
    gap = 0.0
    for a in range(3):
        g = max(b_lo[a], 0.0, -b_hi[a])
        gap += g * g
    return math.sqrt(gap)
