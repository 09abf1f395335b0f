"""A hierarchy leaf's triangles against one ray four at a time, and prefetches of what a node's
entered children will read, both written as LLVM code (numba has neither: `lanes` says why
vector code is written by hand).

On the million-triangle tetrahedron (`bench.embree --levels 9`) a ray that hits spends most
of its time waiting for memory: its triangles (75 MB of rows) and the lower nodes (11 MB)
come from far caches or DRAM, each load waiting on the one before. In a hierarchy that
large (PREFETCH_FROM) a node visit that enters children asks for their lines at once
(`prefetch_entered`), so those loads overlap other work instead of following it: a packet
of eight rays (`packet.packet_walk`) 211 -> 197 ns a ray, a shadow ray walked alone 1.07x
faster (eye rays alone, which mostly go straight down, no faster). A leaf's triangles are
tested in one set of 4-lane instructions (`triangles4`) with `intersect.hit_triangle`'s
arithmetic lane by lane, in the same order (no fused multiply-adds: the IR carries no
fast-math flags), so each triangle gets the same bits as tested alone; the hit's gid is
asked for as soon as it is found (the caller reads it: 12 ns a ray when it was not).
"""

import math

from llvmlite import ir
from numba import types, uint64
from numba.extending import intrinsic

from meshnode.engine.intersect import EDGE_SLACK
from meshnode.engine.jit import inline
from meshnode.engine.traverse import TIE, better

WIDTH = 4  # triangles a `triangles4` call tests
LINE = 64  # bytes of a cache line
# Nodes below this many bytes (a 1 MB L2 cache holds them and their objects' rows, or most)
# are not prefetched: there it only cost (teapot's eye rays in packets 1.45 -> 1.37 of
# Embree's, mount_s1's 1.62 -> 1.55).
PREFETCH_FROM = 1 << 20

_I32 = ir.IntType(32)
_I64 = ir.IntType(64)
_F64 = ir.DoubleType()
_VEC = ir.VectorType(_F64, WIDTH)
_BITS = ir.VectorType(ir.IntType(1), WIDTH)


