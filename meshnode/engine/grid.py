"""The node's uniform grid: resolution choice, and voxel -> object references stored either as
CSR arrays or as a hash table plus a bit table, whichever costs less memory (DESIGN.md 4).
"""

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from meshnode.engine.jit import kernel
from meshnode.engine.tables import Tables
from meshnode.engine.voxelize import voxel_refs
from protocols.render import EngineSpec
from protocols.spec import default

MAX_VOXELS = 1 << 24
MAX_REFS = 1 << 26
# Refining stops before the grid stores each object in more than this many voxels on average:
# finer voxels then only cut nested or overlapping objects apart, at a build cost no render of
# SPD size wins back (shells: 243 K references built in 0.2 s trace in 0.53 s; refined to 48 M
# they took 20.5 s and 260 MB to build and traced in 0.28 s; the hierarchy 0.50 s and 0.42 s).
MAX_REFS_PER_OBJECT = 64
MACRO_SHIFT = 2  # macro cells of 4^3 voxels, for skipping empty space
MACRO = 1 << MACRO_SHIFT
STORAGES = ("auto", "csr", "hash")


class GridArrays(NamedTuple):
    """The grid as the traversal kernels read it (`Grid.arrays`). Both storages' arrays are
    always set, the unused one's empty: the storage is a branch taken per voxel at run time
    (perfectly predicted), which halves the compiled variants."""

    glo: np.ndarray  # (3,) box corner
    cell: np.ndarray  # (3,) voxel size
    res: np.ndarray  # (3,) int64 voxels per axis
    offsets: np.ndarray  # CSR: (V+1,) int32 start of each voxel's refs; empty with hash
    slots: np.ndarray  # hash: (M+1,) int32 start of each slot's entries; empty with CSR
    e_vox: np.ndarray  # hash: (E,) int64 true voxel id of each entry
    e_start: np.ndarray  # hash: (E,) int32 first ref of each entry
    e_count: np.ndarray  # hash: (E,) int32 refs of each entry
    bits: np.ndarray  # hash: (V/8,) uint8, one bit per non-empty voxel
    refs: np.ndarray  # (R,) int32 local object ids, grouped by voxel
    macro: np.ndarray  # (Mz*My*Mx,) uint8 distance to the nearest occupied macro cell
    mres: np.ndarray  # (3,) int64 macro cells per axis
    mshift: int  # macro cells are 2^mshift voxels a side


@dataclass
class Grid:
    """Voxel references of one box. Exactly one storage's arrays are set, the other's are None."""

    lo: np.ndarray  # (3,) box corner
    cell: np.ndarray  # (3,) voxel size
    res: np.ndarray  # (3,) int64 voxels per axis
    refs: np.ndarray  # (R,) int32 local object ids, grouped by voxel
    offsets: np.ndarray | None  # CSR: (V+1,) int32 start of each voxel's refs
    slots: np.ndarray | None  # hash: (M+1,) int32 start of each slot's entries
    entry_voxel: np.ndarray | None  # hash: (E,) int64 true voxel id of each entry
    entry_start: np.ndarray | None  # hash: (E,) int32
    entry_count: np.ndarray | None  # hash: (E,) int32
    bits: np.ndarray | None  # hash: (V/8,) uint8, one bit per non-empty voxel
    storage: str
    stats: dict
    macro: np.ndarray | None = None  # (Mz*My*Mx,) uint8 distance to the nearest occupied macro
    macro_res: np.ndarray | None = None  # (3,) int64 macro cells per axis
    macro_shift: int = MACRO_SHIFT

    @property
    def hi(self) -> np.ndarray:
        return self.lo + self.cell * self.res

    def arrays(self) -> GridArrays:
        """The grid as the traversal kernels take it."""
        i32, i64, u8 = np.zeros(0, np.int32), np.zeros(0, np.int64), np.zeros(0, np.uint8)
        csr = self.storage == "csr"
        return GridArrays(
            self.lo,
            self.cell,
            self.res,
            self.offsets if csr else i32,
            i32 if csr else self.slots,
            i64 if csr else self.entry_voxel,
            i32 if csr else self.entry_start,
            i32 if csr else self.entry_count,
            u8 if csr else self.bits,
            self.refs,
            self.macro,
            self.macro_res,
            self.macro_shift,
        )


