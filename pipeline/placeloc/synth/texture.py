"""World-anchored procedural texture shared by the ray-cast generators (corridor, home)."""

from __future__ import annotations

import math

from numba import njit


@njit(inline="always")
def cell_hash(ix: int, iy: int, seed: int) -> float:
    """A hash of an integer cell and a seed, in [0, 1]."""
    h = (ix * 374761393 + iy * 668265263 + seed * 144665) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    return ((h ^ (h >> 16)) & 0xFFFF) / 65535.0


@njit(inline="always")
def value_noise(s: float, t: float, cell: float, seed: int) -> float:
    """Value noise in [0, 1], bilinear between hashed cell corners (world-anchored texture)."""
    a = s / cell
    b = t / cell
    i = int(math.floor(a))
    j = int(math.floor(b))
    fa = a - i
    fb = b - j
    v00 = cell_hash(i, j, seed)
    v10 = cell_hash(i + 1, j, seed)
    v01 = cell_hash(i, j + 1, seed)
    v11 = cell_hash(i + 1, j + 1, seed)
    return (v00 * (1 - fa) + v10 * fa) * (1 - fb) + (v01 * (1 - fa) + v11 * fa) * fb
