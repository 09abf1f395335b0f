"""A packet's rows (`packet.packet_walk`'s scratch: one row of PACKET float64 per quantity, a
column per ray) in whole vector instructions, written as LLVM vector code like `lanes.slab4`.

Written as numba loops over the packet's n rays, the loop vectoriser made a vector body for
16 or more rays and ran packets of 8 through its scalar remainder; with a trip count of
PACKET it unrolled them into scalar code (numba leaves the SLP vectoriser off). Here every
row operation is a fixed number of vector instructions whatever n is: columns past n hold
rays that enter nothing (`packet._pad`). Each lane does the scalar code's arithmetic, in the
same order (no fused multiply-adds: the IR carries no fast-math flags), so each ray gets the
same bits as walked alone.
"""

import math

from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from meshnode.engine.bvh import HUGE, NEAR_ZERO
from meshnode.engine.intersect import EDGE_SLACK
from meshnode.engine.lanes import SLACK

PACKET = 8  # rays `packet_walk` takes through the tree together (one vector register)

_I32 = ir.IntType(32)
_I64 = ir.IntType(64)
_F64 = ir.DoubleType()
_VEC = ir.VectorType(_F64, PACKET)
_IVEC = ir.VectorType(_I64, PACKET)


def _splat(builder, x, vec=_VEC):
    """x in every lane."""
    undef = ir.Constant(vec, ir.Undefined)
    first = builder.insert_element(undef, x, ir.Constant(_I32, 0))
    zeros = ir.Constant(ir.VectorType(_I32, PACKET), [0] * PACKET)
    return builder.shuffle_vector(first, undef, zeros)


def _const(x):
    """The float64 constant x in every lane."""
    return ir.Constant(_VEC, [x] * PACKET)


def _row_ptr(context, builder, aryty, ary, row, vec=_VEC):
    """Pointer to row `row` of a C-contiguous (rows, PACKET) array, as one vector."""
    arr = context.make_array(aryty)(context, builder, ary)
    start = builder.mul(row, ir.Constant(_I64, PACKET))
    return builder.bitcast(builder.gep(arr.data, [start]), vec.as_pointer())


def _load(context, builder, aryty, ary, row, vec=_VEC):
    return builder.load(_row_ptr(context, builder, aryty, ary, row, vec), align=8)


def _mask_bits(builder, cond):
    """A vector of i1 as an int64 bitmask (bit k: lane k)."""
    return builder.zext(builder.bitcast(cond, ir.IntType(PACKET)), _I64)


def _count(builder, module, cond):
    """How many lanes of a vector of i1 are set."""
    bits = _mask_bits(builder, cond)
    ctpop = module.declare_intrinsic("llvm.ctpop", [_I64])
    return builder.call(ctpop, [bits])


def _not(builder, cond):
    """Lane-wise not of a vector of i1."""
    return builder.xor(cond, ir.Constant(ir.VectorType(ir.IntType(1), PACKET), [1] * PACKET))


def _lt(builder, a, b):
    return builder.fcmp_ordered("<", a, b)


def _gt(builder, a, b):
    return builder.fcmp_ordered(">", a, b)


def _select_min(builder, a, b):
    """numba's min(a, b) of floats, lane by lane: b if b < a else a."""
    return builder.select(_lt(builder, b, a), b, a)


def _hmin(builder, v):
    """The smallest lane of v (by halves: no NaN ever reaches it, so the order is free)."""
    width = PACKET
    while width > 1:
        width //= 2
        lo = builder.shuffle_vector(
            v, v, ir.Constant(ir.VectorType(_I32, width), list(range(width)))
        )
        hi = builder.shuffle_vector(
            v, v, ir.Constant(ir.VectorType(_I32, width), list(range(width, 2 * width)))
        )
        v = builder.select(builder.fcmp_ordered("<", hi, lo), hi, lo)
    return builder.extract_element(v, ir.Constant(_I32, 0))


def _c_rows(array):
    """Whether `array` is a C-contiguous 2-D array (a packet's rows)."""
    return isinstance(array, types.Array) and array.ndim == 2 and array.layout == "C"


