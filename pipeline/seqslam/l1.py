"""Mean absolute difference kernels (numba, all cores) behind ``comparisons.mean_abs_difference``.

Kept in their own module so that importing the comparisons (as ``extract`` does) does not
import numba.

The uint8 kernel is SeqSLAM's hot loop (3576 x 3576 x 2048 byte differences for the
benchmark). numba widens every uint8 operation to 64-bit integers, so a plain loop
vectorises into 4 lanes at best. On CPUs with AVX2 we therefore emit the x86
sum-of-absolute-differences instruction directly (``vpsadbw``: 32 byte pairs per
instruction) through a small LLVM intrinsic, and tile the loops so that a block of query
rows stays in cache while every reference row streams past it once. Results are exact
integer sums either way; elsewhere the plain loop runs.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import binding as _llvm
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

# Only when numba compiles for this very CPU (NUMBA_CPU_NAME=generic, for portable caches,
# would lack the instruction).
HAS_AVX2 = "+avx2" in _llvm.get_host_cpu_features().flatten() and numba.config.CPU_NAME in (None, "host")
# Query rows per tile: 48 x 2 KB rows (64x32 thumbnails) stay in a core's L2 cache.
_TILE = 48


@intrinsic
def _sad_bytes(typingctx, a, ia, b, ib, nblocks):
    """``sum |a.flat[ia + k] - b.flat[ib + k]|`` for ``k < 32 * nblocks`` (C-contiguous uint8)."""
    sig = types.int64(a, types.intp, b, types.intp, types.intp)

    def codegen(context, builder, signature, args):
        arr_a, off_a, arr_b, off_b, nb = args
        pa = builder.gep(context.make_array(signature.args[0])(context, builder, arr_a).data, [off_a])
        pb = builder.gep(context.make_array(signature.args[2])(context, builder, arr_b).data, [off_b])
        v8 = ir.VectorType(ir.IntType(8), 32)
        v64 = ir.VectorType(ir.IntType(64), 4)
        psad = cgutils.get_or_insert_function(builder.module, ir.FunctionType(v64, [v8, v8]), "llvm.x86.avx2.psad.bw")
        acc = cgutils.alloca_once_value(builder, ir.Constant(v64, None))
        with cgutils.for_range(builder, nb) as loop:
            off = builder.mul(loop.index, ir.Constant(loop.index.type, 32))
            va = builder.load(builder.bitcast(builder.gep(pa, [off]), v8.as_pointer()), align=1)
            vb = builder.load(builder.bitcast(builder.gep(pb, [off]), v8.as_pointer()), align=1)
            builder.store(builder.add(builder.load(acc), builder.call(psad, [va, vb])), acc)
        v = builder.load(acc)
        total = builder.extract_element(v, ir.Constant(ir.IntType(32), 0))
        for lane in range(1, 4):
            total = builder.add(total, builder.extract_element(v, ir.Constant(ir.IntType(32), lane)))
        return total

    return sig, codegen


@numba.njit(parallel=True, cache=True)
def _l1_uint8_avx2(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    n, d = a.shape
    m = b.shape[0]
    nb = d // 32
    for jb in numba.prange((m + _TILE - 1) // _TILE):
        j0 = jb * _TILE
        j1 = min(m, j0 + _TILE)
        for i in range(n):
            for j in range(j0, j1):
                s = _sad_bytes(a, i * d, b, j * d, nb)
                for k in range(nb * 32, d):
                    x = np.int32(a[i, k]) - np.int32(b[j, k])
                    s += x if x >= 0 else -x
                out[i, j] = s / d


@numba.njit(parallel=True, cache=True, fastmath=True)
def _l1_uint8_plain(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    n, d = a.shape
    m = b.shape[0]
    for i in numba.prange(n):
        ai = a[i]
        for j in range(m):
            bj = b[j]
            s = 0
            for k in range(d):
                x = np.int32(ai[k]) - np.int32(bj[k])
                s += x if x >= 0 else -x
            out[i, j] = s / d


def l1_uint8(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out[i, j] = mean_k |a[i, k] - b[j, k]|``; ``a``, ``b`` C-contiguous uint8."""
    (_l1_uint8_avx2 if HAS_AVX2 else _l1_uint8_plain)(a, b, out)


@numba.njit(parallel=True, cache=True, fastmath=True)
def l1_float(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    n, d = a.shape
    m = b.shape[0]
    for i in numba.prange(n):
        ai = a[i]
        for j in range(m):
            bj = b[j]
            s = np.float32(0.0)
            for k in range(d):
                s += abs(ai[k] - bj[k])
            out[i, j] = s / d
