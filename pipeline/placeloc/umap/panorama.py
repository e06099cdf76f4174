"""Panoramas as whole queries: equirectangular line images of the map at every grid
position, the query panorama's line image, and scores over every yaw at once.

A 360 degree query with unknown heading is compared whole with the map's panoramic line
image at each grid position, the heading searched as a circular shift of columns (one
column = 360 / width degrees), instead of cutting pinhole views and keeping the best single
one (blank-wall views match sparse views anywhere).

The map's panoramic line images and the query's come from :mod:`placeloc.geometry.panorama`
(equirectangular convention there). The database is rendered at heading 0; a query taken
at heading ``psi`` is that image rolled by ``k = psi W / 360`` columns
(``query[:, u] = db[:, u - k]``).

Two scores, both over all (position, shift) pairs:

- ``iou``: eq. (1) of the UMap paper (intersection over union of line pixels, the database
  dilated by the tolerance), as for pinhole queries;
- ``chamfer``: a truncated distance-transform score that lets unseen map lines and clutter
  cost little: the mean of ``max(0, 1 - d / tau)`` over the map's line pixels (d = distance
  to the nearest query line pixel: how much of the map is seen) and over the query's line
  pixels (d = distance to the nearest map line: how much of what is seen is map), averaged.
  Optionally split by direction: vertical map lines (wall corners, door jambs) only count
  against vertical query lines and the rest against the rest.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numba import njit, prange

from placeloc.geometry.panorama import (  # noqa: F401  (re-exported: the map renderer and the query line image)
    panorama_line_image,
    render_panorama_block,
    render_panoramas,
)
from placeloc.umap.bits import _popcount64, pack

# ------------------------------------------------------------------ scores over every yaw

@njit(parallel=True, cache=True)
def _and_count_shifts(db: np.ndarray, q: np.ndarray, out: np.ndarray) -> None:
    for i in prange(db.shape[0]):
        for k in range(q.shape[0]):
            s = np.uint64(0)
            for j in range(q.shape[1]):
                s += _popcount64(db[i, j] & q[k, j])
            out[i, k] = s


def rolled_queries(query: np.ndarray) -> np.ndarray:
    """Packed copies of a (H, W) line image rolled by -k columns, k = 0..W-1: row k is the
    query seen as if taken at heading 0 when it was taken at heading k 360 / W."""
    w = query.shape[1]
    return pack(np.stack([np.roll(query, -k, axis=1) for k in range(w)]))


def iou_yaw_scores(db: np.ndarray, db_counts: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Eq. (1) (intersection over union) of every database panorama with the query at every
    column shift: (P, W) float64, entry (p, k) for the query taken at heading k 360 / W."""
    q = rolled_queries(query)
    lc = np.zeros((db.shape[0], q.shape[0]), dtype=np.int64)
    if db.shape[0]:
        _and_count_shifts(np.ascontiguousarray(db), q, lc)
    lc = lc.astype(np.float64)
    union = np.asarray(db_counts, np.float64)[:, None] + float(np.count_nonzero(query)) - lc
    return np.divide(lc, union, out=np.zeros_like(lc), where=union > 0)


def closeness(lines: np.ndarray, tau_px: float) -> np.ndarray:
    """``max(0, 1 - d / tau)`` with d the distance (pixels) to the nearest line pixel of a
    (..., H, W) binary image, wrapping around horizontally (a panorama has no left edge)."""
    lines = np.asarray(lines)
    lead = lines.shape[:-2]
    h, w = lines.shape[-2:]
    flat = lines.reshape(-1, h, w)
    pad = int(math.ceil(tau_px)) + 1
    out = np.zeros(flat.shape, np.float32)
    for i, img in enumerate(flat):
        wrapped = np.concatenate([img[:, -pad:], img, img[:, :pad]], axis=1)
        if not wrapped.any():
            continue
        d = cv2.distanceTransform((wrapped == 0).astype(np.uint8), cv2.DIST_L2, 5)[:, pad:pad + w]
        out[i] = np.maximum(0.0, 1.0 - d / tau_px)
    return out.reshape(*lead, h, w)


