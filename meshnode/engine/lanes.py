"""The four child boxes of a hierarchy node (`bvh.BvhArrays`) against one ray in one set of
vector instructions: written as LLVM vector code, since numba leaves its SLP vectoriser off
and a four-step loop is below what the loop vectoriser takes (written as a loop or as four
lanes, numba made scalar code, and the 4-wide walk was no faster than the binary one:
tetra 0.86x, the million-triangle tetrahedron 1.01x; in vector code 1.05x and 1.28x).
"""

import math

from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

SLACK = 1.0 + 1e-12  # box exits are widened by this: round-off never loses a hit on a face
LANES = 4


def _splat(builder, x, vec):
    """x in every lane of the vector type vec."""
    undef = ir.Constant(vec, ir.Undefined)
    first = builder.insert_element(undef, x, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(first, undef, ir.Constant(ir.VectorType(ir.IntType(32), 4), 0))


def _max(builder, a, b):
    """numba's max(a, b) of floats, lane by lane: b if b > a else a."""
    return builder.select(builder.fcmp_ordered(">", b, a), b, a)


def _min(builder, a, b):
    """numba's min(a, b) of floats, lane by lane: b if b < a else a."""
    return builder.select(builder.fcmp_ordered("<", b, a), b, a)


@intrinsic
def slab4(typingctx, nodes, at, nx, ny, nz, ox, oy, oz, rx, ry, rz, t_lo, bound, entry):
    """Entry t of each of the four boxes of the node whose planes start at nodes[at] (lanes of
    4: lo x, lo y, lo z, hi x, hi y, hi z; float32) into entry[0:4], inf for a box the ray
    misses in (t_lo, bound); returns the entered boxes as a bitmask (bit j: box j). nx, ny,
    nz (0 or 12) pick each axis's near planes by the sign of the direction (rx, ry, rz are
    finite reciprocals: no product is inf * 0). In float64: per axis (plane - o) * r, the
    entry the max of the near ones, the exit the min of the far ones times SLACK, entered
    when entry <= exit, exit > t_lo and entry < bound: the binary walk's arithmetic, whose
    boxes were the same, lane by lane, so each box is entered exactly as it was there."""
    sig = types.int64(nodes, at, nx, ny, nz, ox, oy, oz, rx, ry, rz, t_lo, bound, entry)

    def codegen(context, builder, signature, args):
        planes = context.make_array(signature.args[0])(context, builder, args[0])
        out = context.make_array(signature.args[13])(context, builder, args[13])
        at_, nx_, ny_, nz_, ox_, oy_, oz_, rx_, ry_, rz_, lo_, bound_ = args[1:13]
        i64, f64 = ir.IntType(64), ir.DoubleType()
        d4, s4 = ir.VectorType(f64, LANES), ir.VectorType(ir.FloatType(), LANES)

        def planes_at(column, near, sign, o, r):
            k = builder.add(at_, ir.Constant(i64, column))
            k = builder.add(k, near) if sign > 0 else builder.sub(k, near)
            ptr = builder.bitcast(builder.gep(planes.data, [k]), s4.as_pointer())
            v = builder.fpext(builder.load(ptr, align=4), d4)
            return builder.fmul(builder.fsub(v, _splat(builder, o, d4)), _splat(builder, r, d4))

        axes = ((nx_, ox_, rx_), (ny_, oy_, ry_), (nz_, oz_, rz_))
        near = [planes_at(4 * a, n, 1, o, r) for a, (n, o, r) in enumerate(axes)]
        far = [planes_at(12 + 4 * a, n, -1, o, r) for a, (n, o, r) in enumerate(axes)]
        t0 = _max(builder, near[0], _max(builder, near[1], near[2]))
        t1 = _min(builder, far[0], _min(builder, far[1], far[2]))
        t1 = builder.fmul(t1, _splat(builder, ir.Constant(f64, SLACK), d4))
        ok = builder.and_(
            builder.fcmp_ordered("<=", t0, t1),
            builder.fcmp_ordered(">", t1, _splat(builder, lo_, d4)),
        )
        ok = builder.and_(ok, builder.fcmp_ordered("<", t0, _splat(builder, bound_, d4)))
        inf = _splat(builder, ir.Constant(f64, math.inf), d4)
        out_ptr = builder.bitcast(out.data, d4.as_pointer())
        builder.store(builder.select(ok, t0, inf), out_ptr, align=8)
        return builder.zext(builder.bitcast(ok, ir.IntType(LANES)), i64)

    return sig, codegen