@intrinsic
def packet_slabs(typingctx, flat, at, f, row, o_row, r_row, lo_row, bound_row):
    """One box (planes flat[at], flat[at + 4], flat[at + 8], then + HI: one lane of a
    `bvh` node) against every ray of the packet f: each ray's entry t into f[row], inf for
    a ray that does not enter it in (t_lo, bound); returns the nearest entry (inf: none
    enters). f rows o_row.. origins, r_row.. reciprocal directions, lo_row t_lo, bound_row
    the bound. `lanes.slab4`'s arithmetic, the near plane chosen per ray by its direction's
    sign."""
    if not _c_rows(f):
        return None
    sig = types.float64(flat, types.int64, f, *([types.int64] * 5))

    def codegen(context, builder, signature, args):
        flat_, at_, f_, row_, o_, r_, lo_, bound_ = args
        planes = context.make_array(signature.args[0])(context, builder, flat_)
        fty = signature.args[2]

        def plane(column):
            k = builder.add(at_, ir.Constant(_I64, column))
            value = builder.fpext(builder.load(builder.gep(planes.data, [k])), _F64)
            return _splat(builder, value)

        def row_at(base, a):
            return _load(context, builder, fty, f_, builder.add(base, ir.Constant(_I64, a)))

        zero = _const(0.0)
        t0 = t1 = None
        for a in (2, 1, 0):  # max(near x, max(near y, near z)), as the scalar walks nest it
            o = row_at(o_, a)
            r = row_at(r_, a)
            lo = builder.fmul(builder.fsub(plane(4 * a), o), r)
            hi = builder.fmul(builder.fsub(plane(12 + 4 * a), o), r)
            up = builder.fcmp_ordered(">=", r, zero)
            near = builder.select(up, lo, hi)
            far = builder.select(up, hi, lo)
            if t0 is None:
                t0, t1 = near, far
            else:
                t0 = builder.select(_gt(builder, t0, near), t0, near)  # max(near, t0)
                t1 = _select_min(builder, far, t1)  # min(far, t1)
        t1 = builder.fmul(t1, _const(SLACK))
        ok = builder.and_(builder.fcmp_ordered("<=", t0, t1), _gt(builder, t1, row_at(lo_, 0)))
        ok = builder.and_(ok, _lt(builder, t0, row_at(bound_, 0)))
        out = builder.select(ok, t0, _const(math.inf))
        builder.store(out, _row_ptr(context, builder, fty, f_, row_), align=8)
        return _hmin(builder, out)

    return sig, codegen


@intrinsic
def packet_triangle(
    typingctx, tr, i, self_gid, f, origin, o_row, d_row, lo_row, cur_row, bound_row, out_row
):
    """`intersect.hit_triangle` of triangle row i of tr (v0, e1, e2) for every ray of the
    packet f that enters the leaf before its bound (f[cur_row] < f[bound_row]): t or inf
    into f[out_row]. A ray leaving this very triangle (origin[k] == self_gid) misses it.
    Returns how many rays were tested plus, from bit 8 up, the mask of the rays that hit."""
    if not _c_rows(f):
        return None
    sig = types.int64(tr, types.int64, types.int64, f, origin, *([types.int64] * 6))

    def codegen(context, builder, signature, args):
        tr_, i_, gid_, f_, origin_, o_, d_, lo_, cur_, bound_, out_ = args
        tty, fty = signature.args[0], signature.args[3]
        table = context.make_array(tty)(context, builder, tr_)
        row_start = builder.mul(i_, builder.extract_value(table.strides, 0))
        col_stride = builder.extract_value(table.strides, 1)

        def col(c):
            byte = builder.add(row_start, builder.mul(col_stride, ir.Constant(_I64, c)))
            raw = builder.bitcast(table.data, ir.IntType(8).as_pointer())
            ptr = builder.bitcast(builder.gep(raw, [byte]), _F64.as_pointer())
            return _splat(builder, builder.load(ptr))

        def row_at(base, a=0):
            return _load(context, builder, fty, f_, builder.add(base, ir.Constant(_I64, a)))

        mul, sub, add = builder.fmul, builder.fsub, builder.fadd
        v0x, v0y, v0z = col(0), col(1), col(2)
        e1x, e1y, e1z = col(3), col(4), col(5)
        e2x, e2y, e2z = col(6), col(7), col(8)
        dx, dy, dz = row_at(d_, 0), row_at(d_, 1), row_at(d_, 2)
        px = sub(mul(dy, e2z), mul(dz, e2y))
        py = sub(mul(dz, e2x), mul(dx, e2z))
        pz = sub(mul(dx, e2y), mul(dy, e2x))
        det = add(add(mul(e1x, px), mul(e1y, py)), mul(e1z, pz))
        inv = builder.fdiv(_const(1.0), det)
        sx = sub(row_at(o_, 0), v0x)
        sy = sub(row_at(o_, 1), v0y)
        sz = sub(row_at(o_, 2), v0z)
        u = mul(add(add(mul(sx, px), mul(sy, py)), mul(sz, pz)), inv)
        qx = sub(mul(sy, e1z), mul(sz, e1y))
        qy = sub(mul(sz, e1x), mul(sx, e1z))
        qz = sub(mul(sx, e1y), mul(sy, e1x))
        v = mul(add(add(mul(dx, qx), mul(dy, qy)), mul(dz, qz)), inv)
        t = mul(add(add(mul(e2x, qx), mul(e2y, qy)), mul(e2z, qz)), inv)
        bound = row_at(bound_)
        active = _lt(builder, row_at(cur_), bound)
        low, high = _const(-EDGE_SLACK), _const(1.0 + EDGE_SLACK)
        out_u = builder.or_(_lt(builder, u, low), _gt(builder, u, high))
        out_v = builder.or_(_lt(builder, v, low), _gt(builder, add(u, v), high))
        ok = builder.and_(active, builder.fcmp_unordered("!=", det, _const(0.0)))
        ok = builder.and_(ok, _not(builder, builder.or_(out_u, out_v)))
        ok = builder.and_(ok, builder.and_(_lt(builder, row_at(lo_), t), _lt(builder, t, bound)))
        origins = _load(context, builder, signature.args[4], origin_, ir.Constant(_I64, 0), _IVEC)
        mine = builder.icmp_signed("==", origins, _splat(builder, gid_, _IVEC))
        ok = builder.and_(ok, _not(builder, mine))
        hits = builder.select(ok, t, _const(math.inf))
        builder.store(hits, _row_ptr(context, builder, fty, f_, out_), align=8)
        tested = _count(builder, builder.module, active)
        return builder.or_(tested, builder.shl(_mask_bits(builder, ok), ir.Constant(_I64, 8)))

    return sig, codegen


