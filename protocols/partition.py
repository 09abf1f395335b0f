"""The plan made concrete for one render: each node's image rectangles, box and cell, and the
scene's occupancy map (`Partition`).

The host's planning makes it (`host.planning.partition`), CONFIG carries it beside the render's
records (`protocols.render`), and every node reads from it which pixels it starts and which
node takes a ray on; its wire form is checked like theirs, field by field.
"""

from dataclasses import dataclass

import numpy as np

from protocols.render import EVERYWHERE, MAX_NODES, MAX_SIDE
from protocols.spec import Spec, SpecError

MAX_RECTS = 1 << 20  # image rectangles (tiles) in one partition
MAX_OCC_SIDE = 256  # voxels along a side of the scene's occupancy map


@dataclass(frozen=True)
class Partition(Spec):
    """The plan made concrete: node n's rectangles (x0, x1, y0, y1) of the sample grid (one in
    object space, its tiles in image space; `owner[i]` is rectangle i's node), its box (lo,
    hi: the objects it holds and the space it traces, grown by the overlap) and its cell (the
    box before growing: cells tile the scene, and a ray is taken on by the node whose cell
    holds it, so overlap keeps rays longer on a node without drawing them all to one), and
    the scene's box, with its occupancy map (`occ_res` voxels along x, y, z, and `occ_bits`,
    one bit per voxel packed as numpy's packbits does, x fastest: 1 where some object may
    lie; nodes end or skip segments with only empty voxels ahead; the default, one occupied
    voxel, skips nothing), and `occ_fine`: each occupied voxel's 4x4x4 sub-voxels a surface may
    reach, in voxel order, a little-endian uint64 each (bit x + 4 y + 16 z; empty: none, the
    voxels alone); under MeshPlan.copies `takers[i]`, the node taking rectangle i's
    eye rays on where its owner (a node holding that node's engine: a neighbour, or any
    node for a shared cell) does not; `inner_lo`..`inner_hi`, where the scene's small
    objects lie in a box far smaller than the scene's (a floor beneath them), a second map
    there (`inner_res`, `inner_bits`, `inner_fine` as the first's; empty: none)."""

    rects: tuple
    owner: tuple
    los: tuple
    his: tuple
    scene_lo: tuple
    scene_hi: tuple
    cell_los: tuple
    cell_his: tuple
    occ_res: tuple = EVERYWHERE[0]
    occ_bits: bytes = EVERYWHERE[1]
    takers: tuple = ()
    occ_fine: bytes = b""
    inner_lo: tuple = ()
    inner_hi: tuple = ()
    inner_res: tuple = ()
    inner_bits: bytes = b""
    inner_fine: bytes = b""

    def check(self) -> None:
        n = len(self.los) if isinstance(self.los, tuple) else -1
        if not 1 <= n <= MAX_NODES:
            self.fail("los", f"must list 1 to {MAX_NODES} boxes")
        m = len(self.rects) if isinstance(self.rects, tuple) else -1
        if not 1 <= m <= MAX_RECTS:
            self.fail("rects", f"must list 1 to {MAX_RECTS} rectangles")
        r = _array(self, "rects", np.int64, (m, 4))
        if (
            np.any(r < 0)
            or np.any(r > MAX_SIDE + 1)
            or np.any(r[:, 1] < r[:, 0])
            or np.any(r[:, 3] < r[:, 2])
        ):
            self.fail("rects", "each must be x0 <= x1, y0 <= y1 inside the image")
        owner = _array(self, "owner", np.int64, (m,))
        if np.any(owner < 0) or np.any(owner >= n):
            self.fail("owner", f"every rectangle's node must be from 0 to {n - 1}")
        if self.takers != ():
            takers = _array(self, "takers", np.int64, (m,))
            if np.any(takers < 0) or np.any(takers >= n):
                self.fail("takers", f"every rectangle's taker must be from 0 to {n - 1}")
        los, his = _array(self, "los", float, (n, 3)), _array(self, "his", float, (n, 3))
        if np.any(los > his):
            self.fail("his", "every box needs lo <= hi")
        c_lo = _array(self, "cell_los", float, (n, 3))
        c_hi = _array(self, "cell_his", float, (n, 3))
        if np.any(c_lo > c_hi) or np.any(c_lo < los) or np.any(c_hi > his):
            self.fail("cell_his", "every cell needs lo <= hi inside its node's box")
        if np.any(_array(self, "scene_lo", float, (3,)) > _array(self, "scene_hi", float, (3,))):
            self.fail("scene_hi", "the scene box needs lo <= hi")
        self._check_map("occ_res", "occ_bits", "occ_fine")
        if self.inner_res != ():
            lo, hi = _array(self, "inner_lo", float, (3,)), _array(self, "inner_hi", float, (3,))
            if np.any(lo >= hi) or np.any(lo < self.scene_lo) or np.any(hi > self.scene_hi):
                self.fail("inner_hi", "the inner map's box needs lo < hi inside the scene's")
            self._check_map("inner_res", "inner_bits", "inner_fine")
            if bool(self.inner_fine) != bool(self.occ_fine):
                self.fail("inner_fine", "must have sub-voxels where the outer map has them")
        elif self.inner_lo != () or self.inner_hi != () or self.inner_bits or self.inner_fine:
            self.fail("inner_res", "must be given with the rest of the inner map")

    def _check_map(self, res_name: str, bits_name: str, fine_name: str) -> None:
        """A map's voxels per axis, its bits (one a voxel) and its sub-voxel masks (8 bytes
        an occupied voxel, or none)."""
        res = _array(self, res_name, np.int64, (3,))
        if np.any(res < 1) or np.any(res > MAX_OCC_SIDE):
            self.fail(res_name, f"voxels per axis must be from 1 to {MAX_OCC_SIDE}")
        want, bits, fine = (
            -(-int(res.prod()) // 8),
            getattr(self, bits_name),
            getattr(self, fine_name),
        )
        if not isinstance(bits, bytes) or len(bits) != want:
            got = f"{len(bits)} bytes" if isinstance(bits, bytes) else f"a {type(bits).__name__}"
            raise SpecError(
                f"Partition.{bits_name} is {got}: must be {want} bytes, a bit for each "
                f"of the {'x'.join(map(str, res.tolist()))} voxels"
            )
        occupied = int(np.unpackbits(np.frombuffer(bits, np.uint8))[: res.prod()].sum())
        if not isinstance(fine, bytes) or len(fine) not in (0, 8 * occupied):
            self.fail(
                fine_name, f"must be empty or 8 bytes for each of the {occupied} occupied voxels"
            )

    @property
    def inner(self) -> tuple | None:
        """The inner map as `occupancy_arrays` takes it (lo, hi, res, bits, fine); None."""
        if self.inner_res == ():
            return None
        return self.inner_lo, self.inner_hi, self.inner_res, self.inner_bits, self.inner_fine

    @classmethod
    def make(
        cls,
        rects,
        los,
        his,
        scene_box,
        owner=None,
        cells=None,
        occupancy=EVERYWHERE,
        takers=(),
        inner=None,
    ) -> "Partition":
        """From arrays; `owner` None: rectangle n is node n's (object space); `cells` (lo,
        hi) None: the boxes themselves (no overlap); `occupancy` (voxels per axis, bits[,
        sub-voxel masks]); `takers` empty: each rectangle's owner takes its eye rays on;
        `inner` (lo, hi, voxels per axis, bits, masks) an inner map, or None."""

        def rows(a):
            return tuple(tuple(x) for x in np.asarray(a, float).tolist())

        owner = range(len(rects)) if owner is None else owner
        cells = (los, his) if cells is None else cells
        return cls(
            tuple(tuple(x) for x in np.asarray(rects).tolist()),
            tuple(int(o) for o in owner),
            rows(los),
            rows(his),
            *(tuple(np.asarray(b, float).tolist()) for b in scene_box),
            rows(cells[0]),
            rows(cells[1]),
            tuple(int(v) for v in occupancy[0]),
            bytes(occupancy[1]),
            tuple(int(t) for t in takers),
            bytes(occupancy[2]) if len(occupancy) > 2 else b"",
            *(() if inner is None else _inner_fields(inner)),
        )

    def rects_of(self, node: int) -> list[tuple[int, int, int, int]]:
        """The rectangles node `node` owns, in order."""
        return [r for r, o in zip(self.rects, self.owner, strict=True) if o == node]

    @classmethod
    def decode(cls, values: dict) -> dict:
        def tup(v):
            return tuple(tup(x) for x in v) if isinstance(v, list | tuple) else v

        return {k: tup(v) for k, v in values.items()}

    @property
    def nodes(self) -> int:
        return len(self.los)

    @property
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.los, float), np.array(self.his, float)

    @property
    def cells(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.cell_los, float), np.array(self.cell_his, float)

    @property
    def scene_box(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.scene_lo, float), np.array(self.scene_hi, float)


def _array(spec: Spec, name: str, dtype, shape) -> np.ndarray:
    """A field of nested tuples as a finite array of `shape`, or SpecError naming it."""
    try:
        a = np.array(getattr(spec, name), dtype=dtype)
    except (TypeError, ValueError, OverflowError):
        spec.fail(name, f"must be numbers shaped {shape}")
    if a.shape != shape or not np.all(np.isfinite(a)):
        spec.fail(name, f"must be finite numbers shaped {shape}")
    return a


def _inner_fields(inner) -> tuple:
    """An inner map's Partition fields from (lo, hi, voxels per axis, bits, masks)."""
    lo, hi, res, bits, fine = inner
    return (
        tuple(np.asarray(lo, float).tolist()),
        tuple(np.asarray(hi, float).tolist()),
        tuple(int(v) for v in res),
        bytes(bits),
        bytes(fine),
    )
