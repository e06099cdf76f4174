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
  With ``orientation_bins`` B > 1 (directional chamfer matching): every line pixel also
  carries the bin of its direction in the image, and a pixel counts as near only to the
  other side's lines of the same bin or within ``orientation_spread`` bins of it
  (:func:`compatible_lines`); B = 1 is the score above.
"""

from __future__ import annotations

import functools
import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from typing import Any, NamedTuple

import cv2
import numpy as np
from numba import njit, prange
from threadpoolctl import threadpool_limits

from placeloc.core.executor import usable_cores
from placeloc.geometry.floorplan import blocking_faces, wall_distance
from placeloc.geometry.panorama import (  # noqa: F401  (re-exported: the map renderer and the query line image)
    COVERAGE_MARGIN_DEG,
    panorama_line_image,
    render_panorama_block,
    render_panoramas,
)
from placeloc.umap.bits import _popcount64, pack, popcount_rows, unpack
from placeloc.umap.resources import SPECTRA_BLOCK

# ------------------------------------------------------------------ scores over every yaw

@njit(parallel=True, cache=True, nogil=True)
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


def closeness_kernel(tau_px: float) -> np.ndarray:
    """(2r + 1, 2r + 1) float32, r = ceil(tau): ``max(0, 1 - d / tau)`` around a lone line
    pixel, d OpenCV's 5 x 5 chamfer distance (``cv2.distanceTransform``, ``DIST_L2``, mask
    5), taken from that function itself so that :func:`closeness` equals it bit for bit."""
    r = int(math.ceil(tau_px))
    n = 2 * r + 5                      # room around the stamp: the chamfer paths stay inside it
    img = np.ones((n, n), np.uint8)
    img[n // 2, n // 2] = 0
    d = cv2.distanceTransform(img, cv2.DIST_L2, 5)[n // 2 - r:n // 2 + r + 1, n // 2 - r:n // 2 + r + 1]
    return np.maximum(0.0, 1.0 - d / tau_px).astype(np.float32)


@njit(cache=True, inline="always")
def _fold_seam(wide: np.ndarray, out: np.ndarray, r: int) -> None:
    """``out`` (H, W) <- ``wide`` (H, W + 2 r), whose ``r`` columns either side hold what
    was stamped past the panorama's edges: folded back around the seam, keeping the larger."""
    h, w = out.shape
    for y in range(h):
        for x in range(w):
            out[y, x] = wide[y, x + r]
        for c in range(r):
            x = (c - r) % w                     # wide column c is x = c - r
            if wide[y, c] > out[y, x]:
                out[y, x] = wide[y, c]
            x = c % w                           # wide column w + r + c is x = w + c
            if wide[y, w + r + c] > out[y, x]:
                out[y, x] = wide[y, w + r + c]


@njit(parallel=True, cache=True, nogil=True)
def _stamp_closeness(lines: np.ndarray, dy: np.ndarray, dx: np.ndarray, value: np.ndarray, r: int, out: np.ndarray) -> None:
    h, w = lines.shape[1], lines.shape[2]
    for i in prange(lines.shape[0]):
        wide = np.zeros((h, w + 2 * r), np.float32)   # r columns either side, folded back below
        for y in range(h):
            for x in range(w):
                if lines[i, y, x] == 0:
                    continue
                weight = np.float32(lines[i, y, x])
                for j in range(value.shape[0]):
                    yy = y + dy[j]
                    if 0 <= yy < h:
                        xx = x + r + dx[j]
                        v = value[j] * weight
                        if v > wide[yy, xx]:
                            wide[yy, xx] = v
        _fold_seam(wide, out[i], r)


def closeness(lines: np.ndarray, tau_px: float) -> np.ndarray:
    """``max(0, 1 - d / tau)`` (float32) with d the distance (pixels) to the nearest line
    pixel of a (..., H, W) binary image, wrapping around horizontally (a panorama has no
    left edge); d is OpenCV's 5 x 5 chamfer distance transform. A float32 image is a
    weighted line image (:func:`texture_weights`): the largest ``weight max(0, 1 - d / tau)``
    over its line pixels, the same for weights 0 and 1.

    Why stamped, not transformed: a chamfer distance transform gives each pixel the least
    chamfer distance to any line pixel, and only line pixels within tau count, so the
    closeness is the largest :func:`closeness_kernel` value stamped around each line pixel
    (equal to the transform bit for bit: tested); a line image is mostly empty, so this
    touches the kernel's nonzero pixels (25 at tau 3) around each line pixel instead of
    the whole image twice, without stacking padded copies (1.4x cheaper on map panoramas,
    where the local search spends it)."""
    lines = np.asarray(lines)
    lead = lines.shape[:-2]
    h, w = lines.shape[-2:]
    flat = np.ascontiguousarray(lines.reshape(-1, h, w))
    if flat.dtype == np.float64:
        flat = flat.astype(np.float32)
    elif flat.dtype not in (np.uint8, np.float32):
        flat = (flat != 0).astype(np.uint8)
    out = np.zeros(flat.shape, np.float32)
    if flat.size:
        kernel = closeness_kernel(tau_px)
        r = kernel.shape[0] // 2
        dy, dx = np.nonzero(kernel > 0)
        _stamp_closeness(flat, (dy - r).astype(np.int64), (dx - r).astype(np.int64), kernel[dy, dx], r, out)
    return out.reshape(*lead, h, w)


# line pixels a texture patch is worth: two lines across the square (a corner of the map:
# two lines meet there, and a rasterised line is thicker than one pixel where it is oblique)
TEXTURE_LINES = 2.0


def texture_weights(lines: np.ndarray, radius_px: int) -> np.ndarray:
    """(..., H, W) float32 weight of each line pixel of binary panoramic line images: two
    lines' worth of pixels in the (2r + 1)-pixel square around it (2r + 1 a line crossing
    the square: :data:`TEXTURE_LINES`) over the line pixels there, at most 1; 0 off the
    lines. ``radius_px`` 0: every line pixel weighs 1.

    Why: the map draws walls, floor and ceiling edges, door and window frames, each an
    isolated curve; what is dense in a query's line image is mostly texture the map lacks:
    blinds, sunlight striped by them on the floor, tiles, planks, radiator fins, all a few
    degrees apart or less, so that at 2.5 degrees a pixel they fill whole patches.
    Weighted, such a patch counts about as much as two lines through it, so a pose does not
    win by laying its map lines across the stripes; isolated lines and corners keep their
    full weight. What it also weighs down: a distant wall's frames and corners, which the
    map draws dense too (why it is off by default: docs/umap.md)."""
    lines = np.asarray(lines)
    binary = (lines != 0).astype(np.float32)
    if radius_px <= 0:
        return binary
    r = int(radius_px)
    h, w = lines.shape[-2:]
    flat = binary.reshape(-1, h, w)
    out = np.zeros_like(flat)
    for i, img in enumerate(flat):
        # the square's sum, wrapping around the seam (a panorama has no left edge), zero
        # beyond the poles
        padded = np.pad(img, ((r, r), (0, 0)))
        padded = np.concatenate([padded[:, w - r:], padded, padded[:, :r]], axis=1)
        count = cv2.boxFilter(padded, -1, (2 * r + 1, 2 * r + 1), normalize=False,
                              borderType=cv2.BORDER_CONSTANT)[r:r + h, r:r + w]
        out[i] = img * np.minimum(1.0, TEXTURE_LINES * (2 * r + 1) / np.maximum(count, 1.0))
    return out.reshape(lines.shape).astype(np.float32)


@njit(parallel=True, cache=True, nogil=True)
def _chamfer_shifts(db: np.ndarray, db_close: np.ndarray, q_close: np.ndarray, q_rows: np.ndarray, q_cols: np.ndarray,
                    q_vals: np.ndarray, width: int, out: np.ndarray) -> None:
    n_q = 0.0
    for m in range(q_rows.shape[0]):
        n_q += q_vals[m]
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
        for m in range(q_rows.shape[0]):
            r = q_rows[m]
            c = q_cols[m]
            v = q_vals[m]
            # query column c is db column c - k (mod width)
            for k in range(c + 1):
                precision[k] += v * db_close[i, r, c - k]
            for k in range(c + 1, width):
                precision[k] += v * db_close[i, r, c - k + width]
        for k in range(width):
            out[i, 0, k] = recall[k] / n_map if n_map > 0 else 0.0
            out[i, 1, k] = precision[k] / n_q if n_q > 0 else 0.0


# how far the chance level may approach 1 (a closeness image covering everything): the
# chance-corrected halves stay finite
CHANCE_FLOOR = 1e-3


def chance_corrected(value: np.ndarray, chance: np.ndarray) -> np.ndarray:
    """``(value - chance) / (1 - chance)``: 0 for what a line image placed with no regard to
    the other earns, 1 for a perfect match (Cohen's kappa form)."""
    return (value - chance) / np.maximum(1.0 - chance, CHANCE_FLOOR)


CHANCES = ("none", "area", "yaw", "likelihood")


def likelihood_image(close: np.ndarray, weights: np.ndarray, clutter_share: float) -> np.ndarray:
    """``log(s + (1 - s) g / A)`` (float32, same shape) of (..., H, W) closeness images g
    (:func:`closeness`), A each image's mean closeness with rows weighted by ``weights``
    (H,), s = ``clutter_share``: the log likelihood ratio, for a line pixel of the *other*
    image at each pixel, of "drawn by this image's lines or clutter" against "clutter".

    Why (the ``likelihood`` chance of the chamfer score): a detected pixel is clutter with
    probability s, spread evenly over the (row-weighted) sphere, density 1 / Omega, or one
    of this image's lines, drawn near them with density g / (A Omega) (its closeness,
    normalised to integrate to 1). Its likelihood ratio against clutter alone is
    s + (1 - s) g / A: a view drawing much map (A large) spreads its density thin, so clutter
    that lands near one of its many lines gains it little, while a sparse view's few lines,
    where the pixels are, gain it much. An image with no lines (A = 0) explains nothing:
    log s everywhere."""
    close = np.asarray(close, np.float32)
    h, w = close.shape[-2:]
    wr = np.asarray(weights, np.float64).reshape(h, 1)
    area = (close.astype(np.float64) * wr).sum(axis=(-2, -1)) / (w * max(float(wr.sum()), 1e-12))
    area = np.asarray(area)[..., None, None]
    ratio = np.divide(close, area, out=np.zeros(close.shape, np.float64), where=area > 0)
    return np.log(clutter_share + (1.0 - clutter_share) * ratio).astype(np.float32)


