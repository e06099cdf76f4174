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
from collections.abc import Callable, Iterable
from typing import Any

import cv2
import numpy as np
from numba import njit, prange
from threadpoolctl import threadpool_limits

from placeloc.geometry.floorplan import blocking_faces, wall_distance
from placeloc.geometry.panorama import (  # noqa: F401  (re-exported: the map renderer and the query line image)
    panorama_line_image,
    render_panorama_block,
    render_panoramas,
)
from placeloc.umap.bits import _popcount64, pack, popcount_rows, unpack

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


# ------------------------------------------------------------------ the chamfer score as spectra

def row_weights(height: int, *, polar_deg: float, polar_weight: float) -> np.ndarray:
    """(H,) float32 weight of each equirectangular row in the scores: ``polar_weight`` for
    rows more than ``polar_deg`` above or below the horizon (the floor right under the
    camera, where sunlight stripes, rugs and the tripod's base lie, and a ceiling fan or
    lamp right above it), 1 elsewhere."""
    el = 90.0 - 180.0 * (np.arange(height) + 0.5) / height
    return np.where(np.abs(el) > polar_deg, polar_weight, 1.0).astype(np.float32)


def chamfer_spectra(lines: np.ndarray, *, tau_px: float, weights: np.ndarray) -> np.ndarray:
    """The map side of the chamfer score (module docstring) of (P, H, W) binary panoramic
    line images, in the form :func:`chamfer_table` multiplies: (F, P, 2H) complex64, F =
    W // 2 + 1, the conjugate row spectra of the weighted line image over its weighted
    pixel count (recall) and of the weighted closeness image (precision).

    Why spectra: the score at column shift k is a circular cross-correlation of rows,
    summed over rows, so every shift of every position comes from one complex product per
    frequency, summed over rows: one matrix product per frequency for a batch of queries,
    instead of one pass over the pixels per shift. Exact up to float32 rounding."""
    lines = np.asarray(lines).reshape(-1, *lines.shape[-2:])
    w = np.asarray(weights, np.float32)[None, :, None]
    out = np.empty((lines.shape[-1] // 2 + 1, len(lines), 2 * lines.shape[-2]), np.complex64)
    for s in range(0, len(lines), 512):  # blocks keep the float temporaries small
        img = lines[s:s + 512].astype(np.float32) * w
        n = np.maximum(img.sum(axis=(1, 2)), 1e-9)[:, None, None]
        x = np.concatenate([img / n, closeness(lines[s:s + 512], tau_px) * w], axis=1)
        out[:, s:s + 512] = np.conj(np.fft.rfft(x, axis=-1)).transpose(2, 0, 1)
    return out


def chamfer_table(spectra: np.ndarray, queries: np.ndarray, *, tau_px: float, weights: np.ndarray) -> np.ndarray:
    """Chamfer scores (module docstring, rows weighted by ``weights``) of a batch of (N, H, W)
    query line images against every map panorama of ``spectra`` (:func:`chamfer_spectra`) at
    every column shift: (N, P, W) float32, entry (n, p, k) for query n taken at heading
    k 360 / W at position p. Equal to :func:`chamfer_yaw_scores` with unit weights."""
    queries = np.asarray(queries).reshape(-1, *queries.shape[-2:])
    n_q, h, w = queries.shape
    wr = np.asarray(weights, np.float32)[None, :, None]
    q = queries.astype(np.float32)
    nq = np.maximum((q * wr).sum(axis=(1, 2)), 1e-9)[:, None, None]
    x = np.concatenate([closeness(queries, tau_px), q / nq], axis=1)          # (N, 2H, W)
    qs = np.ascontiguousarray(np.fft.rfft(x, axis=-1).astype(np.complex64).transpose(2, 1, 0))  # (F, 2H, N)
    prod = np.matmul(spectra, qs)                                             # (F, P, N)
    return (0.5 * np.fft.irfft(prod.transpose(2, 1, 0), n=w, axis=-1)).astype(np.float32)


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


# the 8 neighbours of a point on a unit square grid
NEIGHBOURS = np.array([[dx, dy] for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy], float)


def refine_steps(radius_m: float, step_m: float) -> list[float]:
    """The steps of a coarse-to-fine local search that ends at ``step_m`` and reaches about
    ``radius_m`` (halving from the largest power-of-two multiple of ``step_m`` within it):
    0.15 m / 0.05 m gives 0.1, 0.05 (8 + 8 renders instead of a 7 x 7 grid's 48)."""
    out = [float(step_m)]
    while sum(out) + 2 * out[0] <= radius_m + 1e-9:
        out.insert(0, 2 * out[0])
    return out


def dilate_lines(imgs: np.ndarray, tolerance_px: int) -> np.ndarray:
    """(N, H, W) binary line images thickened by ``tolerance_px`` (elliptic kernel, as the
    index stage dilates the IoU database)."""
    if tolerance_px <= 0:
        return np.asarray(imgs)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * tolerance_px + 1,) * 2)
    return np.stack([cv2.dilate(np.ascontiguousarray(im), k) for im in imgs])


