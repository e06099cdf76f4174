"""Mean absolute difference kernels (numba, all cores) behind ``comparisons.mean_abs_difference``.

Kept in their own module so that importing the comparisons (as ``extract`` does) does not
import numba.
"""

from __future__ import annotations

import numba
import numpy as np


# Two kernels on purpose: the uint8 one accumulates in integers (exact, and the compiler
# vectorises the widened subtraction); the float one serves z-scored features.
@numba.njit(parallel=True, cache=True, fastmath=True)
def l1_uint8(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
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