def _query_pixels(query: np.ndarray, precision_rows: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows, columns and precision-half weights of a query's line pixels: a float query's
    own weights (:func:`texture_weights`), else 1, times ``precision_rows`` of their row."""
    rows, cols = np.nonzero(query)
    vals = np.asarray(query, np.float64)[rows, cols] if query.dtype.kind == "f" else np.ones(len(rows))
    if precision_rows is not None:
        vals = vals * np.asarray(precision_rows, np.float64)[rows]
    return rows, cols, vals


def chamfer_yaw_scores(db: np.ndarray, db_close: np.ndarray, query: np.ndarray, *, tau_px: float, chance: str,
                       precision_rows: np.ndarray | None = None, clutter_share: float = 0.5,
                       recall_weight: float = 0.5) -> np.ndarray:
    """The truncated chamfer score (module docstring) of every database panorama with the
    query at every column shift, pixel by pixel (the reference :func:`chamfer_table` is
    tested against): (P, W) float64. ``db`` the undilated packed map line images,
    ``db_close`` their :func:`closeness` images (P, H, W); ``chance``: ``none`` (the plain
    halves, in [0, 1]), ``area`` (each half corrected for the share of the image the other
    side's closeness covers) or ``yaw`` (corrected for the half's mean over all shifts).
    A float ``query`` is a weighted line image (:func:`texture_weights`): each line pixel
    counts with its weight in the precision half and stamps its closeness scaled by it.
    ``precision_rows`` (H,): each row's query pixels count in the precision half times
    this (:func:`precision_rows`; the recall half keeps them all). ``likelihood``: each half
    the mean log likelihood ratio of its side's line pixels (:func:`likelihood_image` of the
    other side's closeness, unit row weights, ``clutter_share``). The score is
    ``recall_weight`` times the recall half plus the rest times the precision half
    (:func:`halves_mixed`; 0.5: their mean)."""
    h, w = query.shape
    rows, cols, vals = _query_pixels(query, precision_rows)
    halves = np.zeros((db.shape[0], 2, w))
    q_close = closeness(query, tau_px).astype(np.float32)
    if chance == "likelihood":
        ones = np.ones(h, np.float32)
        q_close = likelihood_image(q_close, ones, clutter_share)
        db_close = likelihood_image(db_close, ones, clutter_share)
    if db.shape[0]:
        _chamfer_shifts(np.ascontiguousarray(db), np.ascontiguousarray(db_close, np.float32),
                        q_close, rows.astype(np.int64), cols.astype(np.int64), vals, w, halves)
    recall, precision = halves[:, 0], halves[:, 1]
    if chance == "area":
        # a query pixel anywhere: the map's closeness averaged over the image; a map pixel
        # anywhere: the query's
        recall = chance_corrected(recall, np.full((len(db), 1), float(q_close.mean())))
        precision = chance_corrected(precision, np.asarray(db_close, np.float64).reshape(len(db), -1).mean(axis=1)[:, None])
    elif chance == "yaw":
        recall = chance_corrected(recall, recall.mean(axis=1, keepdims=True))
        precision = chance_corrected(precision, precision.mean(axis=1, keepdims=True))
    elif chance not in ("none", "likelihood"):
        raise ValueError(f"chance must be one of {', '.join(CHANCES)}, not {chance!r}")
    return halves_mixed(recall, precision, recall_weight)


def halves_mixed(recall: Any, precision: Any, recall_weight: float) -> Any:
    """The chamfer score from its two halves: ``recall_weight`` times the recall half (the
    map's drawn lines near the photo's) plus ``1 - recall_weight`` times the precision half
    (the photo's lines near the map's); 0.5, their mean. Every score of the search (the
    tables, the local search, the rival) mixes them so.

    Why a weight: a sparse view earns the recall half easily (few drawn lines, each near
    something), a busy one the precision half (many drawn lines for clutter to fall near),
    so the mean is one choice among many. Another weight was measured and not taken: 0.4
    placed more photos on development homes and fewer on test homes (docs/umap.md, "The
    halves' weights"; ``placeloc experiment umap-halves``)."""
    return recall_weight * recall + (1.0 - recall_weight) * precision


# ------------------------------------------------------------------ directions: the oriented (directional) score

def orientation_channels(masks: np.ndarray, bins: int) -> np.ndarray:
    """(..., H, W) orientation bitmask images (``render_panoramas`` / ``panorama_line_image``
    with ``orientation_bins``) -> (..., B, H, W) uint8 0/1 channels, channel b the pixels a
    line of direction bin b passes through (:func:`placeloc.geometry.panorama.orientation_bit`)."""
    masks = np.asarray(masks, np.uint8)
    shifts = np.arange(int(bins), dtype=np.uint8).reshape(-1, 1, 1)
    return ((masks[..., None, :, :] >> shifts) & 1).astype(np.uint8)


def compatible_lines(channels: np.ndarray, spread: int) -> np.ndarray:
    """(..., B, H, W) oriented line channels -> (..., B, H, W): channel b the lines a pixel of
    direction bin b counts as near, those of bins b - spread .. b + spread (directions wrap
    at 180 degrees: bin B - 1 neighbours bin 0); the largest weight where channels are
    weights (:func:`texture_weights`). Every bin when 2 spread + 1 >= B."""
    channels = np.asarray(channels)
    b = channels.shape[-3]
    if 2 * int(spread) + 1 >= b:
        return np.broadcast_to(channels.max(axis=-3, keepdims=True), channels.shape).copy()
    out = channels.copy()
    for d in range(1, int(spread) + 1):
        out = np.maximum(out, np.maximum(np.roll(channels, d, axis=-3), np.roll(channels, -d, axis=-3)))
    return out


@njit(cache=True, inline="always")
def _stamp_pixel(wide: np.ndarray, cm: int, y: int, x: int, dy: np.ndarray, dx: np.ndarray, value: np.ndarray,
                 r: int) -> None:
    """One line pixel at (y, x) stamps its closeness ``value`` (or its rank) at offsets (``dy``, ``dx``)
    into every channel of ``wide`` (B, H, W + 2 r; ``r`` columns either side) that its
    compatible bins ``cm`` name, keeping the larger."""
    h = wide.shape[1]
    for c in range(wide.shape[0]):
        if not (cm >> c) & 1:
            continue
        for j in range(value.shape[0]):
            yy = y + dy[j]
            if 0 <= yy < h:
                xx = x + r + dx[j]
                if value[j] > wide[c, yy, xx]:
                    wide[c, yy, xx] = value[j]


@njit(parallel=True, cache=True, nogil=True)
def _stamp_oriented(masks: np.ndarray, compat: np.ndarray, dy: np.ndarray, dx: np.ndarray, value: np.ndarray, r: int,
                    out: np.ndarray) -> None:
    """:func:`_stamp_closeness` for orientation bitmask images: each line pixel stamps its
    closeness into every channel its bins are compatible with (``compat[mask]``)."""
    b, h, w = out.shape[1], out.shape[2], out.shape[3]
    for i in prange(masks.shape[0]):
        wide = np.zeros((b, h, w + 2 * r), np.float32)   # r columns either side, folded back below
        for y in range(h):
            for x in range(w):
                m = masks[i, y, x]
                if m == 0:
                    continue
                _stamp_pixel(wide, compat[m], y, x, dy, dx, value, r)
        for c in range(b):
            _fold_seam(wide[c], out[i, c], r)


@njit(parallel=True, cache=True, nogil=True)
def _oriented_shifts(masks: np.ndarray, near: np.ndarray, offset: np.ndarray, rank: np.ndarray, levels: np.ndarray,
                     r: int, bins: int, q_close: np.ndarray, q_rows: np.ndarray, q_cols: np.ndarray, q_vals: np.ndarray,
                     weights: np.ndarray, shifts: np.ndarray, out: np.ndarray) -> None:
    """The oriented halves at the given shifts (out (L, S, 2)) of orientation bitmask map
    images against a query's stacked channels (rows b H + y), each map's closeness stamped
    into a buffer of its own thread, never stored whole.

    Each map line element stamps its closeness into its *own* bin's channel only; a query
    element of bin c reads the largest of the channels ``near[c]`` (the bins compatible with
    c). Why: the compatible closeness is a largest value over pixels and bins, so it is the
    same number either way (a maximum is exact), and stamping 2 s + 1 channels a pixel
    cost more than the few reads at the query's elements and shifts. What is stamped is
    each kernel value's ``rank`` among the kernel's distinct values (1 the least; 0 none),
    ``levels[rank]`` the value: ranks order as the values do, so the largest rank names the
    largest value. Each channel of the buffer has ``r`` rows and columns of margin on every
    side (stamps past the poles land in the margin rows and are never read; past the seam,
    folded back), so a stamp is ``offset`` (flat offsets of the kernel's pixels) from the
    pixel's own index, with no bounds to test."""
    h, w = masks.shape[1], masks.shape[2]
    n_s = shifts.shape[1]
    n_near = near.shape[1]
    n_k = offset.shape[0]
    stride = w + 2 * r                              # a buffer row
    plane = (h + 2 * r) * stride                    # a buffer channel
    nq = 0.0
    for m in range(q_rows.shape[0]):
        nq += weights[q_rows[m] % h] * q_vals[m]
    for i in prange(masks.shape[0]):
        own = np.zeros(bins * plane, rank.dtype)
        rec = np.zeros(n_s)
        n_map = 0.0
        for y in range(h):
            wr = weights[y]
            for x in range(w):
                mk = masks[i, y, x]
                if mk == 0:
                    continue
                for c in range(bins):
                    if (mk >> c) & 1:           # a map line element of bin c
                        at = c * plane + (y + r) * stride + x + r
                        for j in range(n_k):
                            o = at + offset[j]
                            own[o] = max(own[o], rank[j])
                        n_map += wr             # the recall half
                        for s in range(n_s):
                            cc = x + shifts[i, s]   # db column x is query column x + k
                            rec[s] += wr * q_close[c * h + y, cc - w if cc >= w else cc]
        for c in range(bins):                   # stamped past the edges: fold back around the seam
            for y in range(h):
                row = c * plane + (y + r) * stride
                for k in range(r):
                    if own[row + w + r + k] > own[row + r + k]:
                        own[row + r + k] = own[row + w + r + k]
                    if own[row + k] > own[row + w + k]:
                        own[row + w + k] = own[row + k]
        pre = np.zeros(n_s)
        for m in range(q_rows.shape[0]):
            c = q_rows[m] // h
            y = q_rows[m] - c * h
            v = weights[y] * q_vals[m]
            row = (y + r) * stride + r
            for s in range(n_s):
                cc = q_cols[m] - shifts[i, s]      # query column x is db column x - k
                at = row + (cc + w if cc < 0 else cc)
                best = own[near[c, 0] * plane + at]
                for j in range(1, n_near):
                    got = own[near[c, j] * plane + at]
                    if got > best:
                        best = got
                pre[s] += v * levels[best]
        for s in range(n_s):
            out[i, s, 0] = rec[s] / n_map if n_map > 0 else 0.0
            out[i, s, 1] = pre[s] / nq if nq > 0 else 0.0


def channel_masks(channels: np.ndarray) -> np.ndarray:
    """(..., B, H, W) oriented channels -> (..., H, W) uint8 bitmasks (the inverse of
    :func:`orientation_channels`)."""
    channels = np.asarray(channels)
    masks = np.zeros((*channels.shape[:-3], *channels.shape[-2:]), np.uint8)
    for c in range(channels.shape[-3]):
        masks |= (channels[..., c, :, :] != 0).astype(np.uint8) << np.uint8(c)
    return masks


def oriented_at_shifts(masks: np.ndarray, query: np.ndarray, shifts: np.ndarray, *, tau_px: float, weights: np.ndarray,
                       spread: int, query_close: np.ndarray | None = None,
                       precision_rows: np.ndarray | None = None, recall_weight: float = 0.5,
                       query_pixels: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The oriented chamfer score (:func:`chamfer_table` with ``spread``) of one query's
    (B, H, W) oriented channels (0/1 or weights) against (L, H, W) orientation bitmask map
    images (as :func:`render_panoramas` draws them), each at its own column shifts (L, S):
    (L, S) float64. Each map's compatible closeness is stamped and read in one pass
    (:func:`_oriented_shifts`), so the local search never stores L x B closeness images.
    ``query_pixels``: :func:`oriented_query_pixels` of the query and ``precision_rows``, where
    the caller keeps them (the local search scores one query a few hundred times)."""
    query = np.asarray(query)
    b, h, w = query.shape
    if query_close is None:
        query_close = stack_channels(oriented_closeness(query, tau_px, spread))
    rows, cols, vals = oriented_query_pixels(query, precision_rows) if query_pixels is None else query_pixels
    shifts = np.ascontiguousarray(np.asarray(shifts, np.int64) % w)
    masks = np.ascontiguousarray(np.asarray(masks, np.uint8).reshape(-1, h, w))
    halves = np.zeros((len(masks), shifts.shape[1], 2))
    if len(masks):
        offset, rank, levels, r = _rank_stamp(float(tau_px), w)
        _oriented_shifts(masks, compatible_bins(b, min(int(spread), b)), offset, rank, levels, r, b,
                         np.ascontiguousarray(query_close, np.float32), rows, cols, vals,
                         np.asarray(weights, np.float64), shifts, halves)
    return halves_mixed(halves[..., 0], halves[..., 1], recall_weight)


def oriented_query_pixels(query: np.ndarray, precision_rows: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows (of the stacked channels, b H + y), columns and precision-half weights of a
    (B, H, W) oriented query's line elements, as :func:`oriented_at_shifts` reads them."""
    b = query.shape[0]
    rows, cols, vals = _query_pixels(stack_channels(query), None if precision_rows is None else np.tile(precision_rows, b))
    return rows.astype(np.int64), cols.astype(np.int64), vals


@functools.lru_cache(maxsize=16)
def _rank_stamp(tau_px: float, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The closeness kernel's stamp as :func:`_oriented_shifts` takes it: the flat offsets of
    its pixels in a buffer row of ``w`` + 2 r, each pixel's rank among the kernel's distinct
    values (1 the least), the values by rank (0 first: none) and r. Kept: it depends on the
    kernel and the width alone, and the local search asks for it a few hundred times a
    query. Callers must not write into the arrays."""
    kernel = closeness_kernel(tau_px)
    r = kernel.shape[0] // 2
    dy, dx = np.nonzero(kernel > 0)
    levels, rank = np.unique(kernel[dy, dx], return_inverse=True)
    rank_type = np.uint8 if len(levels) < 2**8 else np.uint16 if len(levels) < 2**16 else np.uint32
    offset = (dy - r) * (w + 2 * r) + (dx - r)          # flat, in a buffer row of w + 2 r
    return (offset.astype(np.int64), (rank.ravel() + 1).astype(rank_type),
            np.concatenate([[0.0], levels]).astype(np.float32), int(r))


@functools.lru_cache(maxsize=64)
def compatible_bins(bins: int, spread: int) -> np.ndarray:
    """(B, K) int64: row b the K = min(2 s + 1, B) bins compatible with bin b (those within
    ``spread`` bins of it, wrapping at 180 degrees), ascending; read-only (kept for the next
    call)."""
    table = compatible_masks(bins, spread)
    out = np.array([[c for c in range(int(bins)) if (table[1 << b] >> c) & 1] for b in range(int(bins))], np.int64)
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=64)
def compatible_masks(bins: int, spread: int) -> np.ndarray:
    """(256,) uint8: for each orientation bitmask, the bitmask of the channels its bins are
    compatible with (:func:`compatible_lines` as a table; read-only: it is kept for the next
    call)."""
    table = np.zeros(256, np.uint8)
    for b in range(int(bins)):
        near = 0
        for d in range(-int(spread), int(spread) + 1):
            near |= 1 << ((b + d) % int(bins))
        for m in range(256):
            if (m >> b) & 1:
                table[m] |= near
    table.flags.writeable = False
    return table


def oriented_closeness(channels: np.ndarray, tau_px: float, spread: int) -> np.ndarray:
    """(..., B, H, W) float32: for a pixel of direction bin b, ``max(0, 1 - d / tau)`` with d
    the distance to the nearest line of a compatible bin (:func:`compatible_lines`,
    :func:`closeness` per channel, so no channel's closeness reaches into another's rows).
    Binary channels are stamped from their bitmasks in one pass (:func:`_stamp_oriented`,
    equal to the channel-by-channel closeness: tested); weighted ones channel by channel."""
    channels = np.asarray(channels)
    if channels.dtype.kind == "f" or channels.shape[-3] > 8:
        return closeness(compatible_lines(channels, spread), tau_px)
    return oriented_closeness_of_masks(channel_masks(channels), channels.shape[-3], tau_px, spread)


def oriented_closeness_of_masks(masks: np.ndarray, bins: int, tau_px: float, spread: int) -> np.ndarray:
    """:func:`oriented_closeness` of (..., H, W) orientation bitmask images (as rendered):
    (..., B, H, W) float32, in one stamping pass."""
    masks = np.asarray(masks, np.uint8)
    h, w = masks.shape[-2:]
    flat = np.ascontiguousarray(masks.reshape(-1, h, w))
    out = np.zeros((flat.shape[0], int(bins), h, w), np.float32)
    if flat.size:
        kernel = closeness_kernel(tau_px)
        r = kernel.shape[0] // 2
        dy, dx = np.nonzero(kernel > 0)
        _stamp_oriented(flat, compatible_masks(bins, min(int(spread), int(bins))), (dy - r).astype(np.int64),
                        (dx - r).astype(np.int64), kernel[dy, dx], r, out)
    return out.reshape(*masks.shape[:-2], int(bins), h, w)


def stack_channels(x: np.ndarray) -> np.ndarray:
    """(..., B, H, W) -> (..., B H, W): the channels as rows of one image. Why: the chamfer
    score is a sum over rows of row cross-correlations, so the oriented score is the plain
    score's arithmetic on the stacked image with the row weights tiled B times, given the
    closeness images of :func:`oriented_closeness`."""
    x = np.asarray(x)
    return x.reshape(*x.shape[:-3], x.shape[-3] * x.shape[-2], x.shape[-1])


def render_oriented_block(item: tuple) -> np.ndarray:
    """Executor work item: (segments, faces, poses, width, height, hidden, bins) -> each
    view's B oriented channels packed one after another, (V, B n_words) uint64."""
    segments, faces, poses, width, height, hidden, bins = item
    masks = render_panoramas(segments, faces, poses, width=width, height=height, hidden=hidden, orientation_bins=bins)
    words = pack(orientation_channels(masks, bins))
    return words.reshape(len(words), -1)


def _check_oriented(chance: str) -> None:
    if chance != "none":
        raise ValueError(f"the oriented chamfer score (orientation_bins > 1) has the plain halves only: chance none, "
                         f"not {chance!r}")


# ------------------------------------------------------------------ the chamfer score as spectra

def row_weights(height: int, *, polar_deg: float, polar_weight: float, solid_angle: bool) -> np.ndarray:
    """(H,) float32 weight of each equirectangular row in the scores: ``polar_weight`` for
    rows more than ``polar_deg`` above or below the horizon (the floor right under the
    camera, where sunlight stripes, rugs and the tripod's base lie, and a ceiling fan or
    lamp right above it), 1 elsewhere; with ``solid_angle`` times the cosine of the row's
    elevation. Why the cosine: a row at elevation e covers cos(e) of the solid angle of a row
    at the horizon with as many pixels, so unweighted means over pixels count the floor
    under the camera and the ceiling over it several times over (a row 75 degrees down
    four times); weighted, each half is a mean over the directions the camera sees."""
    el = 90.0 - 180.0 * (np.arange(height) + 0.5) / height
    w = np.where(np.abs(el) > polar_deg, polar_weight, 1.0)
    if solid_angle:
        w = w * np.cos(np.radians(el))
    return w.astype(np.float32)


def precision_rows(height: int, polar_deg: float) -> np.ndarray:
    """(H,) float32: 1 for equirectangular rows within ``polar_deg`` of the horizon, 0
    beyond: the rows whose query line pixels the chamfer score's precision half counts
    (``umap.panorama.precision_polar_deg``; 90: all).

    Why: within 15 degrees of the nadir (the default, 75) the camera sees the floor within
    0.4 m of its foot (1.5 m up), where the tripod, rugs and sunlight striped by blinds lie
    and a map line only where a wall stands that close; within 15 degrees of the zenith, a
    ceiling fan or lamp. Detected pixels there are mostly clutter, and clutter near some other
    place's lines wins that place the precision half. The recall half still counts the
    map's lines there (a doorway camera's lintel overhead)."""
    el = 90.0 - 180.0 * (np.arange(height) + 0.5) / height
    return (np.abs(el) <= polar_deg).astype(np.float32)


def chamfer_spectra(lines: np.ndarray, *, tau_px: float, weights: np.ndarray,
                    clutter_share: float | None = None, spread: int | None = None) -> np.ndarray:
    """The map side of the chamfer score (module docstring) of (P, H, W) binary panoramic
    line images, in the form :func:`chamfer_table` multiplies: (F, P, 2H) complex64, F =
    W // 2 + 1, the conjugate row spectra of the weighted line image over its weighted
    pixel count (recall) and of the weighted closeness image (precision); with
    ``clutter_share`` (the ``likelihood`` chance) of the weighted :func:`likelihood_image`
    of the closeness instead.

    Why spectra: the score at column shift k is a circular cross-correlation of rows,
    summed over rows, so every shift of every position comes from one complex product per
    frequency, summed over rows: one matrix product per frequency for a batch of queries,
    instead of one pass over the pixels per shift. Exact up to float32 rounding.

    ``spread`` (the oriented score): ``lines`` are (P, B, H, W) oriented channels
    (:func:`orientation_channels`) and the result (F, P, 2 B H), the same two halves of
    the channel-stacked images (:func:`stack_channels`) with the closeness of each channel
    to the compatible ones' lines (:func:`oriented_closeness`)."""
    if spread is not None:
        if clutter_share is not None:
            raise ValueError("the oriented chamfer score has the plain halves only: no clutter_share")
        lines = np.asarray(lines)
        b = lines.shape[1]
        w = np.tile(np.asarray(weights, np.float32), b)[None, :, None]
        out = np.empty((lines.shape[-1] // 2 + 1, len(lines), 2 * b * lines.shape[-2]), np.complex64)
        for s in range(0, len(lines), SPECTRA_BLOCK):
            block = lines[s:s + SPECTRA_BLOCK]
            _spectra_rows(stack_channels(block), stack_channels(oriented_closeness(block, tau_px, spread)), w,
                          out[:, s:s + SPECTRA_BLOCK])
        return out
    lines = np.asarray(lines).reshape(-1, *lines.shape[-2:])
    w = np.asarray(weights, np.float32)[None, :, None]
    out = np.empty((lines.shape[-1] // 2 + 1, len(lines), 2 * lines.shape[-2]), np.complex64)
    for s in range(0, len(lines), SPECTRA_BLOCK):  # blocks keep the float temporaries small
        close = closeness(lines[s:s + SPECTRA_BLOCK], tau_px)
        if clutter_share is not None:
            close = likelihood_image(close, weights, clutter_share)
        _spectra_rows(lines[s:s + SPECTRA_BLOCK], close, w, out[:, s:s + SPECTRA_BLOCK])
    return out


def map_side(pp: Any, height: int) -> dict[str, Any]:
    """:func:`chamfer_spectra`'s settings from the ``umap.panorama`` parameters ``pp`` for
    images ``height`` rows tall: the row weights, the likelihood score's clutter share (None
    for the other chances) and the orientation spread (None with one bin). One home for the
    map side, so that the index stage, :func:`search_near` and ``placeloc plan``'s look-alike
    check draw their spectra alike."""
    # read whatever the chance: the index stage declares the key, and tests/test_stage_keys.py
    # checks that a stage reads every key it declares
    share = float(pp.clutter_share)
    return {"tau_px": pp.chamfer_tau_px,
            "weights": row_weights(height, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight,
                                   solid_angle=pp.solid_angle),
            # the likelihood score stores the map's log likelihood-ratio image, not its closeness
            "clutter_share": share if pp.chamfer_chance == "likelihood" else None,
            "spread": int(pp.orientation_spread) if int(pp.orientation_bins) > 1 else None}


def map_images(segments: np.ndarray, faces: np.ndarray, poses: np.ndarray, *, width: int, height: int,
               bins: int, hidden: bool) -> np.ndarray:
    """The map's line images at ``poses`` (N, 4) as the score takes them: (N, H, W) 0/1, or
    with ``bins`` > 1 (N, B, H, W) oriented channels (:func:`orientation_channels`)."""
    drawn = render_panoramas(segments, faces, poses, width=width, height=height, hidden=hidden,
                             orientation_bins=bins if bins > 1 else 0)
    return orientation_channels(drawn, bins) if bins > 1 else unpack(drawn, height, width)


def _spectra_rows(lines: np.ndarray, close: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """One block of :func:`chamfer_spectra`: (P, R, W) line images and their (P, R, W) float32
    closeness (or likelihood) images, row weights ``w`` (1, R, 1) -> ``out`` (F, P, 2R), the
    conjugate spectra of [weighted lines / their sum, weighted closeness]. Each half is
    written once into one buffer and the spectra conjugated straight into ``out``: the
    same operations, in the same order, as making each array apart and joining them
    (the same bits: tested), with four fewer passes over a block (the index is
    memory-bound: these elementwise passes were most of its time)."""
    p, r, width = lines.shape
    x = np.empty((p, 2 * r, width), np.float32)
    img = x[:, :r]
    np.multiply(lines, w, out=img, dtype=np.float32)                  # the lines as float32, weighted
    n = np.maximum(img.sum(axis=(1, 2)), 1e-9)[:, None, None]
    np.divide(img, n, out=img)
    np.multiply(close, w, out=x[:, r:])
    np.conjugate(_rfft(x).transpose(2, 0, 1), out=out)


def _rfft(x: np.ndarray) -> np.ndarray:
    """The spectra of the rows of ``x`` (last axis; float32 in, complex64 out), on every
    usable core. Why SciPy's: for a batch of 20 oriented queries (20 x 864 rows of 144),
    NumPy's float32 transform took 10-11 ms, SciPy's 2.6-2.8 ms on one thread and 1.4-1.5 ms
    on two (best and median of 7, warm). SciPy's differs from NumPy's in the last bits only
    (1.5e-5 on values of hundreds). Each row is its own transform,
    the same to the bit whatever the thread count. SciPy's FFT is imported here, not with
    the module: it costs a process 0.12-0.2 s, which UMap's evaluate and extract never use."""
    import scipy.fft

    return scipy.fft.rfft(x, axis=-1, workers=usable_cores())


def _irfft(x: np.ndarray, n: int) -> np.ndarray:
    """The inverse of :func:`_rfft` along the last axis, ``n`` samples, on every usable core
    (the same to the bit as NumPy's for these arrays)."""
    import scipy.fft

    return scipy.fft.irfft(x, n=n, axis=-1, workers=usable_cores())


def _batch_products(spectra: np.ndarray, qs: np.ndarray) -> np.ndarray:
    """``spectra @ qs`` per frequency ((F, P, K) by (F, K, N) -> (F, P, N)), a lone query
    (N = 1) beside a zero one. Why: each query's column of a matrix product is its own dot
    products, the same to the bit in any batch of two or more (tested), but numpy takes
    another BLAS route for a single column (a matrix-vector product) whose sums round
    differently, and a search's last batch may hold one query."""
    if qs.shape[-1] != 1:
        return np.matmul(spectra, qs)
    return np.matmul(spectra, np.concatenate([qs, np.zeros_like(qs)], axis=-1))[..., :1]


def seen_rows(coverage: np.ndarray, height: int, tilt_deg: np.ndarray | None = None) -> np.ndarray:
    """(N, height) float32, 1 for the line-image rows whose centre lies inside each query's
    ``coverage`` (N, 4: left, top, width, height as fractions of the whole panorama, as
    :class:`placeloc.geometry.panorama.Coverage`) by more than the drawing's margin, else 0:
    the rows a cropped photo sphere saw. ``tilt_deg`` (N,): how far each was levelled; its
    rows are drawn turned, so the band it saw is narrowed by as much on either side."""
    cov = np.asarray(coverage, np.float64).reshape(-1, 4)
    centre = (np.arange(height) + 0.5) / height
    tilt = np.zeros(len(cov)) if tilt_deg is None else np.asarray(tilt_deg, np.float64).reshape(-1)
    margin = ((COVERAGE_MARGIN_DEG + tilt) / 180.0)[:, None]
    top, bottom = cov[:, 1:2] + margin, cov[:, 1:2] + cov[:, 3:4] - margin
    return ((centre[None, :] >= top) & (centre[None, :] <= bottom)).astype(np.float32)


def _table_products(spectra: np.ndarray, qs: np.ndarray, seen: np.ndarray | None) -> np.ndarray:
    """The products of :func:`chamfer_table` (chance none; :func:`_batch_products`), (F, P,
    N). With ``seen`` (N, R: :func:`seen_rows` tiled over the channels, R the recall half's
    rows) the halves apart, the recall over the map's line pixels in the rows each query saw
    only: its product (the query's closeness is zero outside them) over the share of the
    map's weighted line pixels there, a row's share being its stored spectrum's zero
    frequency."""
    if seen is None:
        return _batch_products(spectra, qs)
    rows = seen.shape[1]
    share = np.maximum(seen @ spectra[0, :, :rows].real.T, 1e-6).T.astype(np.float32)   # (P, N)
    return _batch_products(spectra[:, :, :rows], qs[:, :rows]) / share[None] + \
        _batch_products(spectra[:, :, rows:], qs[:, rows:])


def _close_over_seen(q_close: np.ndarray, seen: np.ndarray | None,
                     channels: int = 1) -> tuple[np.ndarray, np.ndarray | None]:
    """The queries' closeness images (N, C H, W) with the rows each photo did not see
    (``seen`` (N, H), :func:`seen_rows`) zeroed in every one of its ``channels``, and
    ``seen`` tiled over them as :func:`_table_products` takes it; ``seen`` None: both as
    they are."""
    if seen is None:
        return q_close, None
    seen = np.tile(np.asarray(seen, np.float32), channels)
    return q_close * seen[:, :, None], seen


def chamfer_table(spectra: np.ndarray, queries: np.ndarray, *, tau_px: float, weights: np.ndarray,
                  chance: str, precision_rows: np.ndarray | None = None, clutter_share: float = 0.5,
                  spread: int | None = None, seen: np.ndarray | None = None, recall_weight: float = 0.5) -> np.ndarray:
    """Chamfer scores (module docstring, rows weighted by ``weights``, halves corrected for
    chance as ``chance`` says: see :func:`chamfer_yaw_scores`) of a batch of (N, H, W) query
    line images against every map panorama of ``spectra`` (:func:`chamfer_spectra`) at every
    column shift: (N, P, W) float32, entry (n, p, k) for query n taken at heading k 360 / W
    at position p. Equal to :func:`chamfer_yaw_scores` with unit weights.

    The chance levels cost nothing extra: a row's mean over all shifts is its zero
    frequency, so the ``area`` level of the map side is the stored spectra's zero frequency
    (the weighted closeness summed) and the ``yaw`` level is each half's product at
    frequency 0; the correction is then a per-(query, position) scale of each half's
    product and an offset, applied before the one inverse FFT. ``likelihood`` needs spectra
    built with the same ``clutter_share``; the query's closeness becomes its
    :func:`likelihood_image` and the product is the plain one.

    ``spread`` (the oriented score): ``queries`` are (N, B, H, W) oriented channels (0/1, or
    weights), ``spectra`` built with the same ``spread``; chance ``none`` only.

    ``seen`` (N, H; :func:`seen_rows`; chance ``none``): the rows each query's photo saw (a
    photo sphere stored cropped); its recall half counts the map's lines in those rows only
    (:func:`_table_products`), so a pose is not marked down for lines where the photo has no
    pixels. None: every row.

    ``recall_weight`` (:func:`halves_mixed`): each half's products are scaled by twice its
    weight before the one inverse FFT, which then gives the mixed score."""
    mix_r, mix_p = 2.0 * float(recall_weight), 2.0 * (1.0 - float(recall_weight))
    if seen is not None and chance != "none":
        seen = None   # the chance-corrected halves are not derived for a part of the sphere
    if spread is not None:
        _check_oriented(chance)
        queries = np.asarray(queries)
        n_q, b, h, w = queries.shape
        wr = np.asarray(weights, np.float32)[None, None, :, None]
        q = queries.astype(np.float32)
        q_close = stack_channels(oriented_closeness(q if queries.dtype.kind == "f" else queries, tau_px, spread))
        if precision_rows is not None:
            q = q * np.asarray(precision_rows, np.float32)[None, None, :, None]
        nq = np.maximum((q * wr).sum(axis=(1, 2, 3)), 1e-9)[:, None, None]
        q_close, seen = _close_over_seen(q_close, seen, b)
        # times the weights after the division: at 0.5 (times 1.0) the table before, to the bit
        x = np.concatenate([q_close * mix_r, stack_channels(q) / nq * mix_p], axis=1)     # (N, 2 B H, W)
        qs = np.ascontiguousarray(_rfft(x).astype(np.complex64).transpose(2, 1, 0))
        prod = _table_products(spectra, qs, seen)                                 # (F, P, N)
        return (0.5 * _irfft(prod.transpose(2, 1, 0), w)).astype(np.float32)
    queries = np.asarray(queries).reshape(-1, *queries.shape[-2:])
    n_q, h, w = queries.shape
    wr = np.asarray(weights, np.float32)[None, :, None]
    q = queries.astype(np.float32)                                            # a float query: weighted
    q_close = closeness(q if queries.dtype.kind == "f" else queries, tau_px)
    if chance == "likelihood":
        q_close = likelihood_image(q_close, weights, clutter_share)
    if precision_rows is not None:                                            # the precision half's rows only
        q = q * np.asarray(precision_rows, np.float32)[None, :, None]
    nq = np.maximum((q * wr).sum(axis=(1, 2)), 1e-9)[:, None, None]
    q_close, seen = _close_over_seen(q_close, seen)
    x = np.concatenate([q_close, q / nq], axis=1)                             # (N, 2H, W)
    qs = np.ascontiguousarray(_rfft(x).astype(np.complex64).transpose(2, 1, 0))  # (F, 2H, N)
    if chance in ("none", "likelihood"):
        qs[:, :h] *= np.float32(mix_r)
        qs[:, h:] *= np.float32(mix_p)
        prod = _table_products(spectra, qs, seen)                             # (F, P, N)
        return (0.5 * _irfft(prod.transpose(2, 1, 0), w)).astype(np.float32)
    recall = _batch_products(spectra[:, :, :h], qs[:, :h])                    # (F, P, N) each half
    precision = _batch_products(spectra[:, :, h:], qs[:, h:])
    if chance == "area":
        area = float(w) * float(np.sum(weights))
        r_chance = np.broadcast_to((q_close * wr).sum(axis=(1, 2))[None, :] / area, recall.shape[1:])
        p_chance = np.broadcast_to(spectra[0, :, h:].real.sum(axis=1)[:, None] / area, recall.shape[1:])
    elif chance == "yaw":
        r_chance, p_chance = recall[0].real / w, precision[0].real / w
    else:
        raise ValueError(f"chance must be one of {', '.join(CHANCES)}, not {chance!r}")
    r_scale = mix_r / np.maximum(1.0 - r_chance, CHANCE_FLOOR)
    p_scale = mix_p / np.maximum(1.0 - p_chance, CHANCE_FLOOR)
    prod = recall * r_scale.astype(np.float32) + precision * p_scale.astype(np.float32)
    offset = (r_chance * r_scale + p_chance * p_scale).T                      # (N, P)
    return (0.5 * (_irfft(prod.transpose(2, 1, 0), w) - offset[:, :, None])).astype(np.float32)


def box_blur(images: np.ndarray, radius_px: int) -> np.ndarray:
    """(..., H, W) float32 images, each pixel the mean of the (2r + 1)-pixel square around it,
    wrapping around horizontally (a panorama has no left edge) and zero beyond the poles, so
    that what lies on the image is kept (a pixel's mass spread over its square; mass past a
    pole is lost). ``radius_px`` 0: the images as float32."""
    images = np.asarray(images, np.float32)
    r = int(radius_px)
    if r <= 0:
        return images.copy()
    h, w = images.shape[-2:]
    flat = images.reshape(-1, h, w)
    out = np.empty_like(flat)
    for i, img in enumerate(flat):
        wide = np.concatenate([img[:, w - r:], img, img[:, :r]], axis=1)
        out[i] = cv2.boxFilter(wide, -1, (2 * r + 1, 2 * r + 1), normalize=True,
                               borderType=cv2.BORDER_CONSTANT)[:, r:r + w]
    return out.reshape(images.shape)


def tolerant_bands(width: int, recall_tau_px: float) -> int:
    """The column frequencies :func:`search_panoramas` keeps of the tolerant table
    (:func:`tolerant_chamfer_table`'s ``bands``): 0 to ``width / recall_tau_px`` cycles around
    the panorama, at most all ``width // 2 + 1``.

    Why: the recall half correlates the map's lines with the query's closeness, a cone
    ``recall_tau_px`` pixels in half-width along a row, whose spectrum (a squared sinc) first
    falls to zero at ``width / recall_tau_px`` cycles; the precision half's blur is a low
    pass too. Above that the table holds mostly the heading's fine detail, and the search
    takes only each position's best over all headings from it; the products are one per
    frequency, so 19 of 73 (8 px at 144 columns) cost a quarter."""
    return int(min(width // 2 + 1, math.floor(width / recall_tau_px) + 1))


def tolerant_chamfer_table(spectra: np.ndarray, queries: np.ndarray, *, recall_tau_px: float, blur_px: int,
                           weights: np.ndarray, precision_rows: np.ndarray | None = None,
                           spread: int | None = None, bands: int | None = None,
                           seen: np.ndarray | None = None, recall_weight: float = 0.5) -> np.ndarray:
    """A more tolerant chamfer score (chance ``none``) of a batch of query line images
    against the same ``spectra`` as :func:`chamfer_table` (built with its ``tau_px``), at
    every position and column shift: (N, P, W) float32. Only the query's side changes, so
    it needs no second index; with ``recall_tau_px`` equal to the spectra's tau and
    ``blur_px`` 0 it is :func:`chamfer_table` (tested).

    What each half becomes (m the map's line image, q the query's times the precision
    rows, w the row weights, tau the spectra's truncation, x + k the query pixel a map pixel
    x falls on at shift k):

    - recall: ``sum_x w m(x) c'(x + k) / sum_x w m(x)`` with ``c'`` the query's closeness
      ``max(0, 1 - d / tau')`` at ``tau' = recall_tau_px`` instead of tau. Since ``c' >= c``
      and a map line moved by delta pixels loses at most ``delta / tau'`` of its closeness
      (``delta / tau`` in the exact score), the half falls off tau' / tau times more slowly
      as the pose moves away from where the lines fall;
    - precision: ``sum_y w (K * q)(y) g(y - k) / sum_y w (K * q)(y)``, ``g`` the map's
      closeness at tau (the stored spectra) and ``K * q`` the query's line image blurred by
      the normalised (2 b + 1)-pixel square ``K``, b = ``blur_px`` (:func:`box_blur`). As
      K is symmetric, the numerator is ``sum_y q(y) sum_d K(d) w(y + d) g(y + d - k)``:
      each query line pixel scores the map's closeness averaged over the square around it
      (the row weights varying little across it). The average of the cone ``max(0, 1 -
      d / tau)`` over the square reaches tau + b pixels, so a detected line up to tau + b
      pixels off a map line still earns, where the exact half gives nothing beyond tau.

    Why: near a wall a few centimetres move the nearby wall's lines by several pixels, so
    the exact score's peak there is narrower than the grid step, and the grid points around
    a true pose score like many other places (docs/umap.md, "Candidates by a tolerant
    score"). With tolerance wider than the lines' move over half a step, the truth's
    nearest grid point keeps much of its score and ranks among the places a search
    refines; the answer itself is still scored with the exact score.

    ``bands``: only the column frequencies 0 .. bands - 1 of each row's correlation are
    multiplied (:func:`tolerant_bands`), so the table is the full one low-passed over the
    column shifts (tested): a heading blurred, for bands / (W / 2 + 1) of the products'
    cost; None: all. ``seen`` and ``recall_weight``: as :func:`chamfer_table`'s."""
    queries = np.asarray(queries)
    if spread is None:
        queries = queries.reshape(-1, 1, *queries.shape[-2:])            # one channel: the plain score
    n_q, b, h, w = queries.shape
    q = queries.astype(np.float32)                                        # a float query: weighted
    source = q if queries.dtype.kind == "f" else queries
    if spread is None:
        q_close = closeness(source[:, 0], recall_tau_px)
    else:
        q_close = stack_channels(oriented_closeness(source, recall_tau_px, spread))
    if precision_rows is not None:                                        # the precision half's rows only
        q = q * np.asarray(precision_rows, np.float32)[None, None, :, None]
    q = box_blur(q, blur_px)
    wr = np.asarray(weights, np.float32)[None, None, :, None]
    nq = np.maximum((q * wr).sum(axis=(1, 2, 3)), 1e-9)[:, None, None]
    q_close, seen = _close_over_seen(q_close, seen, b)
    x = np.concatenate([q_close * (2.0 * float(recall_weight)),
                        stack_channels(q) / nq * (2.0 * (1.0 - float(recall_weight)))], axis=1)   # (N, 2 B H, W)
    f = spectra.shape[0] if bands is None else max(1, min(int(bands), spectra.shape[0]))
    qs = np.ascontiguousarray(_rfft(x)[..., :f].astype(np.complex64).transpose(2, 1, 0))
    prod = _table_products(spectra[:f], qs, seen)                         # (f, P, N); the rest are zero
    return (0.5 * _irfft(prod.transpose(2, 1, 0), w)).astype(np.float32)


def best_pose(scores: np.ndarray) -> tuple[int, int, float]:
    """(position row, column shift, score) of the best entry of a (P, W) score table."""
    i, k = np.unravel_index(int(np.argmax(scores)), scores.shape)
    return int(i), int(k), float(scores[i, k])



class Rival(NamedTuple):
    """The best *rival* of an answer (:func:`rival_pose`): its score, plan position and
    heading column; NaN score and position, column -1, where no pose scored is a rival."""

    score: float
    x: float
    y: float
    col: int


def rival_pose(table: np.ndarray, grid_xy: np.ndarray, seen_xy: np.ndarray, seen_score: np.ndarray,
               seen_col: np.ndarray, answer_xy: np.ndarray, answer_col: int, *, distance_m: float,
               yaw_cols: float) -> Rival:
    """The best *rival* of an answer: a pose that would be a different answer, i.e. more
    than ``distance_m`` from ``answer_xy`` at any heading, or within it at a heading more
    than ``yaw_cols`` columns (circularly) from ``answer_col``.

    Looked for among every (grid position, shift) of the (P, W) score ``table`` and among
    the off-grid plan points the local search scored (``seen_xy``, ``seen_score``,
    ``seen_col``: each point's best over the shifts it was scored at and that shift, all
    within a few columns of its candidate's heading, so they only give rivals by distance).
    The first of equal scores wins: the grid's far poses, then its turned ones, then the
    points scored off the grid. The answer's score minus the rival's is its margin: how much
    better the answer is than the best place or heading that would make it wrong, by the
    same score the search ranks with; the rival's pose is where a doubtful answer's
    alternative lies (a twin room's same spot)."""
    best = Rival(-np.inf, math.nan, math.nan, -1)
    grid_xy = np.asarray(grid_xy, float)
    is_far = np.hypot(*(grid_xy - answer_xy).T) > distance_m
    far = np.flatnonzero(is_far)
    if len(far):
        # each position's best shift first: one pass over the table, no copy of its far rows
        per_position = table.max(axis=1)
        i = far[int(np.argmax(per_position[far]))]
        best = Rival(float(per_position[i]), float(grid_xy[i, 0]), float(grid_xy[i, 1]), int(np.argmax(table[i])))
    w = table.shape[1]
    cols = np.abs((np.arange(w) - int(answer_col) + w // 2) % w - w // 2)   # circular distance in columns
    turned = np.flatnonzero(cols > yaw_cols + 1e-9)
    near = np.flatnonzero(~is_far)
    if len(near) and len(turned):
        sub = table[np.ix_(near, turned)]
        i, k = np.unravel_index(int(np.argmax(sub)), sub.shape)
        if float(sub[i, k]) > best.score:
            best = Rival(float(sub[i, k]), float(grid_xy[near[i], 0]), float(grid_xy[near[i], 1]), int(turned[k]))
    if len(seen_xy):
        far_seen = np.flatnonzero(np.hypot(*(np.asarray(seen_xy, float) - answer_xy).T) > distance_m)
        if len(far_seen):
            i = far_seen[int(np.argmax(seen_score[far_seen]))]
            if float(seen_score[i]) > best.score:
                best = Rival(float(seen_score[i]), float(seen_xy[i, 0]), float(seen_xy[i, 1]), int(seen_col[i]))
    return best if np.isfinite(best.score) else Rival(math.nan, math.nan, math.nan, -1)


class PanoramaAnswers(NamedTuple):
    """What :func:`search_panoramas` finds for each of N query panoramas."""

    best: np.ndarray      # (N,) grid row of the answer's candidate
    xy: np.ndarray        # (N, 2) plan position, refined off the grid
    heading: np.ndarray   # (N,) degrees
    score: np.ndarray     # (N,) the answer's score
    rival: np.ndarray     # (N,) the best score of a pose that would be another answer (:func:`rival_pose`)
    rival_xy: np.ndarray  # (N, 2) where that rival stands (NaN: no rival)
    rival_heading: np.ndarray  # (N,) and the way it faces, degrees
    # (N,) the best score before the final search (refine_final_m; the score itself where none ran)
    before_final: np.ndarray

    @property
    def margin(self) -> np.ndarray:
        """How far the answer is ahead of the best different answer (NaN: no rival): its
        score before the final search minus the rival's. Why not the final score: the final
        search polishes the winner alone, to the centimetre, and no rival gets that polish,
        so a twin room's spot, as good as the answer, would seem 0.01 behind it."""
        return self.before_final - self.rival


def best_over_heights(found: Sequence[PanoramaAnswers], offsets: Sequence[int], *, distance_m: float,
                      yaw_deg: float) -> PanoramaAnswers:
    """Each panorama's answer over the grid's layers of several camera heights
    (``umap.grid.heights``), each searched alone (``found[j]``, its grid rows from
    ``offsets[j]``): the layer whose answer scores highest (the first of equal scores), its
    grid row made global, so that the answer's height is the row's. Its rival is the best
    pose any layer's search saw that would be another answer: the chosen layer's own rival,
    and another layer's answer (its score before the final search, as the margin compares)
    or rival where it lies more than ``distance_m`` from the answer or faces more than
    ``yaw_deg`` away (:func:`rival_pose`'s rule); the same place at another height is no
    rival."""
    score = np.stack([f.score for f in found])
    pick = np.argmax(score, axis=0)   # a layer that did not search a panorama holds -inf there (unsearched)
    n = score.shape[1]
    take = np.arange(n)

    def field(name: str) -> np.ndarray:
        return np.stack([getattr(f, name) for f in found])[pick, take]

    best = np.stack([f.best + int(o) for f, o in zip(found, offsets)])[pick, take]
    xy, heading = field("xy"), field("heading")
    rival, rival_xy, rival_heading = field("rival").copy(), field("rival_xy").copy(), field("rival_heading").copy()

    def apart(k: int, other_xy: np.ndarray, other_heading: float) -> bool:
        if not (np.isfinite(other_xy).all() and np.isfinite(other_heading)):
            return False
        turned = abs((float(other_heading) - float(heading[k]) + 180.0) % 360.0 - 180.0)
        return bool(np.hypot(*(other_xy - xy[k])) > distance_m or turned > yaw_deg)

    for k in range(n):
        for j, f in enumerate(found):
            if j == pick[k]:
                continue
            for value, where, facing in ((f.before_final[k], f.xy[k], f.heading[k]),
                                         (f.rival[k], f.rival_xy[k], f.rival_heading[k])):
                if np.isfinite(value) and apart(k, where, facing) and not value <= rival[k]:
                    rival[k], rival_xy[k], rival_heading[k] = value, where, facing
    return PanoramaAnswers(best, xy, heading, field("score"), rival, rival_xy, rival_heading, field("before_final"))


def unsearched(n: int) -> PanoramaAnswers:
    """The answers of a layer that searched none of ``n`` panoramas: no score (-inf, never
    :func:`best_over_heights`' pick), no pose, no rival."""
    nan = np.full(n, np.nan)
    return PanoramaAnswers(np.zeros(n, np.int64), np.full((n, 2), np.nan), nan, np.full(n, -np.inf), nan,
                           np.full((n, 2), np.nan), nan, nan)


def scatter_answers(into: PanoramaAnswers, rows: np.ndarray, found: PanoramaAnswers) -> PanoramaAnswers:
    """``into`` with the answers of panoramas ``rows`` replaced by ``found`` (searched for them only)."""
    return PanoramaAnswers(*(_put(a, rows, b) for a, b in zip(into, found)))


def _put(a: np.ndarray, rows: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = a.copy()
    out[rows] = b
    return out


def search_layers(lines: np.ndarray, poses: np.ndarray, segments: np.ndarray, faces: np.ndarray,
                  database: dict[str, np.ndarray], pp: Any, *, tolerance_px: int, wall_margin_m: float, hidden: bool,
                  progress: Callable[[Iterable, str, int], Iterable] = lambda it, desc, total: it,
                  seen: np.ndarray | None = None,
                  inside: Sequence[Callable[[np.ndarray], np.ndarray] | None] | None = None,
                  outside: np.ndarray | None = None) -> PanoramaAnswers:
    """:func:`search_panoramas` over a grid of one or more layers, one per camera height
    (``umap.grid.heights``; ``poses`` holds them one after another, as build-dictionary
    writes them): each layer searched alone over its own rows of ``database``, each
    panorama's answer the best over them (:func:`best_over_heights`). With
    ``pp.height_layers`` k, each panorama is searched whole only in the k layers whose grid
    table scores it best (:func:`grid_table_best`, chamfer only). ``progress(iterable, what,
    total)`` wraps each layer's loop over its panoramas. ``seen``, ``inside`` and ``outside``
    (here the best over the layers searched, its row counted over every layer): as
    :func:`search_panoramas`'."""
    starts = np.flatnonzero(np.r_[True, np.diff(poses[:, 2]) != 0]) if len(poses) else np.zeros(1, np.int64)
    bounds = list(zip(starts.tolist(), [*starts[1:].tolist(), len(poses)]))
    # the spectra hold positions on their second axis (frequency first), the rest on their first
    layers = [{k: v[:, lo:hi] if k == "spectra" else v[lo:hi] for k, v in database.items()} for lo, hi in bounds]
    n = len(lines)
    searched = np.ones((len(bounds), n), bool)   # [layer, panorama]: searched whole there
    keep = int(pp.height_layers)
    if len(bounds) > 1 and 0 < keep < len(bounds) and "spectra" in database:
        # each panorama's best layers by the grid table alone (a fifth of a search's cost):
        # the search off the grid, most of it, runs there only
        table = np.stack([grid_table_best(lines, layer["spectra"], pp, seen, region_masks(inside, poses[lo:hi]))
                          for layer, (lo, hi) in zip(layers, bounds)])
        searched[:] = False
        searched[np.argsort(-table, axis=0, kind="stable")[:keep], np.arange(n)[None, :]] = True
    found = []
    for (lo, hi), layer, rows in zip(bounds, layers, searched):
        ks = np.flatnonzero(rows)
        if not len(ks):   # no panorama's best layers by the table
            found.append(unsearched(n))
            continue
        what = "panorama search" + (f" at {poses[lo, 2]:.2f} m" if len(bounds) > 1 else "")
        away = None if outside is None else np.tile([-np.inf, -1.0], (len(ks), 1))
        answers = search_panoramas(lines[ks] if len(ks) < n else lines, poses[lo:hi], segments, faces, layer, pp,
                                   tolerance_px=tolerance_px, wall_margin_m=wall_margin_m, hidden=hidden,
                                   progress=lambda it, what=what, m=len(ks): progress(it, what, m),
                                   seen=None if seen is None else seen[ks],
                                   inside=None if inside is None else [inside[k] for k in ks], outside=away)
        if away is not None:   # the best outside over the layers, its row among all of them
            better = away[:, 0] > outside[ks, 0]
            outside[ks[better]] = np.column_stack([away[better, 0], away[better, 1] + lo])
        found.append(answers if len(ks) == n else scatter_answers(unsearched(n), ks, answers))
    if len(found) == 1:
        return found[0]
    return best_over_heights(found, [lo for lo, _ in bounds], distance_m=float(pp.margin_distance_m),
                             yaw_deg=float(pp.margin_yaw_deg))


class CeilingChoice(NamedTuple):
    """The home's ceiling height found among several searched (``umap.grid.ceilings``)."""

    layer: float              # the ceiling of the grid's layers that score the run's panoramas best
    height: float             # refined between that layer's neighbours: the ceiling the answers are searched at
    means: dict[float, float]  # each ceiling's mean over the panoramas of their best grid-table score
    rows: tuple[int, int]     # the grid rows [lo, hi) of the chosen ceiling's layers

    @property
    def at_edge(self) -> bool:
        """The best ceiling is the lowest or the highest searched (with more than one): the
        home's may lie beyond the list."""
        return len(self.means) > 1 and self.layer in (min(self.means), max(self.means))


def region_masks(inside: Sequence[Callable[[np.ndarray], np.ndarray] | None] | None, poses: np.ndarray) -> np.ndarray | None:
    """(N, P) bool: the grid ``poses`` inside each query's region (``inside``, as
    :func:`search_panoramas` takes it), or None where no query has one."""
    if inside is None or all(r is None for r in inside):
        return None
    every = np.ones(len(poses), bool)
    return np.stack([every if r is None else r(poses[:, :2]) for r in inside])


def choose_ceiling(lines: np.ndarray, ceiling: np.ndarray, spectra: np.ndarray, pp: Any,
                   seen: np.ndarray | None = None, keep: np.ndarray | None = None) -> CeilingChoice:
    """The home's ceiling among the grid's layers of several ceiling heights (``ceiling``:
    each grid position's, as build-dictionary writes them, one ceiling's layers contiguous):
    each panorama's best grid-table score over each ceiling's layers (:func:`grid_table_best`,
    a fifth of a search's cost), averaged over the panoramas; the highest mean wins (the
    lowest ceiling of equal means), and the height is refined by the parabola through it and
    its two neighbours (:func:`parabola_peak`). ``keep`` (N, P) bool: each panorama's grid
    positions that count (its room, ``umap.room_hints``; None: all).

    Why one ceiling for the run, and by the grid table: a home's rooms share a ceiling height
    (a plan drawn by hand gives one), and the mean over a run's panoramas is a smooth curve
    with one peak where a panorama's own best is not. On development homes 0-2 (ceilings
    2.37, 2.5 and 2.66 m, searched at 2.3-2.8 every 0.1 m) the table's mean peaks at the layer
    nearest the truth each time, as the whole search's does, for a fifth of its cost a layer
    (docs/umap.md, "A floor plan whose ceiling height is not known")."""
    ceiling = np.asarray(ceiling, np.float64)
    means, bounds = {}, {}
    for c in np.unique(ceiling):
        rows = np.flatnonzero(ceiling == c)
        lo, hi = int(rows[0]), int(rows[-1]) + 1
        if hi - lo != len(rows):
            raise ValueError(f"the grid rows of ceiling {c:g} m are not one block: rebuild build-dictionary (--force)")
        # over every position of every camera height under this ceiling: each panorama's best over its layers
        best = grid_table_best(lines, spectra[:, lo:hi], pp, seen, None if keep is None else keep[:, lo:hi])
        means[float(c)] = float(np.mean(best)) if len(best) else -math.inf
        bounds[float(c)] = (lo, hi)
    chosen = max(means, key=lambda c: (means[c], -c))
    order = sorted(means)
    k = order.index(chosen)
    height = chosen
    if 0 < k < len(order) - 1:
        height = parabola_peak(order[k - 1:k + 2], [means[c] for c in order[k - 1:k + 2]])
    return CeilingChoice(chosen, height, means, bounds[chosen])


def parabola_peak(x: Sequence[float], y: Sequence[float]) -> float:
    """Where the parabola through three points (x ascending, the middle one highest or level
    with the highest) peaks, kept between the outer two: the vertex of a three-point
    interpolation, for unequal spacing too. A flat or upturned triple gives the middle x."""
    (x0, x1, x2), (y0, y1, y2) = (float(v) for v in x), (float(v) for v in y)
    den = (x1 - x0) * (y1 - y2) - (x1 - x2) * (y1 - y0)
    if not den > 0.0:   # no peak: a line or a valley
        return x1
    peak = x1 - 0.5 * ((x1 - x0) ** 2 * (y1 - y2) - (x1 - x2) ** 2 * (y1 - y0)) / den
    return float(min(max(peak, x0), x2))


# ------------------------------------------------------------------ local refinement

@njit(cache=True)
def _distinct(order: np.ndarray, xy: np.ndarray, count: int, min_separation_m: float, out: np.ndarray,
              taken: int = 0) -> int:
    """Fills ``out[taken:count]`` with rows of ``order`` at least ``min_separation_m`` from
    every row in ``out`` so far (its first ``taken`` given); returns how many ``out`` holds."""
    n = taken
    if n >= count:
        return n
    for i in order:
        ok = True
        for m in range(n):
            j = out[m]
            if math.hypot(xy[i, 0] - xy[j, 0], xy[i, 1] - xy[j, 1]) < min_separation_m:
                ok = False
                break
        if ok:
            out[n] = i
            n += 1
            if n == count:
                break
    return n


def _ranked(scores: np.ndarray) -> np.ndarray:
    """The rows of a (P, W) score table by their best score, best first (the first of equals
    first), leaving out the rows that score -inf everywhere (outside a photo's room:
    ``umap.room_hints``)."""
    top = scores.max(axis=1)
    order = np.argsort(-top, kind="stable")
    return order[np.isfinite(top[order])]


def distinct_candidates(scores: np.ndarray, xy: np.ndarray, *, count: int, min_separation_m: float) -> np.ndarray:
    """Rows of the ``count`` best grid positions (each scored at its best yaw), greedily
    skipping any within ``min_separation_m`` of one already taken: the distinct places that
    compete (the same spot in two look-alike rooms, say)."""
    order = _ranked(scores)
    out = np.zeros(max(count, 0), dtype=np.int64)
    n = _distinct(order.astype(np.int64), np.ascontiguousarray(xy, np.float64), count, float(min_separation_m), out)
    return out[:n]


def coarse_to_fine_candidates(scores: np.ndarray, tolerant: np.ndarray, xy: np.ndarray, *, count: int, coarse: int,
                              min_separation_m: float) -> np.ndarray:
    """Rows of ``count`` distinct places (:func:`distinct_candidates`): the best
    ``count - coarse`` by the exact ``scores`` first, then places by the ``tolerant`` table
    (:func:`tolerant_chamfer_table`, each position at its best yaw) in its order, each at
    least ``min_separation_m`` from every place taken, until there are ``count``.
    ``coarse`` >= ``count``: every candidate by the tolerant table."""
    count = max(int(count), 0)
    exact = max(count - max(int(coarse), 0), 0)
    out = np.zeros(count, dtype=np.int64)
    pts = np.ascontiguousarray(xy, np.float64)
    n = _distinct(_ranked(scores).astype(np.int64), pts, exact, float(min_separation_m), out)
    n = _distinct(_ranked(tolerant).astype(np.int64), pts, count, float(min_separation_m), out, n)
    return out[:n]


def suppressed_neighbours(scores: np.ndarray, xy: np.ndarray, candidates: np.ndarray, *, top: int,
                          min_separation_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The grid rows among the ``top`` best by rank alone (each at its best yaw) that are not
    ``candidates`` (:func:`distinct_candidates`), in rank order, and for each the index into
    ``candidates`` of the best-ranked candidate within ``min_separation_m`` of it (the one
    that kept it out; a row near none, ranked below the last candidate, is left out).

    Why: a narrow peak (0.1 m wide) between grid points can lie in the cell of a grid point
    one step from a better-ranked candidate; the separation keeps that point out, and a
    candidate's search covers its own cell only, so the peak's cell is never searched
    (generated test home 24's pano_015 at one grid origin: the point 0.08 m from the truth
    ranked 5th of 1,450 and lay 0.25 m from the 2nd candidate). The best few by rank are where
    the table itself puts the peak. :func:`search_panoramas` searches the cells of those kept
    out by a pose of its beam after the beam is chosen, so that the beam is still chosen
    among distinct places by their own cells (searched before the beam, the extra cells
    raise the places they lie beside over others: the best of more samples), and each that
    beats its pose joins the beam beside it rather than in its place (on the rugged score a
    better start can climb to a lower bump: both on generated homes, docs/umap.md)."""
    if top <= 0 or not len(candidates):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    order = _ranked(scores)[:top]
    rows = order[~np.isin(order, candidates)].astype(np.int64)
    d = np.hypot(*(xy[rows][:, None, :] - xy[candidates][None, :, :]).transpose(2, 0, 1))     # (rows, candidates)
    near = d < min_separation_m
    owner = np.where(near.any(axis=1), np.argmax(near, axis=1), -1).astype(np.int64)
    return rows[owner >= 0], owner[owner >= 0]


# the 8 neighbours of a point on a unit square grid
NEIGHBOURS = np.array([[dx, dy] for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy], float)


def square_offsets(radius: int) -> np.ndarray:
    """(K, 2) offsets of the points of a square grid within ``radius`` steps of its centre
    on each axis, the centre left out (radius 1: :data:`NEIGHBOURS`)."""
    r = range(-int(radius), int(radius) + 1)
    return np.array([[dx, dy] for dx in r for dy in r if dx or dy], float).reshape(-1, 2)


def refine_steps(grid_step_m: float, finest_m: float) -> list[float]:
    """The steps of the local search after the cell stage (:func:`search_panoramas`):
    halving from a sixth of the grid step (the cell stage samples at a third) while not
    below ``finest_m``; at least one step."""
    out = [grid_step_m / 6.0]
    while out[-1] / 2.0 >= finest_m - 1e-9:
        out.append(out[-1] / 2.0)
    return out


# moves a pose may make at each step of the final search before the step is halved: a pose
# still climbing after 4 moves at one step is leaving the basin the beam found, and the cap
# bounds the renders (8 a move) a panorama
FINAL_MOVES = 4


def pattern_search(score_at: Callable[[np.ndarray, Any], tuple[np.ndarray, Any]], xy: np.ndarray, value: float,
                   state: Any, *, start_m: float, finest_m: float, moves: int = FINAL_MOVES) -> tuple[np.ndarray, float, Any]:
    """A compass (pattern) search for the maximum of a score over the plane (Kolda, Lewis and
    Torczon, "Optimization by direct search: new perspectives on some classical and modern
    methods", SIAM Review 2003): from ``xy`` (scoring ``value``) poll the 8 neighbours
    ``step`` away, move to the best while it is better (at most ``moves`` times), then
    halve the step, from ``start_m`` while the step is not below ``finest_m`` metres. Steps
    and stop are in metres, not grid steps; where it ends still depends on where it starts
    (:func:`search_panoramas` starts it from a point of the plan's own lattice).

    ``score_at(points, state)`` gives the (P,) scores of (P, 2) points (``-inf`` for points
    not allowed) and a (P,) sequence of the states they were scored with (here the heading
    column: each pose's yaw is re-searched around its own); ``state`` is that of ``xy``.
    Returns the best point, its score and its state."""
    xy = np.asarray(xy, float).copy()
    step = float(start_m)
    while step >= finest_m - 1e-9:
        for _ in range(moves):
            scores, states = score_at(xy[None] + step * NEIGHBOURS, state)
            i = int(np.argmax(scores))
            if not scores[i] > value:
                break
            xy, value, state = xy + step * NEIGHBOURS[i], float(scores[i]), states[i]
        step /= 2.0
    return xy, value, state


def lattice_disk(centre: np.ndarray, spacing_m: float, radius_m: float) -> np.ndarray:
    """The points of the plan's own lattice of ``spacing_m`` (multiples of it from the plan's
    origin, whatever the grid's) within ``radius_m`` of ``centre``, row by row in increasing
    x then y: two centres near each other share the points of their disks' overlap, in the
    same order. A radius too small to hold a point gives the lattice point nearest ``centre``."""
    centre = np.asarray(centre, float)
    lo = np.ceil((centre - radius_m) / spacing_m - 1e-9).astype(np.int64)
    hi = np.floor((centre + radius_m) / spacing_m + 1e-9).astype(np.int64)
    ix, iy = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    pts = np.column_stack([ix.ravel(), iy.ravel()]) * spacing_m
    pts = pts[np.hypot(*(pts - centre).T) <= radius_m + 1e-9]
    return pts if len(pts) else (np.round(centre / spacing_m) * spacing_m)[None]


def beam_of(scores: np.ndarray, *, size: int, within: float) -> np.ndarray:
    """The poses (indices into ``scores``, best first, the first of equals first) that go on
    from the cell stage: the ``size`` best, and of those only the ones scoring within
    ``within`` of the best (0: all ``size``). Why a gap: on generated homes no place that far
    behind after the cell stage went on to win (docs/umap.md, "A beam of the places that can
    still win"), and each pose costs the beam's square and climbs (64 renders)."""
    scores = np.asarray(scores, float)
    beam = np.argsort(-scores, kind="stable")[:max(1, int(size))]
    if within > 0 and len(beam):
        beam = beam[scores[beam] >= scores[beam[0]] - within]
    return beam


def final_starts(xy: np.ndarray, scores: np.ndarray, *, ties: float, apart_m: float) -> list[int]:
    """The poses of a beam (plan points ``xy`` (B, 2) scoring ``scores``) that the final
    search starts from (:func:`search_panoramas`): the best, then each other scoring within
    ``ties`` of it, best first, that lies more than ``apart_m`` from every one taken (a pose
    that near one taken is inside that one's search). Indices into the beam. ``ties`` 0: the
    best alone (the first of equals), as before the ties were searched. The poses within
    ``ties`` of the best, best first, are :func:`beam_of`'s."""
    out: list[int] = []
    for i in beam_of(scores, size=len(scores) if ties > 0 else 1, within=ties):
        if all(np.hypot(*(xy[i] - xy[t])) > apart_m for t in out):
            out.append(int(i))
    return out


def grid_step(xy: np.ndarray) -> float:
    """The spacing of a plan grid: the smallest gap between its distinct x or y values."""
    gaps = [np.diff(np.unique(np.round(xy[:, a], 6))) for a in (0, 1)]
    gaps = np.concatenate([g[g > 1e-6] for g in gaps]) if len(xy) > 1 else np.zeros(0)
    return float(gaps.min()) if len(gaps) else 0.25


@njit(parallel=True, cache=True, nogil=True)
def _chamfer_at_shifts(imgs: np.ndarray, m_close: np.ndarray, q_close: np.ndarray, q_rows: np.ndarray, q_cols: np.ndarray,
                       q_vals: np.ndarray, weights: np.ndarray, shifts: np.ndarray, out: np.ndarray,
                       chance_out: np.ndarray, with_levels: bool) -> None:
    """Recall and precision halves at the given shifts (out (L, S, 2)), and with
    ``with_levels`` each point's chance levels (chance_out (L, 4): area recall, area
    precision, yaw recall, yaw precision)."""
    h, w = imgs.shape[1], imgs.shape[2]
    wsum = 0.0
    for r in range(h):
        wsum += weights[r]
    q_row_mean = np.zeros(h)
    q_area = 0.0
    for r in range(h):
        acc = 0.0
        for c in range(w):
            acc += q_close[r, c]
        q_row_mean[r] = acc / w
        q_area += weights[r] * acc
    q_area /= w * wsum
    nq = 0.0
    for m in range(q_rows.shape[0]):
        nq += weights[q_rows[m]] * q_vals[m]
    for i in prange(imgs.shape[0]):
        m_row_mean = np.zeros(h)
        m_area = 0.0
        if with_levels:
            for r in range(h):
                acc = 0.0
                for c in range(w):
                    acc += m_close[i, r, c]
                m_row_mean[r] = acc / w
                m_area += weights[r] * acc
            m_area /= w * wsum
        n_map = 0.0
        yaw_r = 0.0
        rec = np.zeros(shifts.shape[1])
        for r in range(h):
            wr = weights[r]
            for c in range(w):
                if imgs[i, r, c]:
                    n_map += wr
                    yaw_r += wr * q_row_mean[r]
                    for s in range(shifts.shape[1]):
                        # db column c is query column c + k (shifts lie in 0..w-1: one wrap at most)
                        cc = c + shifts[i, s]
                        rec[s] += wr * q_close[r, cc - w if cc >= w else cc]
        yaw_p = 0.0
        pre = np.zeros(shifts.shape[1])
        for m in range(q_rows.shape[0]):
            r = q_rows[m]
            c = q_cols[m]
            wr = weights[r] * q_vals[m]
            yaw_p += wr * m_row_mean[r]
            for s in range(shifts.shape[1]):
                cc = c - shifts[i, s]
                pre[s] += wr * m_close[i, r, cc + w if cc < 0 else cc]
        for s in range(shifts.shape[1]):
            out[i, s, 0] = rec[s] / n_map if n_map > 0 else 0.0
            out[i, s, 1] = pre[s] / nq if nq > 0 else 0.0
        chance_out[i, 0] = q_area
        chance_out[i, 1] = m_area
        chance_out[i, 2] = yaw_r / n_map if n_map > 0 else 0.0
        chance_out[i, 3] = yaw_p / nq if nq > 0 else 0.0


def chamfer_at_shifts(imgs: np.ndarray, query: np.ndarray, shifts: np.ndarray, *, tau_px: float, weights: np.ndarray,
                      chance: str, query_close: np.ndarray | None = None,
                      precision_rows: np.ndarray | None = None, clutter_share: float = 0.5,
                      spread: int | None = None, recall_weight: float = 0.5) -> np.ndarray:
    """The chamfer score of :func:`chamfer_table` (same weights and chance correction) of one
    (H, W) query line image against (L, H, W) map line images, each only at its own column
    shifts ``shifts`` (L, S): (L, S) float64. What the local search needs: a few shifts
    around a candidate's heading, without the spectra's FFTs (equal to the table's entries:
    tested). A float ``query`` is a weighted line image, as for :func:`chamfer_table`.

    ``spread`` (the oriented score): ``imgs`` (L, B, H, W) and ``query`` (B, H, W) oriented
    channels, ``query_close`` (if given) its stacked :func:`oriented_closeness`: see
    :func:`oriented_at_shifts`."""
    if spread is not None:
        _check_oriented(chance)
        return oriented_at_shifts(channel_masks(imgs), query, shifts, tau_px=tau_px, weights=weights, spread=spread,
                                  query_close=query_close, precision_rows=precision_rows, recall_weight=recall_weight)
    imgs = np.ascontiguousarray(imgs, np.uint8)
    q_close = closeness(query, tau_px).astype(np.float32) if query_close is None else query_close
    rows, cols, vals = _query_pixels(query, precision_rows)
    shifts = np.ascontiguousarray(np.asarray(shifts, np.int64) % query.shape[1])
    halves = np.zeros((len(imgs), shifts.shape[1], 2))
    levels = np.zeros((len(imgs), 4))
    if len(imgs):
        m_close = closeness(imgs, tau_px)
        if chance == "likelihood":
            m_close = likelihood_image(m_close, weights, clutter_share)
            q_close = likelihood_image(q_close, weights, clutter_share)
        _chamfer_at_shifts(imgs, m_close, q_close, rows.astype(np.int64), cols.astype(np.int64), vals,
                           np.asarray(weights, np.float64), shifts, halves, levels, chance in ("area", "yaw"))
    recall, precision = halves[..., 0], halves[..., 1]
    if chance == "area":
        recall, precision = chance_corrected(recall, levels[:, 0:1]), chance_corrected(precision, levels[:, 1:2])
    elif chance == "yaw":
        recall, precision = chance_corrected(recall, levels[:, 2:3]), chance_corrected(precision, levels[:, 3:4])
    elif chance not in ("none", "likelihood"):
        raise ValueError(f"chance must be one of {', '.join(CHANCES)}, not {chance!r}")
    return halves_mixed(recall, precision, recall_weight)


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

# queries scored together: one matrix product per frequency serves the whole batch, and a
# wider one runs nearer BLAS's peak (one BLAS thread, 2,043 positions x 864 oriented rows:
# 14-16 ms a query in batches of 16, 10-12 in batches of 32, 9 in batches of 64); each
# query's column of the product is the same number whatever the batch (compared)
PANORAMA_BATCH = 32

# bytes of local renders :class:`RenderCache` keeps for a search (6,472 orientation bitmask
# images of 144 x 72): what the 32 bench panoramas' exact repeats need, not a whole home's
RENDER_CACHE_BYTES = 64 * 2**20


class RenderCache:
    """Renders of local plan points kept by their exact coordinates (their float64 bytes),
    newest kept, oldest dropped past ``max_bytes``: ``cache(pts)`` renders only the points
    not seen before, each once, and returns every point's render in order.

    Why: a point's render depends on the point alone (the map, height, heading 0 and image
    size are those of the search), and the local search renders the same points again:
    the cell stage's points around a grid position that is a candidate of several queries,
    and the beam's square where it covers points of the cell stage. On the 32 bench
    panoramas a fifth of the renders repeat a point bit for bit; a point equal to within
    rounding is rendered anew, so every score is the one rendered on the spot."""

    def __init__(self, render: Callable[[np.ndarray], np.ndarray], max_bytes: int = RENDER_CACHE_BYTES) -> None:
        self.render = render
        self.max_bytes = int(max_bytes)
        self.kept: OrderedDict[bytes, np.ndarray] = OrderedDict()   # oldest first
        self.bytes = 0
        self.rendered = 0
        self.reused = 0
        # queries searched on threads share the cache: the lock covers the look-up and the
        # keeping, not the render, so renders run side by side (two threads that miss the
        # same point both render it, to the same bits)
        self.lock = threading.Lock()

    def __call__(self, pts: np.ndarray) -> np.ndarray:
        pts = np.ascontiguousarray(pts, np.float64)
        keys = [row.tobytes() for row in pts]
        new: dict[bytes, int] = {}                   # a point not kept -> its row in the fresh renders
        first: list[int] = []                        # the fresh renders' points, by their first row in pts
        found: dict[bytes, np.ndarray] = {}          # the kept renders, taken now (another thread may drop them)
        with self.lock:
            for i, key in enumerate(keys):
                if key in new or key in found:
                    continue
                img = self.kept.get(key)
                if img is None:
                    new[key] = len(new)
                    first.append(i)
                else:
                    found[key] = img
        fresh = self.render(pts[first] if len(new) < len(keys) else pts)
        if len(new) == len(keys):                    # nothing kept: the fresh renders are the answer
            out = fresh
        else:
            out = np.empty((len(keys), *fresh.shape[1:]), fresh.dtype)
            for i, key in enumerate(keys):
                out[i] = fresh[new[key]] if key in new else found[key]
        with self.lock:
            self.rendered += len(new)
            self.reused += len(keys) - len(new)
            for key, row in new.items():
                if key in self.kept:                 # kept meanwhile by another thread: the same bits
                    continue
                img = fresh[row].copy()              # not a view that holds the whole batch
                self.kept[key] = img
                self.bytes += img.nbytes
            while self.bytes > self.max_bytes and self.kept:
                self.bytes -= self.kept.popitem(last=False)[1].nbytes
        return out


# queries searched at once by :func:`search_panoramas` (None: :func:`panorama_threads`
# decides; 1: one after another, each kernel on every usable core)
PANORAMA_THREADS: int | None = None


@njit(parallel=True, cache=True, nogil=True)
def _first_parallel(out: np.ndarray) -> None:
    """A parallel kernel that does nothing useful: calling it makes numba choose its
    threading layer, which :func:`panorama_threads` then reads."""
    for i in prange(out.shape[0]):
        out[i] = i


def panorama_threads(n: int) -> int:
    """Threads :func:`search_panoramas` searches ``n`` queries on, each query's local search
    on one thread with its kernels on one core: the usable cores (at most ``n``), or
    :data:`PANORAMA_THREADS` where set. Why: a step of the local search renders and scores a
    few dozen poses, too few to keep many cores busy in one kernel, and between its kernels
    each query runs Python; queries side by side keep the cores busy (the kernels release
    the GIL). 1 where numba's threading layer is ``workqueue``, which aborts the process
    when two threads call its kernels at once (``omp`` and ``tbb`` allow it)."""
    want = max(1, min(usable_cores() if PANORAMA_THREADS is None else int(PANORAMA_THREADS), n))
    if want == 1:
        return 1
    import numba

    _first_parallel(np.zeros(1))
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel has run: cannot tell
        return 1
    return want if layer in ("omp", "tbb") else 1


def _each_searched(batches: Iterable[list[tuple[int, np.ndarray, np.ndarray | None]]],
                   search_one: Callable[[int, np.ndarray, np.ndarray | None], None], threads: int) -> Iterator[int]:
    """``search_one`` on every query of each batch (query, table, tolerant table), a batch
    at a time: the next batch's tables are made on every core (BLAS's thread count is the
    process's) once this batch's searches have ended. Yields each query as its search ends.
    With ``threads`` > 1 the queries of a batch run on that many threads, numba's kernels on
    one thread in each (its thread count is a thread's own)."""
    if threads <= 1:
        for batch in batches:
            for item in batch:
                search_one(*item)
                yield item[0]
        return
    import numba

    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="placeloc-panoramas",
                            initializer=numba.set_num_threads, initargs=(1,)) as pool:
        for batch in batches:
            futures = {pool.submit(search_one, *item): item[0] for item in batch}
            try:
                for done in as_completed(futures):
                    done.result()
                    yield futures[done]
            finally:  # stopped (an error, Ctrl-C): the queries not begun are not begun
                for future in futures:
                    future.cancel()


def _query_side(lines: np.ndarray, pp: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, int | None]:
    """What every score of the queries ``lines`` takes (``pp``: the ``umap.panorama``
    parameters): the queries (line pixels weighted down inside dense texture for the chamfer
    score), the row weights, the precision half's rows (None: all) and the orientation
    spread (None: one bin)."""
    spread = int(pp.orientation_spread) if int(pp.orientation_bins) > 1 else None
    chamfer = pp.score == "chamfer"
    if spread is not None and not chamfer:
        raise ValueError("orientation_bins > 1 needs the chamfer score")
    h = lines.shape[-2]
    weights = row_weights(h, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
    queries = lines
    if chamfer and pp.texture_radius_px > 0:
        queries = (texture_weights(lines, pp.texture_radius_px) if spread is None
                   else lines * texture_weights(lines.max(axis=1), pp.texture_radius_px)[:, None])
    prows = precision_rows(h, pp.precision_polar_deg) if pp.precision_polar_deg < 90.0 else None
    return queries, weights, prows, spread


def _search_table(spectra: np.ndarray, queries: np.ndarray, weights: np.ndarray, prows: np.ndarray | None,
                  spread: int | None, pp: Any, seen: np.ndarray | None = None) -> np.ndarray:
    """The search's first step for a batch of queries (:func:`_query_side`'s): every grid
    position and yaw of ``spectra`` by the chamfer score with ``pp``'s settings
    (:func:`chamfer_table`), one home for both :func:`search_panoramas` and
    :func:`grid_table_best`, which must score alike."""
    return chamfer_table(spectra, queries, tau_px=pp.chamfer_tau_px, weights=weights, chance=pp.chamfer_chance,
                         precision_rows=prows, clutter_share=pp.clutter_share, spread=spread, seen=seen,
                         recall_weight=pp.recall_weight)


def grid_table_best(lines: np.ndarray, spectra: np.ndarray, pp: Any, seen: np.ndarray | None = None,
                    keep: np.ndarray | None = None) -> np.ndarray:
    """(N,) each query's best chamfer score over every grid position and yaw of ``spectra``
    (the search's first step, :func:`chamfer_table`, without the local search): how well a
    layer of the grid at one camera height explains each panorama, to choose the layers
    worth searching whole (``umap.panorama.height_layers``). ``keep`` (N, P) bool: each
    query's positions that count (its room, ``umap.room_hints``; -inf where none does)."""
    queries, weights, prows, spread = _query_side(lines, pp)
    out = np.full(len(lines), -np.inf)
    with threadpool_limits(limits=usable_cores(), user_api="blas"):
        for s in range(0, len(lines), PANORAMA_BATCH):
            table = _search_table(spectra, queries[s:s + PANORAMA_BATCH], weights, prows, spread, pp,
                                  None if seen is None else seen[s:s + PANORAMA_BATCH])
            if table.shape[1]:
                if keep is not None:
                    table = np.where(keep[s:s + PANORAMA_BATCH, :, None], table, -np.inf)
                out[s:s + len(table)] = table.reshape(len(table), -1).max(axis=1)
    return out


def search_panoramas(lines: np.ndarray, poses: np.ndarray, segments: np.ndarray, faces: np.ndarray,
                     database: dict[str, np.ndarray], pp: Any, *, tolerance_px: int, wall_margin_m: float, hidden: bool,
                     progress: Callable[[Iterable], Iterable] = lambda it: it,
                     seen: np.ndarray | None = None,
                     inside: Sequence[Callable[[np.ndarray], np.ndarray] | None] | None = None,
                     outside: np.ndarray | None = None) -> PanoramaAnswers:
    """Best (grid row, plan position, heading in degrees, score) of each (N, H, W) query line
    image, and the best score of a rival answer (:func:`rival_pose`, ``pp.margin_distance_m``
    and ``pp.margin_yaw_deg``; every pose the search scored competes): every grid position
    and yaw scored (``database``: ``spectra`` for the chamfer score, :func:`chamfer_spectra`;
    ``bits`` and ``counts`` for eq. (1)); then, with
    ``pp.refine_candidates``, a local search off the grid (``pp``: the ``umap.panorama``
    parameters):

    1. the cell stage: ``refine_candidates`` distinct grid positions (each at its best yaw;
       with the chamfer score and chance none the last ``coarse_candidates`` of them by a
       tolerant score, :func:`coarse_to_fine_candidates`, the rest the best by the exact
       one) each sample the 8 points a third of a grid step around them, so that every
       plan point of their cells lies within a sixth of a step (0.06 m diagonally at 0.25 m)
       of a sampled point: a peak 0.1 m wide between grid points is seen wherever the grid
       falls;
    2. with ``refine_climb``, every candidate first climbs that many times by its 8
       neighbours at a sixth of a grid step, so that a peak whose cell-stage point ranks
       low is reached before the beam is chosen;
    3. the ``refine_beam`` best poses so far (with ``refine_beam_within`` and the chamfer
       score, only those within that of the best: :func:`beam_of`) then move coarse to fine (:func:`refine_steps`:
       the 8 neighbours at each step, down to ``refine_step_m``); at the first step (a sixth
       of a grid step) each first samples the whole square of ``refine_square`` steps either
       side of it (:func:`square_offsets`; 3: the grid cell around it; chamfer score only),
       so that the peak is found where the score between the sampled points is too rugged
       to climb. With ``refine_top``, before that the cells of the best-ranked grid points
       that a pose of the beam kept out of the candidates are sampled as in the cell stage,
       and each that beats its pose joins the beam (:func:`suppressed_neighbours`).

    4. with ``refine_final_m`` (chamfer only), a :func:`pattern_search` from
       ``refine_final_start_m`` halving down to ``refine_final_m`` metres, so that the answer
       does not keep the grid's phase. With ``refine_final_radius_m`` it starts from the best
       point of the plan's own lattice of half the first step within that radius of the
       beam's best pose (:func:`lattice_disk`), and its end is the answer: the grid's origin
       then changes no answer whose beams end within the radius of each other. Without, it
       climbs from the beam's best pose (from the nearest point of the plan's lattice of the
       first step; ``refine_final_start_m`` 0: from the beam's finest step, where it is) and
       is kept where it scores higher. With ``refine_final_ties``, every pose of the beam
       scoring within that of its best (and further than the radius from one taken,
       :func:`final_starts`) gets the same search, and the best end is the answer: two places
       whose beam scores differ by less than the grid's phase moves them are compared on the
       plan's lattice. Where another place more than ``margin_distance_m`` away was finished
       too, the margin's score is the answer's finished one (finished against finished).

    Every local pose is rendered on the spot and scored the same way at the ``refine_yaw_cols``
    column shifts either side of its candidate's best heading so far (:func:`chamfer_at_shifts`);
    the best pose wins.

    With ``pp.orientation_bins`` B > 1 (the oriented score, chamfer only) ``lines`` are
    (N, B, H, W) oriented channels (:func:`orientation_channels`), ``database["spectra"]``
    built with the same bins and ``orientation_spread``, and the local poses are rendered
    with their directions.

    ``seen`` (N, H; :func:`seen_rows`; chamfer with chance ``none``): the rows each query's
    photo covered (photo spheres stored cropped): in every score of that query, the tables'
    and the local search's, the recall half counts the map's lines in those rows only (the
    local search weighs the other rows zero). None: every row.

    ``inside`` (``umap.room_hints``): each query's region, plan points (P, 2) -> (P,) bool, or
    None (anywhere): its grid table keeps the positions inside only (the rest score -inf, so
    they are never a candidate, an answer or a rival), and its local search stays inside.
    ``outside`` (N, 2), where given, receives each such query's best grid-table score outside
    its region and that position's grid row (-inf and -1 where none): whether the place the
    region kept out would have won by far (a wrong room named).

    After each batch's tables, its queries are searched side by side, one a thread
    (:func:`panorama_threads`), each to the same answer as alone."""
    bins = int(pp.orientation_bins)
    n, h, w = lines.shape[0], lines.shape[-2], lines.shape[-1]
    best, heading, score, rival = np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros(n), np.full(n, np.nan)
    rival_xy, rival_heading = np.full((n, 2), np.nan), np.full(n, np.nan)
    chamfer = pp.score == "chamfer"
    queries, weights, prows, spread = _query_side(lines, pp)

    # candidates by a tolerant score (coarse_candidates), only its ranks used; the plain
    # halves only (a chance-corrected tolerant score is not derived: every candidate exact)
    coarse = chamfer and pp.chamfer_chance == "none" and pp.coarse_candidates > 0 and pp.refine_candidates > 0

    # a photo sphere stored cropped: each score's recall half over the rows it saw
    # (None: every query saw every row)
    if seen is not None and (not chamfer or pp.chamfer_chance != "none" or bool(np.all(seen == 1.0))):
        seen = None

    def tolerant_tables(ks: np.ndarray) -> np.ndarray:
        return tolerant_chamfer_table(database["spectra"], queries[ks], recall_tau_px=pp.coarse_tau_px,
                                      blur_px=pp.coarse_blur_px, weights=weights, precision_rows=prows, spread=spread,
                                      bands=tolerant_bands(w, pp.coarse_tau_px), seen=None if seen is None else seen[ks],
                                      recall_weight=pp.recall_weight)

    def tables(ks: np.ndarray) -> np.ndarray:
        if chamfer:
            return _search_table(database["spectra"], queries[ks], weights, prows, spread, pp,
                                 None if seen is None else seen[ks])
        return np.stack([iou_yaw_scores(database["bits"], database["counts"], lines[k]) for k in ks])

    z = float(poses[0, 2]) if len(poses) else 0.0

    def render_local(pts: np.ndarray) -> np.ndarray:
        """Renders at plan points (height z, heading 0): orientation bitmasks (L, H, W) with
        the oriented score, else packed line images (L, n_words)."""
        local = np.column_stack([pts, np.full(len(pts), z), np.zeros(len(pts))])
        return render_panoramas(segments, faces, local, width=w, height=h, hidden=hidden,
                                orientation_bins=bins if spread is not None else 0)

    renders = RenderCache(render_local)
    regions = list(inside) if inside is not None else [None] * n   # each query's region (umap.room_hints), or None
    # the plan points the local search scored for the current query, each at its best shift:
    # the rivals off the grid. Per thread: a query's whole search runs on one thread
    # (:func:`panorama_threads`), so each thread's lists are its current query's (and so is
    # ``pixels``, its line elements for the oriented local score, oriented_query_pixels, made
    # at its first call)
    scored_here = threading.local()

    def local_scores(k: int, pts: np.ndarray, cols: np.ndarray, q_close: np.ndarray | None) -> np.ndarray:
        """(L, S) scores of query k at plan points pts (rendered on the spot, or kept from
        an earlier render of the same point) at shifts cols (L, S)."""
        # the rows the photo saw weigh the map's lines: only those count in the recall half
        wk = weights if seen is None else weights * seen[k]
        if spread is not None:
            if scored_here.pixels is None:   # the same for each of the query's few hundred calls
                scored_here.pixels = oriented_query_pixels(queries[k], prows)
            out = oriented_at_shifts(renders(pts), queries[k], cols, tau_px=pp.chamfer_tau_px, weights=wk,
                                     spread=spread, query_close=q_close, precision_rows=prows,
                                     recall_weight=pp.recall_weight, query_pixels=scored_here.pixels)
        elif chamfer:
            out = chamfer_at_shifts(unpack(renders(pts), h, w), queries[k], cols, tau_px=pp.chamfer_tau_px,
                                    weights=wk, chance=pp.chamfer_chance, query_close=q_close,
                                    precision_rows=prows, clutter_share=pp.clutter_share,
                                    recall_weight=pp.recall_weight)
        else:
            dil = pack(dilate_lines(unpack(renders(pts), h, w), tolerance_px))
            out = np.take_along_axis(iou_yaw_scores(dil, popcount_rows(dil), lines[k]), cols % w, axis=1)
        scored_here.xy.append(pts)
        scored_here.score.append(out.max(axis=1))
        scored_here.col.append(np.take_along_axis(cols, out.argmax(axis=1)[:, None], axis=1)[:, 0] % w)
        return out

    def keep_rival(k: int, table: np.ndarray, answer_xy: np.ndarray, answer_col: int) -> None:
        seen = (np.concatenate(scored_here.xy), np.concatenate(scored_here.score), np.concatenate(scored_here.col)) \
            if scored_here.xy else (np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64))
        r = rival_pose(table, poses[:, :2], *seen, answer_xy, answer_col, distance_m=pp.margin_distance_m,
                       yaw_cols=rival_cols)
        rival[k], rival_xy[k], rival_heading[k] = r.score, (r.x, r.y), (r.col * 360.0 / w if r.col >= 0 else np.nan)

    walls = blocking_faces(faces, float(poses[0, 2])) if len(poses) else faces
    cell = grid_step(poses[:, :2]) / 3.0 if len(poses) else 0.0
    steps = refine_steps(3.0 * cell, pp.refine_step_m)
    window = np.arange(-pp.refine_yaw_cols, pp.refine_yaw_cols + 1)
    square = square_offsets(pp.refine_square)
    refined_xy = np.full((n, 2), np.nan)
    before_final = np.full(n, np.nan)   # the best score before the final search (PanoramaAnswers.margin)
    final_start = pp.refine_final_start_m if pp.refine_final_start_m > 0 else steps[-1]   # the final search's first step
    rival_cols = pp.margin_yaw_deg * w / 360.0

    def batches() -> Iterable[list[tuple[int, np.ndarray, np.ndarray | None]]]:
        for s in range(0, n, PANORAMA_BATCH):
            ks = np.arange(s, min(n, s + PANORAMA_BATCH))
            # the tables are a few large products per batch: BLAS on every usable core (the
            # search below holds it to one thread). Each query's column of a product is the same
            # to the bit whatever the thread count (tested); on 16 cores the tables took 26 ms a
            # panorama of 75 on one thread (bench-umap on an H100 host)
            with threadpool_limits(limits=usable_cores(), user_api="blas"):
                batch = tables(ks), tolerant_tables(ks) if coarse else [None] * len(ks)
            yield [(int(k), t, c) for k, t, c in zip(ks, *batch)]

    def move(k: int, xy: np.ndarray, col: np.ndarray, sc: np.ndarray, step: float, floor_d: np.ndarray,
             q_close: np.ndarray | None, offsets: np.ndarray = NEIGHBOURS) -> None:
        """One step of the local search: each pose's neighbours (``offsets`` steps away, by
        default the 8 nearest) at ``step``, kept where better (in place)."""
        pts = (xy[:, None, :] + step * offsets[None]).reshape(-1, 2)
        owner = np.repeat(np.arange(len(xy)), len(offsets))
        if len(walls):  # not through a wall: as far from the walls as the grid keeps its positions
            ok = wall_distance(pts, walls) >= floor_d[owner]
            pts, owner = pts[ok], owner[ok]
        if regions[k] is not None:   # not out of the photo's room (umap.room_hints)
            ok = regions[k](pts)
            pts, owner = pts[ok], owner[ok]
        if not len(pts):
            return
        cols = col[owner][:, None] + window[None]
        sub = local_scores(k, pts, cols, q_close)
        top, arg = sub.max(axis=1), sub.argmax(axis=1)
        # each pose's best neighbour (the first of equals), where better than the pose: the
        # owners run in order, one block each
        starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
        block_top = np.maximum.reduceat(top, starts)
        block = np.cumsum(np.r_[False, owner[1:] != owner[:-1]])
        best_of = np.minimum.reduceat(np.where(top == block_top[block], np.arange(len(top)), len(top)), starts)
        better = block_top > sc[owner[starts]]
        j, i = owner[starts][better], best_of[better]
        xy[j], col[j], sc[j] = pts[i], cols[i, arg[i]] % w, top[i]

    def cell_stage(k: int, rows: np.ndarray, table: np.ndarray, q_close: np.ndarray | None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The cell stage of grid ``rows`` (each from its best shift in ``table``): each moved to
        the best of the 8 points a third of a grid step around it where better. Returns their
        (position, heading column, score, least distance to a wall), the candidates' and
        ``refine_top``'s alike."""
        xy = poses[rows, :2].copy()
        col = np.argmax(table[rows], axis=1).astype(np.int64)
        sc = table[rows].max(axis=1).astype(np.float64)
        floor_d = np.minimum(wall_margin_m, wall_distance(xy, walls)) if len(walls) else np.zeros(len(rows))
        move(k, xy, col, sc, cell, floor_d, q_close)
        return xy, col, sc, floor_d

    def final_scorer(k: int, floor: float, q_close: np.ndarray | None) -> Callable:
        """:func:`pattern_search`'s score: query k's scores at plan points (-inf nearer a wall
        than ``floor``) at the yaw window about a heading column, and the best column of each."""
        def score_at(pts: np.ndarray, col: int) -> tuple[np.ndarray, np.ndarray]:
            out, cols_out = np.full(len(pts), -np.inf), np.full(len(pts), col, dtype=np.int64)
            ok = wall_distance(pts, walls) >= floor if len(walls) else np.ones(len(pts), bool)
            if regions[k] is not None:
                ok &= regions[k](pts)
            if ok.any():
                cols = np.broadcast_to(col + window, (int(ok.sum()), len(window)))
                sub = local_scores(k, pts[ok], np.ascontiguousarray(cols), q_close)
                out[ok], cols_out[ok] = sub.max(axis=1), cols[0, sub.argmax(axis=1)] % w
            return out, cols_out
        return score_at

    def finish(k: int, xy0: np.ndarray, col0: int, sc0: float, floor: float, q_close: np.ndarray | None
               ) -> tuple[np.ndarray, float, int, bool]:
        """The final search (``refine_final_m``, chamfer only) of query k from a pose of its
        beam: its end (position, score, heading column) and whether the end is the answer
        whatever it scores (from the plan's lattice within ``refine_final_radius_m``), else
        it is kept only where it scores higher than the beam's pose."""
        scorer = final_scorer(k, floor, q_close)
        finest = min(pp.refine_final_m, final_start)
        if pp.refine_final_start_m > 0 and pp.refine_final_radius_m > 0:
            # from the best point of the plan's own lattice (not the grid's) of half the first
            # step within the radius: two grid origins whose beams end on neighbouring bumps of
            # the score, within the radius of each other, score the same points and start from
            # the same one. Half the first step (0.04 m): a peak 0.1 m wide has a point within
            # 0.03 m of its top (at 0.08 m one was missed, docs/umap.md). Its end is the answer
            # even where the beam's own pose scored higher (by a median 0.001 on generated
            # homes): that pose keeps the grid's phase
            disk = lattice_disk(xy0, final_start / 2.0, pp.refine_final_radius_m)
            s, c = scorer(disk, col0)
            i0 = int(np.argmax(s))
            if np.isfinite(s[i0]):
                fx, fs, fc = pattern_search(scorer, disk[i0], float(s[i0]), int(c[i0]), start_m=final_start,
                                            finest_m=finest)
                return fx, fs, fc, True
            return xy0, sc0, col0, False
        x0, s0, c0 = xy0, sc0, col0
        if pp.refine_final_start_m > 0:
            # from the nearest point of the plan's own lattice of the first step
            x0 = np.round(xy0 / final_start) * final_start
            s, c = scorer(x0[None], c0)
            s0, c0 = float(s[0]), int(c[0])
        fx, fs, fc = pattern_search(scorer, x0, s0, c0, start_m=final_start, finest_m=finest)
        return (fx, fs, fc, False) if fs > sc0 else (xy0, sc0, col0, False)              # kept where higher

    def search_one(k: int, table: np.ndarray, tolerant: np.ndarray | None) -> None:
        """Query k's answer from its table (and tolerant table): the candidates, the local
        search and the final search, written into ``best``, ``heading``, ``score``, ... at k.
        Reads nothing another query writes, so queries may run on threads of their own."""
        if regions[k] is not None:   # the grid positions outside its region never compete
            keep = regions[k](poses[:, :2])[:, None]
            if outside is not None:
                away = np.where(keep[:, 0], -np.inf, table.max(axis=1))
                if len(away) and np.isfinite(away.max()):
                    outside[k] = away.max(), float(np.argmax(away))
            table = np.where(keep, table, -np.inf)
            tolerant = None if tolerant is None else np.where(keep, tolerant, -np.inf)
        best[k], shift, score[k] = best_pose(table)
        heading[k] = shift * 360.0 / w
        scored_here.xy, scored_here.score, scored_here.col, scored_here.pixels = [], [], [], None
        answer_xy, answer_col = poses[best[k], :2], shift
        if pp.refine_candidates <= 0:
            cands = np.zeros(0, np.int64)
        elif tolerant is not None:
            cands = coarse_to_fine_candidates(table, tolerant, poses[:, :2], count=pp.refine_candidates,
                                              coarse=pp.coarse_candidates, min_separation_m=pp.refine_separation_m)
        else:
            cands = distinct_candidates(table, poses[:, :2], count=pp.refine_candidates,
                                        min_separation_m=pp.refine_separation_m)
        if not len(cands):
            keep_rival(int(k), table, answer_xy, answer_col)
            return
        q_close = None
        if chamfer:
            q_close = (closeness(queries[k], pp.chamfer_tau_px).astype(np.float32) if spread is None else
                       stack_channels(oriented_closeness(queries[k], pp.chamfer_tau_px, spread)).astype(np.float32))
        rows = cands
        xy, col, sc, floor_d = cell_stage(int(k), rows, table, q_close)
        for _ in range(pp.refine_climb):                                        # every candidate climbs
            move(int(k), xy, col, sc, steps[0], floor_d, q_close)
        # the gap was measured on the chamfer score; the IoU score's differences are smaller
        beam = beam_of(sc, size=pp.refine_beam, within=pp.refine_beam_within if chamfer else 0.0)
        rows, xy, col, sc, floor_d = rows[beam], xy[beam], col[beam], sc[beam], floor_d[beam]
        # refine_top: the cells of the best-ranked grid points that a pose of the beam kept
        # out of the candidates, searched after the beam is chosen (so that the choice among
        # places is the candidates' own); each that beats the pose joins the beam beside it
        # (not in its place: a better start need not climb higher on a rugged score)
        extra, owner = suppressed_neighbours(table, poses[:, :2], cands, top=pp.refine_top,
                                             min_separation_m=pp.refine_separation_m)
        slot = np.full(len(cands), -1)
        slot[beam] = np.arange(len(beam))
        extra, owner = extra[slot[owner] >= 0], slot[owner[slot[owner] >= 0]]
        if len(extra):
            e_xy, e_col, e_sc, e_floor = cell_stage(int(k), extra, table, q_close)
            up = e_sc > sc[owner]
            rows, xy, col = np.r_[rows, extra[up]], np.r_[xy, e_xy[up]], np.r_[col, e_col[up]]
            sc, floor_d = np.r_[sc, e_sc[up]], np.r_[floor_d, e_floor[up]]
        for i, step in enumerate(steps):                                        # coarse to fine
            # the beam's cells, densely (chamfer only: the IoU of dilated lines is flat over a
            # few centimetres, and a dense square finds its spurious maxima: 5 degrees off on
            # the end-to-end test)
            if i == 0 and chamfer and pp.refine_square > 1:
                move(int(k), xy, col, sc, step, floor_d, q_close, square)
            move(int(k), xy, col, sc, step, floor_d, q_close)
        j = int(np.argmax(sc))
        # the margin's score: the beam's best (at least the grid's best), taken before the final
        # search polishes the answer alone; no rival gets that polish (but see the ties below)
        before_final[k] = max(score[k], float(sc[j]))
        final = False                                                         # the final search's end taken
        if chamfer and pp.refine_final_m > 0:                                 # the winner, in metres
            # every pose of the beam near the best (refine_final_ties) is finished before they are
            # compared: two places whose beam scores differ by less than the grid's phase moves
            # them are then compared on the plan's own lattice, where the grid's origin does not reach
            starts = final_starts(xy, sc, ties=pp.refine_final_ties,
                                  apart_m=max(pp.refine_final_radius_m, final_start))
            ends = [finish(int(k), xy[i], int(col[i]), float(sc[i]), float(floor_d[i]), q_close) for i in starts]
            e = max(range(len(ends)), key=lambda i: ends[i][1])                # the first of equals
            j = starts[e]
            if any(np.hypot(*(ends[i][0] - ends[e][0])) > pp.margin_distance_m for i in range(len(ends))):
                # another place was finished too, and is a rival: the margin compares finished
                # with finished (a twin room's same spot: 0, as before the final search)
                before_final[k] = ends[e][1]
            xy[j], sc[j], col[j], final = ends[e]
        if final or sc[j] > score[k]:
            # the grid row stays that of the candidate; the position is the refined one
            best[k], heading[k], score[k] = rows[j], col[j] * 360.0 / w, sc[j]
            refined_xy[k] = xy[j]
            answer_xy, answer_col = xy[j], int(col[j])
        keep_rival(int(k), table, answer_xy, answer_col)

    # the queries side by side, one a thread (panorama_threads); the same answers to the bit
    threads = panorama_threads(n)
    # one BLAS thread: the products are many and small, and waiting BLAS threads spin (on two
    # shared cores they cost 3-5x the CPU time of the search; bench-umap)
    limiter = threadpool_limits(limits=1, user_api="blas")
    try:
        for _ in progress(_each_searched(batches(), search_one, threads)):
            pass
    finally:
        limiter.restore_original_limits()
    est = poses[best, :2].copy()
    ok = ~np.isnan(refined_xy[:, 0])
    est[ok] = refined_xy[ok]
    return PanoramaAnswers(best, est, heading, score, rival, rival_xy, rival_heading,
                           np.where(np.isnan(before_final), score, before_final))


def search_near(lines: np.ndarray, point: np.ndarray, model: Any, pp: Any, *, radius_m: float, step_m: float,
                z: float | None, tolerance_px: int, wall_margin_m: float, hidden: bool,
                seen: np.ndarray | None = None) -> PanoramaAnswers:
    """The search of :func:`search_panoramas` for (N, ...) query line images over a grid of
    ``step_m`` within ``radius_m`` of the plan ``point`` only (free space of ``model``, at
    camera height ``z``; None: the model's), its database drawn on the spot: what the method
    finds near a place, and its score. The diagnostic that tells a score failure from a
    search failure: where the best pose near the truth scores below a wrong answer, the
    score prefers the wrong place (no search fixes that); where above, the search missed it.
    Raises ValueError where no grid position lies within the radius, or where the camera
    height is not given (no ``z``, no ``camera_z`` in the model) or lies outside the storey.
    ``seen``: the rows each query's photo covered, as :func:`search_panoramas` takes them."""
    from placeloc.geometry import pose_grid
    from placeloc.geometry.floorplan import free_space_mask

    point = np.asarray(point, float).reshape(2)
    r = float(radius_m)
    name = model.source or "the model"
    if z is None:
        if model.camera_z is None:
            raise ValueError(f"{name} gives no camera height (camera_z): pass z, the camera's height in metres")
        z = float(model.camera_z)
    if len(model.faces) and not float(model.faces[:, 4].min()) < z < float(model.faces[:, 5].max()):
        raise ValueError(f"camera height {z} m lies outside the storey of {name} (floor {model.faces[:, 4].min()} m, "
                         f"ceiling {model.faces[:, 5].max()} m)")
    # the grid keeps the model's free space as the localize grid does (plan_grid's test)
    poses = pose_grid([point[0] - r, point[0] + r, step_m], [point[1] - r, point[1] + r, step_m], z, [0.0])
    keep = free_space_mask(poses[:, :2], model, inside_only=True, wall_margin_m=wall_margin_m, z=z)[0]
    poses = poses[keep & (np.hypot(*(poses[:, :2] - point).T) <= r + 1e-9)]
    if not len(poses):
        raise ValueError(f"no free grid position of {name} within {r:g} m of ({point[0]:.2f}, {point[1]:.2f}) at "
                         f"{step_m:g} m")
    if pp.score != "chamfer":
        raise ValueError("search_near scores with the chamfer score only (umap.panorama.score chamfer)")
    h, w = lines.shape[-2:]
    # the map side as the index stage makes it (map_side)
    spectra = chamfer_spectra(map_images(model.segments, model.faces, poses, width=w, height=h,
                                         bins=int(pp.orientation_bins), hidden=hidden), **map_side(pp, h))
    return search_panoramas(lines, poses, model.segments, model.faces, {"spectra": spectra}, pp,
                            tolerance_px=tolerance_px, wall_margin_m=wall_margin_m, hidden=hidden, seen=seen)