def local_grid(x: float, y: float, *, radius_m: float, step_m: float) -> np.ndarray:
    """Plan points of a square grid of spacing ``step_m`` within ``radius_m`` of (x, y) on
    each axis, (x, y) included."""
    n = int(np.floor(radius_m / step_m + 1e-9))
    d = np.arange(-n, n + 1) * step_m
    gx, gy = np.meshgrid(x + d, y + d, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


# ------------------------------------------------------------------ the search

# queries scored together: one matrix product per frequency serves the whole batch
PANORAMA_BATCH = 16


def search_panoramas(lines: np.ndarray, poses: np.ndarray, segments: np.ndarray, faces: np.ndarray,
                     database: dict[str, np.ndarray], pp: Any, *, tolerance_px: int, wall_margin_m: float, hidden: bool,
                     progress: Callable[[Iterable], Iterable] = lambda it: it
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Best (grid row, plan position, heading in degrees, score) of each (N, H, W) query line
    image: every grid position and yaw scored (``database``: ``spectra`` for the chamfer
    score, :func:`chamfer_spectra`; ``bits`` and ``counts`` for eq. (1)); then, with
    ``pp.refine_candidates``, the best distinct grid positions are refined coarse to fine
    (:func:`refine_steps`: the 8 neighbours at each step, rendered on the spot and scored the
    same way) and the best refined pose is kept. ``pp``: the ``umap.panorama`` parameters."""
    n, h, w = lines.shape
    best, heading, score = np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros(n)
    weights = row_weights(h, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight)
    chamfer = pp.score == "chamfer"

    def tables(ks: np.ndarray) -> np.ndarray:
        if chamfer:
            return chamfer_table(database["spectra"], lines[ks], tau_px=pp.chamfer_tau_px, weights=weights)
        return np.stack([iou_yaw_scores(database["bits"], database["counts"], lines[k]) for k in ks])

    def local_tables(k: int, pts: np.ndarray, z: float) -> np.ndarray:
        """(L, W) scores of query k at plan points pts (rendered on the spot), every shift."""
        local = np.column_stack([pts, np.full(len(pts), z), np.zeros(len(pts))])
        imgs = unpack(render_panoramas(segments, faces, local, width=w, height=h, hidden=hidden), h, w)
        if chamfer:
            sp = chamfer_spectra(imgs, tau_px=pp.chamfer_tau_px, weights=weights)
            return chamfer_table(sp, lines[k:k + 1], tau_px=pp.chamfer_tau_px, weights=weights)[0]
        dil = pack(dilate_lines(imgs, tolerance_px))
        return iou_yaw_scores(dil, popcount_rows(dil), lines[k])

    walls = blocking_faces(faces, float(poses[0, 2])) if len(poses) else faces
    steps = refine_steps(pp.refine_radius_m, pp.refine_step_m)
    refined_xy = np.full((n, 2), np.nan)

    def scored() -> Iterable:
        for s in range(0, n, PANORAMA_BATCH):
            ks = np.arange(s, min(n, s + PANORAMA_BATCH))
            yield from zip(ks, tables(ks))

    # one BLAS thread: the products are many and small, and waiting BLAS threads spin (on two
    # shared cores they cost 3-5x the CPU time of the search; bench-umap)
    limiter = threadpool_limits(limits=1, user_api="blas")
    try:
        for k, table in progress(scored()):
            best[k], shift, score[k] = best_pose(table)
            heading[k] = shift * 360.0 / w
            cands = distinct_candidates(table, poses[:, :2], count=pp.refine_candidates,
                                        min_separation_m=pp.refine_separation_m) if pp.refine_candidates > 0 else []
            if not len(cands):
                continue
            # every candidate's current best (position, yaw, score); one render call per step for all of them
            xy = poses[cands, :2].copy()
            yaw = np.argmax(table[cands], axis=1) * 360.0 / w
            sc = table[cands].max(axis=1)
            floor_d = (np.minimum(wall_margin_m, wall_distance(xy, walls)) if len(walls) else np.zeros(len(cands)))
            for step in steps:  # coarse to fine: the 8 neighbours at each step around each candidate's best so far
                pts = (xy[:, None, :] + step * NEIGHBOURS[None]).reshape(-1, 2)
                owner = np.repeat(np.arange(len(cands)), len(NEIGHBOURS))
                if len(walls):  # not through a wall: as far from the walls as the grid keeps its positions
                    ok = wall_distance(pts, walls) >= floor_d[owner]
                    pts, owner = pts[ok], owner[ok]
                if not len(pts):
                    continue
                sub = local_tables(int(k), pts, float(poses[cands[0], 2]))
                top, arg = sub.max(axis=1), sub.argmax(axis=1)
                for j in range(len(cands)):
                    mine = np.flatnonzero(owner == j)
                    if len(mine) and top[mine].max() > sc[j]:
                        i = mine[int(np.argmax(top[mine]))]
                        xy[j], yaw[j], sc[j] = pts[i], arg[i] * 360.0 / w, top[i]
            j = int(np.argmax(sc))
            if sc[j] > score[k]:
                # the grid row stays that of the candidate; the position is the refined one
                best[k], heading[k], score[k] = cands[j], yaw[j], sc[j]
                refined_xy[k] = xy[j]
    finally:
        limiter.restore_original_limits()
    est = poses[best, :2].copy()
    ok = ~np.isnan(refined_xy[:, 0])
    est[ok] = refined_xy[ok]
    return best, est, heading, score