@intrinsic
def prefetch(typingctx, array, index):
    """Ask for the cache line holding element `index` of array's data (read, kept in every
    level): no wait, no fault, nothing loaded into a register."""
    if not isinstance(index, types.Integer):
        return None
    sig = types.void(array, index)

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        ptr = builder.bitcast(builder.gep(data, [args[1]]), ir.IntType(8).as_pointer())
        fnty = ir.FunctionType(ir.VoidType(), [ptr.type, _I32, _I32, _I32])
        name = "llvm.prefetch.p0"
        fn = builder.module.globals.get(name) or ir.Function(builder.module, fnty, name=name)
        builder.call(fn, [ptr, ir.Constant(_I32, 0), ir.Constant(_I32, 3), ir.Constant(_I32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@inline
def prefetch_entered(flat, flat_refs, at, mask, node_cols, ref_col, leaf_bits, tri, first_tri):
    """Prefetch what the children entered (bit j of mask: lane j of the node at flat[at]) will
    read: an inner child's node (its two lines), a leaf of triangles its rows (local ids from
    first_tri up are tri's rows; other kinds are left alone)."""
    if flat.shape[0] < PREFETCH_FROM // 4:  # float32 columns
        return
    while mask != 0:
        lane = _low_lane(mask)
        mask &= mask - 1
        ref = flat_refs[at + uint64(ref_col + lane)]
        if ref > 0:
            node = uint64(ref) * uint64(node_cols)
            prefetch(flat, node)
            prefetch(flat, node + uint64(node_cols // 2))
        elif tri is not None:
            packed = ~ref
            row = (packed >> leaf_bits) - first_tri
            if 0 <= row < tri.shape[0]:
                cols = tri.shape[1]
                end = (row + (packed & ((1 << leaf_bits) - 1))) * cols
                for k in range(row * cols, end, LINE // 8):
                    prefetch(tri, k)
                prefetch(tri, end - 1)


@inline
def _low_lane(mask):
    """The lowest lane set in a non-zero 4-lane mask."""
    return 0 if mask & 1 else (1 if mask & 2 else (2 if mask & 4 else 3))


def _splat(builder, x):
    """x in every lane."""
    undef = ir.Constant(_VEC, ir.Undefined)
    first = builder.insert_element(undef, x, ir.Constant(_I32, 0))
    return builder.shuffle_vector(first, undef, ir.Constant(ir.VectorType(_I32, WIDTH), 0))


def _const(x):
    return ir.Constant(_VEC, [x] * WIDTH)


@intrinsic
def triangles4(typingctx, tr, row, count, ox, oy, oz, dx, dy, dz, t_lo, bound, out):
    """`intersect.hit_triangle` of rows row .. row + min(count, 4) - 1 of tr (v0, e1, e2 in
    its first nine columns) against one ray: each lane's t, or inf, into out[0:4]; returns
    the lanes hit in (t_lo, bound) as a bitmask (bit j: row + j). Lanes past count read row
    itself and are never hit."""
    sig = types.int64(tr, types.int64, types.int64, *([types.float64] * 8), out)

    def codegen(context, builder, signature, args):
        tr_, row_, count_, ox_, oy_, oz_, dx_, dy_, dz_, lo_, bound_, out_ = args
        table = context.make_array(signature.args[0])(context, builder, tr_)
        raw = builder.bitcast(table.data, ir.IntType(8).as_pointer())
        stride = builder.extract_value(table.strides, 0)
        live = ir.Constant(_BITS, ir.Undefined)
        rows = []
        for j in range(WIDTH):
            lane = ir.Constant(_I64, j)
            inside = builder.icmp_signed("<", lane, count_)
            live = builder.insert_element(live, inside, ir.Constant(_I32, j))
            at = builder.select(inside, builder.add(row_, lane), row_)
            rows.append(builder.gep(raw, [builder.mul(at, stride)]))

        def col(c):
            v = ir.Constant(_VEC, ir.Undefined)
            for j, start in enumerate(rows):
                ptr = builder.bitcast(
                    builder.gep(start, [ir.Constant(_I64, 8 * c)]), _F64.as_pointer()
                )
                v = builder.insert_element(v, builder.load(ptr), ir.Constant(_I32, j))
            return v

        mul, sub, add = builder.fmul, builder.fsub, builder.fadd

        def lt(a, b):
            return builder.fcmp_ordered("<", a, b)

        def gt(a, b):
            return builder.fcmp_ordered(">", a, b)

        def dot(a, b):
            return add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]))

        def cross(a, b):
            return [sub(mul(a[k - 2], b[k - 1]), mul(a[k - 1], b[k - 2])) for k in (0, 1, 2)]

        e1 = [col(3), col(4), col(5)]
        e2 = [col(6), col(7), col(8)]
        d = [_splat(builder, x) for x in (dx_, dy_, dz_)]
        p = cross(d, e2)
        det = dot(e1, p)
        inv = builder.fdiv(_const(1.0), det)
        s = [sub(_splat(builder, o), col(c)) for c, o in enumerate((ox_, oy_, oz_))]
        u = mul(dot(s, p), inv)
        q = cross(s, e1)
        v = mul(dot(d, q), inv)
        t = mul(dot(e2, q), inv)
        low, high = _const(-EDGE_SLACK), _const(1.0 + EDGE_SLACK)
        outside = builder.or_(builder.or_(lt(u, low), gt(u, high)), lt(v, low))
        outside = builder.or_(outside, gt(add(u, v), high))
        ok = builder.and_(live, builder.fcmp_unordered("!=", det, _const(0.0)))
        ok = builder.and_(ok, builder.xor(outside, ir.Constant(_BITS, [1] * WIDTH)))
        ok = builder.and_(ok, lt(_splat(builder, lo_), t))
        ok = builder.and_(ok, lt(t, _splat(builder, bound_)))
        data = context.make_array(signature.args[11])(context, builder, out_).data
        hits = builder.select(ok, t, _const(math.inf))
        builder.store(hits, builder.bitcast(data, _VEC.as_pointer()), align=8)
        return builder.zext(builder.bitcast(ok, ir.IntType(WIDTH)), _I64)

    return sig, codegen


@inline
def triangle_leaf(tri, row0, first, end, o, d, t_lo, bound, best, origin, any_hit, gid, out):
    """The leaf of triangles first .. end - 1 (local ids; tri's rows from row0 up) against
    the ray o + t d (tuples), as `bvh.bvh_walk`'s loop of `traverse.test_object` calls tests
    them one by one: a lane counts only below the bound its earlier lanes left, a triangle
    the ray leaves (gid origin) is never hit, and an any-hit walk stops at the first hit.
    best: (t, local id) so far; returns the new best, bound, and how many were tested.
    `out` takes each group's four t."""
    best_t, best_u = best
    tests = 0
    for group in range(first, end, WIDTH):
        n = min(WIDTH, end - group)
        hits = triangles4(
            tri, group - row0, n, o[0], o[1], o[2], d[0], d[1], d[2], t_lo, bound, out
        )
        tests += n
        while hits != 0:
            lane = _low_lane(hits)
            hits &= hits - 1
            u = group + lane
            t = out[lane]
            if origin >= 0 and gid[u] == origin:
                continue
            if t < bound and better(t, u, best_t, best_u, gid):
                best_t, best_u, bound = t, u, t * TIE
                prefetch(gid, u)  # the caller reads its gid: let it come during the walk
                if any_hit:
                    return best_t, best_u, bound, tests - (n - lane - 1)
    return best_t, best_u, bound, tests
