"""Packed appends for the CPU's neighbour lists: one AVX-512 instruction sequence tests a chunk of
candidates and appends those within the support to a list.

The list builder and the skin's filter (grid.py) test each candidate j against row i's support and
append the accepted ones; about a third are accepted, in no pattern a branch predictor could learn.
The scalar loop therefore stores every candidate and advances the count by the test's outcome (no
branch), but the count still chains one candidate to the next, so LLVM leaves it scalar. AVX-512
has the missing instruction: ``vpcompressd`` packs the lanes a mask selects into consecutive lanes.
numba has no vector types, so the chunk is written here in LLVM IR (an ``@intrinsic``): gather
x_j, form |x_i - x_j|^2 with the same float operations in the same order as the scalar loop
((dx dx + dy dy) + dz dz, no fused multiply-add), compare with H^2, pack the accepted indices in a
register, count them with a population count and store that many lanes (a masked store).

Packed in a register, not compress-stored to memory (``llvm.masked.compressstore``, ``vpcompressd``
with a memory operand): AMD's Zen 4 runs the memory form as microcode, and on an AMD EPYC
(2026-12-07, evening) the list filter then took twice the scalar loop's time (the 49k dam break's
grid stage 12.1-13.9 ms against 5.6-8.6 ms scalar); packed in a register and stored with a mask,
6.1-8.2 ms. The entries written, and where, are the same either way.

The same candidates pass and are stored in the same order as by the scalar loop, so the lists are
identical whichever path built them (tested in tests/test_grid.py), and a run's bits do not depend
on the CPU it ran on.

``AVX512``: whether this process compiles for a CPU with AVX-512F (the features numba targets,
sphcore/__init__.py). Without it LLVM would emulate the masked instructions lane by lane, slower
than the scalar loop, so grid.py then keeps the scalar loop. A chunk is ``lanes(x)`` candidates:
16 in float32, 8 in float64 (one 512-bit register of coordinates).
"""
import numba
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


def _compiles_for_avx512() -> bool:
    """Whether numba compiles for AVX-512F with its 256-bit forms (VL): the features it targets
    (NUMBA_CPU_FEATURES, or the host's). LLVM makes AVX-512F depend on FMA, so ``-fma`` turns it off."""
    features = numba.config.CPU_FEATURES
    if not features:
        if numba.config.CPU_NAME not in (None, "host"):  # another CPU named (NUMBA_CPU_NAME): its features unknown
            return False
        from numba.core.codegen import get_host_cpu_features
        features = get_host_cpu_features()
    features = features.split(",")
    return "+avx512f" in features and "+avx512vl" in features and "-fma" not in features


AVX512 = _compiles_for_avx512()

_I32 = ir.IntType(32)
_I64 = ir.IntType(64)


def _lanes(float_type) -> int:
    """Candidates per chunk: one 512-bit register of coordinates."""
    return 16 if float_type == types.float32 else 8


def _declare(builder, name, ret, args):
    return cgutils.get_or_insert_function(builder.module, ir.FunctionType(ret, args), name)


def _splat(builder, value, vector_type):
    v = builder.insert_element(ir.Constant(vector_type, ir.Undefined), value, ir.Constant(_I32, 0))
    return builder.shuffle_vector(v, ir.Constant(vector_type, ir.Undefined),
                                  ir.Constant(ir.VectorType(_I32, vector_type.count), [0] * vector_type.count))


def _row_start(builder, array, row):
    """The address (i64) of row ``row`` of a 2D array."""
    return builder.add(builder.ptrtoint(array.data, _I64), builder.mul(row, builder.extract_value(array.strides, 0)))


def _element(builder, array, row, column):
    """The address (i64) of int32 element [row, column] of a C-ordered 2D array."""
    return builder.add(_row_start(builder, array, row), builder.mul(column, ir.Constant(_I64, 4)))