def grow_box(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pad a box so objects on its faces are strictly inside and flat boxes get a thickness."""
    ext = hi - lo
    pad = 1e-6 * max(float(ext.max()), 1e-300) + 1e-12 * np.maximum(np.abs(lo), np.abs(hi))
    return lo - pad, hi + pad


def choose_resolution(lo, hi, n_objects: int, density: float) -> np.ndarray:
    """Voxels per axis proportional to the box sides, about `density * n_objects` in total.

    Sides far thinner than the largest get one voxel (a flat floor needs no layers)."""
    ext = np.asarray(hi, float) - np.asarray(lo, float)
    active = ext > 1e-3 * ext.max()
    target = min(max(1.0, density * n_objects), MAX_VOXELS)
    cell = (np.prod(ext[active]) / target) ** (1.0 / active.sum())
    res = np.where(active, np.clip(np.round(ext / cell), 1, 2048), 1).astype(np.int64)
    while np.prod(res) > MAX_VOXELS:
        res = np.maximum(1, res // 2)
    return res


def _count(tables: Tables, glo, ghi, res):
    """References per voxel at resolution `res` (the first of the two build passes)."""
    cell = (ghi - glo) / res
    args = (glo, cell, res, tables.lo, tables.hi, tables.geometry())
    counts = np.zeros(int(np.prod(res)), np.int32)
    voxel_refs(*args, False, counts, counts, np.zeros(0, np.int32))
    return cell, args, counts


def occupancy(counts: np.ndarray) -> float:
    """Objects in the voxel of an average reference: sum(c^2) / sum(c). A ray that reaches
    occupied space meets about this many candidates per voxel."""
    c = counts.astype(np.float64)
    return float((c * c).sum() / max(c.sum(), 1.0))


@kernel
def _macro_distance(counts, res, mres, b):
    """Chessboard distance (in macro cells, capped at 255) from every macro cell of b^3 voxels
    to the nearest one holding an object: a ray in a cell at distance k can skip the empty cube
    of radius k - 1 around it in one jump (proximity clouds)."""
    mx, my, mz = mres[0], mres[1], mres[2]
    dist = np.full(mx * my * mz, 255, np.uint8)
    for v in range(counts.shape[0]):
        if counts[v] > 0:
            ix = v % res[0]
            iy = (v // res[0]) % res[1]
            iz = v // (res[0] * res[1])
            dist[ix // b + mx * (iy // b + my * (iz // b))] = 0
    changed = True
    while changed:
        changed = False
        for sweep in range(2):
            for m0 in range(mx * my * mz):
                m = m0 if sweep == 0 else mx * my * mz - 1 - m0
                x = m % mx
                y = (m // mx) % my
                z = m // (mx * my)
                best = int(dist[m])
                for dz in range(-1, 2):
                    for dy in range(-1, 2):
                        for dx in range(-1, 2):
                            xx, yy, zz = x + dx, y + dy, z + dz
                            if 0 <= xx < mx and 0 <= yy < my and 0 <= zz < mz:
                                d = int(dist[xx + mx * (yy + my * zz)]) + 1
                                if d < best:
                                    best = d
                if best < dist[m]:
                    dist[m] = best
                    changed = True
    return dist


def build_grid(
    tables: Tables,
    lo: np.ndarray,
    hi: np.ndarray,
    density: float = default(EngineSpec, "density"),
    storage: str = default(EngineSpec, "storage"),
    res: np.ndarray | None = None,
) -> Grid:
    """Grid over [lo, hi] holding every object of `tables`; storage by memory cost unless forced.

    Resolution: `density` voxels per object spread over the box by its side lengths; then, where
    objects crowd a small part of the box (a sphereflake on a wide floor), the resolution grows
    until the occupancy seen by a reference is near 4 / density (at most three rounds, at most
    MAX_VOXELS). Empty voxels are what the hash storage and the macro cells make cheap."""
    target_occupancy = 4.0 / density
    if storage not in STORAGES:
        raise ValueError(f"storage must be one of {STORAGES}, got {storage!r}")
    glo, ghi = grow_box(np.asarray(lo, float), np.asarray(hi, float))
    fixed = res is not None
    boost = 1.0
    previous, stopped = None, ""
    for _ in range(1 if fixed else 4):
        trial = np.asarray(
            res if fixed else choose_resolution(glo, ghi, tables.n, density * boost)
        ).astype(np.int64)
        cell, args, counts = _count(tables, glo, ghi, trial)
        occ = occupancy(counts)
        cap = min(MAX_REFS, MAX_REFS_PER_OBJECT * max(tables.n, 1))
        if previous is not None and (occ > 0.75 * previous[4] or counts.sum() > cap):
            # Finer voxels stopped paying (objects overlap each other): keep the last grid.
            stopped = (
                f"; finer, each object in {counts.sum() / max(tables.n, 1):.0f} voxels on "
                f"average (over {MAX_REFS_PER_OBJECT}): kept the last"
                if counts.sum() > cap
                else "; finer voxels stopped lowering the occupancy: kept the last"
            )
            trial, cell, args, counts, occ, boost = previous
            break
        previous = (trial, cell, args, counts, occ, boost)
        if fixed or occ <= 1.5 * target_occupancy or np.prod(trial) * 2 > MAX_VOXELS:
            break
        boost *= occ / target_occupancy
    res = trial
    n_vox = int(np.prod(res))
    offsets = np.zeros(n_vox + 1, np.int32)
    np.cumsum(counts, out=offsets[1:])
    refs = np.empty(int(offsets[-1]), np.int32)
    voxel_refs(*args, True, counts, offsets[:-1].copy(), refs)

    occupied = np.flatnonzero(counts)
    n_slots = 1 << max(0, math.ceil(math.log2(max(len(occupied), 1))))
    csr_bytes = offsets.nbytes + refs.nbytes
    hash_bytes = (n_slots + 1) * 4 + len(occupied) * 16 + refs.nbytes + (n_vox + 7) // 8
    chosen = storage if storage != "auto" else ("csr" if csr_bytes <= hash_bytes else "hash")
    stats = {
        "resolution": res.tolist(),
        "voxels": n_vox,
        "empty_voxels": n_vox - len(occupied),
        "object_references": len(refs),
        "csr_bytes": csr_bytes,
        "hash_bytes": hash_bytes,
        "hash_slots": n_slots,
        "storage": chosen,
        "storage_reason": (
            f"forced by flag ({storage})"
            if storage != "auto"
            else f"smaller: csr {csr_bytes} B vs hash {hash_bytes} B"
        ),
        "structure_bytes": csr_bytes if chosen == "csr" else hash_bytes,
        "density": density,
        "occupancy": occ,
        "target_occupancy": target_occupancy,
        "resolution_boost": boost,
        "resolution_reason": (
            "given by caller"
            if fixed
            else f"{density:g} voxels per object over the box by side lengths, "
            f"refined x{boost:.3g} "
            f"toward {target_occupancy:g} objects per occupied voxel (reached {occ:.3g})" + stopped
        ),
    }
    mres = (res + MACRO - 1) // MACRO
    macro = _macro_distance(counts, res, mres, MACRO)
    stats["macro_cells"] = mres.tolist()
    stats["macro_bytes"] = macro.nbytes
    stats["structure_bytes"] += macro.nbytes
    if chosen == "csr":
        return Grid(
            glo, cell, res, refs, offsets, None, None, None, None, None, chosen, stats, macro, mres
        )
    # Hash storage: entries (true voxel id, refs range) grouped by slot = voxel & (M - 1).
    slot_of = occupied & (n_slots - 1)
    order = np.argsort(slot_of, kind="stable")
    entry_voxel = occupied[order].astype(np.int64)
    slots = np.zeros(n_slots + 1, np.int32)
    np.cumsum(np.bincount(slot_of, minlength=n_slots), out=slots[1:])
    bits = np.packbits(counts > 0, bitorder="little")
    return Grid(
        glo,
        cell,
        res,
        refs,
        None,
        slots,
        entry_voxel,
        offsets[entry_voxel].astype(np.int32),
        counts[entry_voxel].astype(np.int32),
        bits,
        chosen,
        stats,
        macro,
        mres,
    )


def box_only(lo: np.ndarray, hi: np.ndarray) -> Grid:
    """A one-voxel grid of no references over [lo, hi] (padded as `build_grid` pads): the
    node's box for a node that answers rays from its hierarchy instead."""
    glo, ghi = grow_box(np.asarray(lo, float), np.asarray(hi, float))
    res = np.ones(3, np.int64)
    stats = {
        "resolution": [1, 1, 1],
        "storage": "csr",
        "structure_bytes": 0,
        "storage_reason": "box only: the node's hierarchy holds the objects",
    }
    return Grid(
        glo,
        ghi - glo,
        res,
        np.zeros(0, np.int32),
        np.zeros(2, np.int32),
        None,
        None,
        None,
        None,
        None,
        "csr",
        stats,
        np.zeros(1, np.uint8),
        res.copy(),
    )