@intrinsic
def copy_row(typingctx, dst, dst_row, src, src_row):
    """dst[dst_row] = src[src_row] for two (rows, PACKET) float64 arrays: one vector move."""
    if not (_c_rows(dst) and _c_rows(src)):
        return None
    sig = types.void(dst, types.int64, src, types.int64)

    def codegen(context, builder, signature, args):
        d, dr, s, sr = args
        value = _load(context, builder, signature.args[2], s, sr)
        builder.store(value, _row_ptr(context, builder, signature.args[0], d, dr), align=8)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def count_below(typingctx, a, a_row, b, b_row):
    """How many k have a[a_row, k] < b[b_row, k]: rays still live against a bound."""
    if not (_c_rows(a) and _c_rows(b)):
        return None
    sig = types.int64(a, types.int64, b, types.int64)

    def codegen(context, builder, signature, args):
        x = _load(context, builder, signature.args[0], args[0], args[1])
        y = _load(context, builder, signature.args[2], args[2], args[3])
        return _count(builder, builder.module, _lt(builder, x, y))

    return sig, codegen


def _call(builder, name, v):
    """The LLVM intrinsic llvm.<name> of one float64 vector (llvmlite names scalar ones only)."""
    full = f"llvm.{name}.v{PACKET}f64"
    fn = builder.module.globals.get(full)
    if fn is None:
        fn = ir.Function(builder.module, ir.FunctionType(_VEC, [_VEC]), name=full)
    return builder.call(fn, [v])


def _abs(builder, v):
    return _call(builder, "fabs", v)


def _reciprocals(context, builder, fty, f_, d, r_):
    """Rows r_.. = `bvh.reciprocal` of the direction rows d (x, y, z vectors)."""
    for a in range(3):
        tiny = _lt(builder, _abs(builder, d[a]), _const(NEAR_ZERO))
        inverse = builder.select(tiny, _const(HUGE), builder.fdiv(_const(1.0), d[a]))
        row = builder.add(r_, ir.Constant(_I64, a))
        builder.store(inverse, _row_ptr(context, builder, fty, f_, row), align=8)


@intrinsic
def reciprocals(typingctx, f, d_row, r_row):
    """Rows r_row.. = `bvh.reciprocal` of the direction rows d_row.. of the packet f: three
    vector divisions for the packet instead of three divisions a ray."""
    if not _c_rows(f):
        return None
    sig = types.void(f, types.int64, types.int64)

    def codegen(context, builder, signature, args):
        fty, (f_, d_, r_) = signature.args[0], args
        rows = [
            _load(context, builder, fty, f_, builder.add(d_, ir.Constant(_I64, a)))
            for a in range(3)
        ]
        _reciprocals(context, builder, fty, f_, rows, r_)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def unit_directions(typingctx, f, d_row):
    """The direction rows d_row.. of the packet f made unit length as `queries.ray_hits`
    scales a ray's (by the largest component first, so the norm cannot overflow; every lane
    finite and non-zero, or garbage in a column no ray uses): vector divisions and a root for
    the packet, instead of two divisions and a root a ray."""
    if not _c_rows(f):
        return None
    sig = types.void(f, types.int64)

    def codegen(context, builder, signature, args):
        fty, (f_, d_) = signature.args[0], args
        at = [builder.add(d_, ir.Constant(_I64, a)) for a in range(3)]
        d = [_load(context, builder, fty, f_, row) for row in at]
        ax, ay, az = (_abs(builder, x) for x in d)
        big = builder.select(_gt(builder, az, ay), az, ay)
        big = builder.select(_gt(builder, big, ax), big, ax)
        s = builder.fdiv(_const(1.0), big)
        squares = [builder.fmul(builder.fmul(x, s), builder.fmul(x, s)) for x in d]
        total = builder.fadd(builder.fadd(squares[0], squares[1]), squares[2])
        k = builder.fdiv(s, _call(builder, "sqrt", total))
        d = [builder.fmul(x, k) for x in d]
        for x, row in zip(d, at, strict=True):
            builder.store(x, _row_ptr(context, builder, fty, f_, row), align=8)
        return context.get_dummy_value()

    return sig, codegen