@njit(parallel=True, cache=True)
def _chamfer_shifts(db: np.ndarray, db_close: np.ndarray, q_close: np.ndarray, q_rows: np.ndarray, q_cols: np.ndarray,
                    width: int, out: np.ndarray) -> None:
    n_q = q_rows.shape[0]
    for i in prange(db.shape[0]):
        recall = np.zeros(width, dtype=np.float32)
        n_map = 0
        for j in range(db.shape[1]):
            word = db[i, j]
            if word == 0:
                continue
            for b in range(64):
                if (word >> np.uint64(b)) & np.uint64(1):
                    p = j * 64 + b
                    r = p // width
                    c = p % width
                    n_map += 1
                    # db column c is query column c + k (mod width): two runs without a modulo
                    for k in range(width - c):
                        recall[k] += q_close[r, c + k]
                    for k in range(width - c, width):
                        recall[k] += q_close[r, c + k - width]
        precision = np.zeros(width, dtype=np.float32)
        for m in range(n_q):
            r = q_rows[m]
            c = q_cols[m]
            # query column c is db column c - k (mod width)
            for k in range(c + 1):
                precision[k] += db_close[i, r, c - k]
            for k in range(c + 1, width):
                precision[k] += db_close[i, r, c - k + width]
        for k in range(width):
            rr = recall[k] / n_map if n_map > 0 else 0.0
            pp = precision[k] / n_q if n_q > 0 else 0.0
            out[i, k] = 0.5 * (rr + pp)


def chamfer_yaw_scores(db: np.ndarray, db_close: np.ndarray, query: np.ndarray, *, tau_px: float) -> np.ndarray:
    """The truncated chamfer score (module docstring) of every database panorama with the
    query at every column shift: (P, W) float64 in [0, 1]. ``db`` the undilated packed map
    line images, ``db_close`` their :func:`closeness` images (P, H, W)."""
    h, w = query.shape
    rows, cols = np.nonzero(query)
    out = np.zeros((db.shape[0], w))
    if db.shape[0]:
        _chamfer_shifts(np.ascontiguousarray(db), np.ascontiguousarray(db_close, np.float32),
                        closeness(query, tau_px).astype(np.float32), rows.astype(np.int64), cols.astype(np.int64), w, out)
    return out


def best_pose(scores: np.ndarray) -> tuple[int, int, float]:
    """(position row, column shift, score) of the best entry of a (P, W) score table."""
    i, k = np.unravel_index(int(np.argmax(scores)), scores.shape)
    return int(i), int(k), float(scores[i, k])



# ------------------------------------------------------------------ local refinement

def distinct_candidates(scores: np.ndarray, xy: np.ndarray, *, count: int, min_separation_m: float) -> np.ndarray:
    """Rows of the ``count`` best grid positions (each scored at its best yaw), greedily
    skipping any within ``min_separation_m`` of one already taken: the distinct places that
    compete (the same spot in two look-alike rooms, say)."""
    best = scores.max(axis=1)
    taken: list[int] = []
    for i in np.argsort(-best, kind="stable"):
        if all(np.hypot(*(xy[i] - xy[j])) >= min_separation_m for j in taken):
            taken.append(int(i))
            if len(taken) == count:
                break
    return np.asarray(taken, dtype=np.int64)


def local_grid(x: float, y: float, *, radius_m: float, step_m: float) -> np.ndarray:
    """Plan points of a square grid of spacing ``step_m`` within ``radius_m`` of (x, y) on
    each axis, (x, y) included."""
    n = int(np.floor(radius_m / step_m + 1e-9))
    d = np.arange(-n, n + 1) * step_m
    gx, gy = np.meshgrid(x + d, y + d, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=1)
