"""Binary line images packed 64 pixels to a uint64 word (row-major, bit b of word w is pixel
64 w + b): the storage both renderers write and the scorers read."""

from __future__ import annotations

import numpy as np
from numba import njit

# cell size of the pooled line images (8 x 8 pixels: a cell of 8 columns never straddles two
# 64-bit words), which bound the eq. (1) score of a view before it is read
POOL_PX = 8


def n_words(height: int, width: int) -> int:
    """Words per packed image of ``height`` x ``width`` pixels."""
    return (height * width + 63) // 64


@njit(cache=True, inline="always")
def pack_into(img: np.ndarray, n_pixels: int, out_row: np.ndarray) -> None:
    """Pack the first ``n_pixels`` of a flat 0/1 image into ``out_row`` (uint64 words)."""
    for w in range(out_row.shape[0]):
        word = np.uint64(0)
        base = w * 64
        for b in range(64):
            p = base + b
            if p < n_pixels and img[p]:
                word |= np.uint64(1) << np.uint64(b)
        out_row[w] = word