def _append_within(context, builder, x_type, x, j64, active, xi, yi, zi, H2, nbr_type, nbr, row, count):
    """Shared body: j64 (<L x i64>) the candidates, ``active`` (<L x i1>) the lanes that hold one;
    appends those within H2 of (xi, yi, zi) to nbr[row, count:]; returns the new count (i64)."""
    L = j64.type.count
    real = context.get_value_type(x_type.dtype)
    width = context.get_abi_sizeof(real)
    xa = context.make_array(x_type)(context, builder, x)
    na = context.make_array(nbr_type)(context, builder, nbr)
    vreal = ir.VectorType(real, L)
    vi64 = ir.VectorType(_I64, L)
    vi1 = ir.VectorType(ir.IntType(1), L)
    pointers = ir.VectorType(real.as_pointer(), L)
    gather = _declare(builder, f"llvm.masked.gather.v{L}{'f32' if width == 4 else 'f64'}.v{L}p0", vreal,
                      [pointers, _I32, vi1, vreal])
    # x[j, c] lies at data + j * strides[0] + c * strides[1] (bytes)
    row_bytes = builder.mul(j64, _splat(builder, builder.extract_value(xa.strides, 0), vi64))
    base = builder.add(_splat(builder, builder.ptrtoint(xa.data, _I64), vi64), row_bytes)
    column = builder.extract_value(xa.strides, 1)
    zero = ir.Constant(vreal, [0.0] * L)
    d = []
    for c, xc in enumerate((xi, yi, zi)):
        offset = _splat(builder, builder.mul(column, ir.Constant(_I64, c)), vi64)
        at = builder.inttoptr(builder.add(base, offset), pointers)
        xj = builder.call(gather, [at, ir.Constant(_I32, width), active, zero])
        d.append(builder.fsub(_splat(builder, xc, vreal), xj))
    r2 = builder.fadd(builder.fadd(builder.fmul(d[0], d[0]), builder.fmul(d[1], d[1])), builder.fmul(d[2], d[2]))
    inside = builder.and_(builder.fcmp_ordered("<", r2, _splat(builder, H2, vreal)), active)
    vi32 = ir.VectorType(_I32, L)
    bits = ir.IntType(L)
    mask_bits = builder.bitcast(inside, bits)
    popcount = _declare(builder, f"llvm.ctpop.i{L}", bits, [bits])
    kept = builder.zext(builder.call(popcount, [mask_bits]), _I64)  # the accepted candidates
    if nbr_type.layout == "C":  # a row's entries are adjacent: pack in a register, store the first `kept` lanes
        compress = _declare(builder, f"llvm.experimental.vector.compress.v{L}i32", vi32, [vi32, vi1, vi32])
        packed = builder.call(compress, [builder.trunc(j64, vi32), inside, ir.Constant(vi32, ir.Undefined)])
        first = _lane_mask(builder, kept, L)
        store = _declare(builder, f"llvm.masked.store.v{L}i32.p0", ir.VoidType(), [vi32, vi32.as_pointer(), _I32, vi1])
        builder.call(store, [packed, builder.inttoptr(_element(builder, na, row, count), vi32.as_pointer()),
                             ir.Constant(_I32, 4), first])
    else:  # any other layout (the CUDA simulator's column-major lists): lane l goes to column count +
        # (accepted lanes before l), a scatter
        vbits = ir.VectorType(bits, L)
        before = builder.and_(_splat(builder, mask_bits, vbits), ir.Constant(vbits, [(1 << lane) - 1 for lane in range(L)]))
        vpop = _declare(builder, f"llvm.ctpop.v{L}i{L}", vbits, [vbits])
        column = builder.add(_splat(builder, count, vi64), builder.zext(builder.call(vpop, [before]), vi64))
        at = builder.add(_splat(builder, _row_start(builder, na, row), vi64),
                         builder.mul(column, _splat(builder, builder.extract_value(na.strides, 1), vi64)))
        vptr = ir.VectorType(_I32.as_pointer(), L)
        scatter = _declare(builder, f"llvm.masked.scatter.v{L}i32.v{L}p0", ir.VoidType(), [vi32, vptr, _I32, vi1])
        builder.call(scatter, [builder.trunc(j64, vi32), builder.inttoptr(at, vptr), ir.Constant(_I32, 4), inside])
    return builder.add(count, kept)


def _lane_mask(builder, left, L):
    vi64 = ir.VectorType(_I64, L)
    return builder.icmp_unsigned("<", ir.Constant(vi64, list(range(L))), _splat(builder, left, vi64))


@intrinsic
def append_listed(typingctx, x, cand, row, k, left, xi, yi, zi, H2, nbr, count):
    """The candidates cand[row, k : k + min(lanes, left)] within H2 of (xi, yi, zi), in order, written to
    nbr[row, count:] (never more than min(lanes, left) entries); returns the new count. x (n, 3)
    real; cand and nbr (n, columns) int32 and C-ordered (a row's entries adjacent)."""
    if cand.layout != "C" or nbr.layout != "C" or cand.dtype != types.int32 or nbr.dtype != types.int32:
        return None
    real = x.dtype
    sig = types.int64(x, cand, types.int64, types.int64, types.int64, real, real, real, real, nbr, types.int64)

    def codegen(context, builder, signature, args):
        x_, cand_, row_, k_, left_, xi_, yi_, zi_, H2_, nbr_, count_ = args
        L = _lanes(real)
        active = _lane_mask(builder, left_, L)
        ca = context.make_array(signature.args[1])(context, builder, cand_)
        at = _element(builder, ca, row_, k_)
        vi32 = ir.VectorType(_I32, L)
        load = _declare(builder, f"llvm.masked.load.v{L}i32.p0", vi32,
                        [vi32.as_pointer(), _I32, active.type, vi32])
        j = builder.call(load, [builder.inttoptr(at, vi32.as_pointer()), ir.Constant(_I32, 4), active,
                                ir.Constant(vi32, [0] * L)])
        return _append_within(context, builder, signature.args[0], x_, builder.sext(j, ir.VectorType(_I64, L)), active,
                              xi_, yi_, zi_, H2_, signature.args[9], nbr_, row_, count_)
    return sig, codegen


@intrinsic
def append_range(typingctx, x, lo, left, xi, yi, zi, H2, nbr, row, count):
    """The rows j = lo .. lo + min(lanes, left) - 1 within H2 of (xi, yi, zi), in order, written to
    nbr[row, count:] (never more than min(lanes, left) entries); returns the new count. nbr (n,
    columns) int32, in any layout (C: one compress-store; otherwise a scatter)."""
    if nbr.dtype != types.int32:
        return None
    real = x.dtype
    sig = types.int64(x, types.int64, types.int64, real, real, real, real, nbr, types.int64, types.int64)

    def codegen(context, builder, signature, args):
        x_, lo_, left_, xi_, yi_, zi_, H2_, nbr_, row_, count_ = args
        L = _lanes(real)
        vi64 = ir.VectorType(_I64, L)
        j = builder.add(_splat(builder, lo_, vi64), ir.Constant(vi64, list(range(L))))
        return _append_within(context, builder, signature.args[0], x_, j, _lane_mask(builder, left_, L),
                              xi_, yi_, zi_, H2_, signature.args[7], nbr_, row_, count_)
    return sig, codegen


@intrinsic
def lanes(typingctx, x):
    """Candidates per chunk of append_listed / append_range for the positions ``x`` (a constant)."""
    def codegen(context, builder, signature, args):
        return ir.Constant(_I64, _lanes(x.dtype))
    return types.int64(x), codegen
