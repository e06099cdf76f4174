"""Plane polygon primitives shared by the floor-plan loader and the ZInD importer (a leaf:
neither of them needs to import the other for these)."""

from __future__ import annotations

import numpy as np


def point_in_polygon(xy: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule, vectorized over points."""
    x, y = xy[:, 0][:, None], xy[:, 1][:, None]
    a = poly
    b = np.roll(poly, -1, axis=0)
    cond = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (np.count_nonzero(cond & (x < xc), axis=1) % 2) == 1


def on_edge(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray, tol: float = 0.01) -> tuple[float, float] | None:
    """Parameters along a -> b (metres) of the two ends of p-q when both lie on that edge."""
    e = b - a
    length = float(np.hypot(*e))
    if length < 1e-9:
        return None
    out = []
    for r in (p, q):
        s = float((r - a) @ e) / length
        off = abs(float(e[0] * (r - a)[1] - e[1] * (r - a)[0])) / length
        if off > tol or s < -tol or s > length + tol:
            return None
        out.append(min(max(s, 0.0), length))
    return min(out), max(out)
