"""Bit-packed binary images and the AND + popcount score of eq. (1).

Layout: an H x W binary image is flattened row-major and packed 64 pixels per uint64
word, pixel p in word p >> 6, bit p & 63 (little-endian bit order, as
``np.packbits(bitorder="little")`` then viewed as ``<u8``). The last word is zero-padded.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from placeloc.geometry.bitimage import POOL_PX, n_words


def pack(images: np.ndarray) -> np.ndarray:
    """(..., H, W) binary images -> (..., n_words) uint64."""
    images = np.asarray(images)
    lead = images.shape[:-2]
    h, w = images.shape[-2:]
    flat = (images.reshape(-1, h * w) != 0)
    nw = n_words(h, w)
    padded = np.zeros((flat.shape[0], nw * 64), dtype=bool)
    padded[:, : h * w] = flat
    words = np.packbits(padded, axis=1, bitorder="little").view("<u8")
    return words.reshape(*lead, nw)


def unpack(words: np.ndarray, height: int, width: int) -> np.ndarray:
    """(..., n_words) uint64 -> (..., H, W) uint8 in {0, 1}."""
    words = np.ascontiguousarray(words, dtype="<u8")
    lead = words.shape[:-1]
    bits = np.unpackbits(words.reshape(-1, words.shape[-1]).view(np.uint8), axis=1, bitorder="little")
    return bits[:, : height * width].reshape(*lead, height, width)


# below this many rows a single thread scores them (starting the thread pool costs more)
SERIAL_ROWS = 2048


@njit(inline="always")
def _popcount64(x: np.uint64) -> np.uint64:
    # SWAR popcount; LLVM turns this idiom into a single POPCNT where the CPU has one.
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (x * np.uint64(0x0101010101010101)) >> np.uint64(56)


@njit(parallel=True, cache=True)
def _and_count_rows(db: np.ndarray, q: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    # Contiguous inner loop over a row's words: LLVM vectorizes AND + popcount.
    for r in prange(rows.shape[0]):
        i = rows[r]
        s = np.uint64(0)
        for j in range(q.shape[0]):
            s += _popcount64(db[i, j] & q[j])
        out[r] = s


@njit(cache=True)
def _and_count_rows_serial(db: np.ndarray, q: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    # few rows: one thread, no wait for the pool's threads to be scheduled
    for r in range(rows.shape[0]):
        i = rows[r]
        s = np.uint64(0)
        for j in range(q.shape[0]):
            s += _popcount64(db[i, j] & q[j])
        out[r] = s


@njit(parallel=True, cache=True)
def _and_count_all(db: np.ndarray, q: np.ndarray, out: np.ndarray) -> None:
    for i in prange(db.shape[0]):
        s = np.uint64(0)
        for j in range(q.shape[0]):
            s += _popcount64(db[i, j] & q[j])
        out[i] = s


@njit(parallel=True, cache=True)
def popcount_rows(db: np.ndarray) -> np.ndarray:
    out = np.zeros(db.shape[0], dtype=np.int64)
    for i in prange(db.shape[0]):
        s = np.uint64(0)
        for j in range(db.shape[1]):
            s += _popcount64(db[i, j])
        out[i] = s
    return out


def and_count(db: np.ndarray, query: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """A(DB_i AND SEN) for every row i of ``db`` (or only ``rows``): int64 counts."""
    q = np.ascontiguousarray(query, dtype=np.uint64)
    if db.shape[1] != q.shape[0]:
        raise ValueError(f"query has {q.shape[0]} words but the database {db.shape[1]}: the line images differ in size")
    if rows is None:
        out = np.zeros(db.shape[0], dtype=np.int64)
        _and_count_all(db, q, out)
        return out
    rows = np.asarray(rows, dtype=np.int64)
    out = np.zeros(rows.shape[0], dtype=np.int64)
    if rows.size > SERIAL_ROWS:
        _and_count_rows(db, q, rows, out)
    elif rows.size:
        _and_count_rows_serial(db, q, rows, out)
    return out


def iou_scores(db: np.ndarray, db_counts: np.ndarray, query: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """Eq. (1) of the paper, read as intersection over union (the printed formula
    ``A(LC)/A(DB_i) + A(SEN) - A(LC)`` has lost its parentheses):

        M_i = A(LC) / (A(DB_i) + A(SEN) - A(LC)),  LC = DB_i AND SEN,

    A() the number of non-zero pixels. Returns float64 scores in [0, 1] (0 for an empty union).
    """
    lc = and_count(db, query, rows).astype(np.float64)
    a_db = np.asarray(db_counts if rows is None else db_counts[rows], dtype=np.float64)
    a_sen = float(np.bitwise_count(np.ascontiguousarray(query, dtype=np.uint64)).sum())
    union = a_db + a_sen - lc
    return np.divide(lc, union, out=np.zeros_like(lc), where=union > 0)


def iou_naive(db_images: np.ndarray, query_image: np.ndarray) -> np.ndarray:
    """The naive per-view loop over unpacked images (reference and benchmark baseline)."""
    q = query_image != 0
    a_sen = np.count_nonzero(q)
    out = np.zeros(len(db_images))
    for i, img in enumerate(db_images):
        d = img != 0
        lc = np.count_nonzero(d & q)
        union = np.count_nonzero(d) + a_sen - lc
        out[i] = lc / union if union else 0.0
    return out


# ------------------------------------------------------------------ exact pruning of the search



def pool_or(words: np.ndarray, height: int, width: int, cell: int = POOL_PX) -> np.ndarray:
    """Packed line images (V, n_words) -> packed cell images: a cell (``cell`` x ``cell``
    pixels, the last row/column of cells padded) is on when any of its pixels is."""
    imgs = unpack(words, height, width)
    ch, cw = -(-height // cell), -(-width // cell)
    pad = np.zeros((imgs.shape[0], ch * cell, cw * cell), np.uint8)
    pad[:, :height, :width] = imgs
    return pack(pad.reshape(-1, ch, cell, cw, cell).max(axis=(2, 4)))


def query_planes(query: np.ndarray, height: int, width: int, cell: int = POOL_PX) -> np.ndarray:
    """Bit planes of the query's line pixel count per cell: row k holds bit k of each cell's
    count, packed like :func:`pool_or`'s cells."""
    img = unpack(np.ascontiguousarray(query, dtype=np.uint64)[None], height, width)[0]
    ch, cw = -(-height // cell), -(-width // cell)
    pad = np.zeros((ch * cell, cw * cell), np.int64)
    pad[:height, :width] = img
    cnt = pad.reshape(ch, cell, cw, cell).sum(axis=(1, 3))
    n_planes = max(int(cnt.max()).bit_length(), 1)
    return pack(np.stack([(cnt >> k) & 1 for k in range(n_planes)]))


@njit(parallel=True, cache=True)
def _bound_counts(pooled: np.ndarray, planes: np.ndarray, out: np.ndarray) -> None:
    for i in prange(pooled.shape[0]):
        s = np.uint64(0)
        for k in range(planes.shape[0]):
            c = np.uint64(0)
            for j in range(planes.shape[1]):
                c += _popcount64(pooled[i, j] & planes[k, j])
            s += c << np.uint64(k)
        out[i] = s


def best_iou(db: np.ndarray, db_counts: np.ndarray, pooled: np.ndarray, query: np.ndarray, height: int, width: int,
             rows: np.ndarray | None = None) -> tuple[int, float]:
    """(row, score) of the best eq. (1) score among ``rows`` (None: all), exactly as
    ``argmax(iou_scores(...))`` would give, reading only the views that can win.

    A(DB_i AND SEN) is at most the number of query line pixels in cells where ``pooled``
    (:func:`pool_or` of ``db``) is on, so eq. (1) is at most B / (A(DB_i) + A(SEN) - B) with
    that count B; views whose bound is below a score already reached are not read."""
    rows = np.arange(db.shape[0]) if rows is None else np.asarray(rows, dtype=np.int64)
    if rows.size == 0:
        return -1, -1.0
    planes = query_planes(query, height, width)
    ub = np.zeros(db.shape[0], dtype=np.int64)
    _bound_counts(pooled, planes, ub)
    a_sen = float(np.bitwise_count(np.ascontiguousarray(query, dtype=np.uint64)).sum())
    b = ub[rows].astype(np.float64)
    den = db_counts[rows] + a_sen - b
    bound = np.divide(b, den, out=np.zeros_like(b), where=den > 0)
    # score the most promising views first, then every view whose bound reaches the best score
    # so far (a second, wider round first when the first left too many)
    best = -1.0
    for k in (256, 8192):
        live = rows if best < 0 else rows[bound >= best]
        if best >= 0 and live.size <= k:
            break
        lb = bound if best < 0 else bound[bound >= best]
        top = live[np.argpartition(-lb, k - 1)[:k]] if live.size > k else live
        best = max(best, float(iou_scores(db, db_counts, query, top).max()))
    cand = rows[bound >= best]
    sc = iou_scores(db, db_counts, query, cand)
    k = int(np.argmax(sc))
    return int(cand[k]), float(sc[k])
