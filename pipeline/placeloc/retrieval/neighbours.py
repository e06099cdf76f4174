"""Nearest neighbours of query rows among reference rows: plain arrays in and out."""

from __future__ import annotations

import numpy as np


def thumbnail_row(gray: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A grey image as one row: an area-averaged thumbnail of ``size`` (width, height),
    brightness and contrast removed (zero mean, unit length), so cosine similarity between
    two rows is their normalised cross-correlation."""
    import cv2

    t = cv2.resize(gray, (int(size[0]), int(size[1])), interpolation=cv2.INTER_AREA).astype(np.float32).ravel()
    t -= t.mean()
    n = float(np.linalg.norm(t))
    return t / n if n > 0 else t


def thumbnail_arrays(image: np.ndarray, *, size: tuple[int, int]) -> dict[str, np.ndarray]:
    """The engine's per-image function (:mod:`placeloc.core.imagework`): one grey image ->
    its ``features`` row (:func:`thumbnail_row`)."""
    return {"features": thumbnail_row(image, size)}


def prepare(rows: np.ndarray, distance: str) -> np.ndarray:
    """Rows as the distance works on them: unit length for cosine."""
    rows = np.ascontiguousarray(rows, np.float32)
    if distance == "cosine":
        n = np.linalg.norm(rows, axis=1, keepdims=True)
        rows = rows / np.where(n > 0, n, 1)
    return rows


def nearest(reference: np.ndarray, query: np.ndarray, *, k: int, distance: str, use_faiss: bool = False,
            block_size: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nearest reference rows of every query row, best first: (indices (Q, k),
    scores (Q, k)); scores are cosine similarities (higher = nearer) or Euclidean
    distances (lower = nearer). Rows must be :func:`prepare`-d. Fewer than ``k`` references:
    the missing columns are -1 / NaN."""
    ref, qry = prepare(reference, distance), prepare(query, distance)
    kk = min(int(k), len(ref))
    if use_faiss:
        from placeloc.core.faiss_loader import import_faiss

        faiss = import_faiss()
        index = faiss.IndexFlatIP(ref.shape[1]) if distance == "cosine" else faiss.IndexFlatL2(ref.shape[1])
        index.add(ref)
        score, idx = index.search(qry, kk)
        idx = idx.astype(np.int64)
        if distance == "l2":
            score = np.sqrt(np.maximum(score, 0))
    else:
        idx = np.zeros((len(qry), kk), np.int64)
        score = np.zeros((len(qry), kk), np.float32)
        ref_sq = (ref * ref).sum(1)
        for b0 in range(0, len(qry), block_size):
            q = qry[b0:b0 + block_size]
            sim = q @ ref.T
            # cosine: larger similarity is nearer; l2: smaller squared distance |r|^2 - 2 q.r (+ |q|^2)
            key = -sim if distance == "cosine" else ref_sq[None, :] - 2.0 * sim
            part = np.argpartition(key, kk - 1, axis=1)[:, :kk] if kk < len(ref) else np.tile(np.arange(len(ref)), (len(q), 1))
            order = np.argsort(np.take_along_axis(key, part, axis=1), axis=1, kind="stable")
            idx[b0:b0 + len(q)] = np.take_along_axis(part, order, axis=1)
            best = np.take_along_axis(sim, idx[b0:b0 + len(q)], axis=1)
            if distance == "l2":
                best = np.sqrt(np.maximum(ref_sq[idx[b0:b0 + len(q)]] - 2.0 * best + (q * q).sum(1)[:, None], 0))
            score[b0:b0 + len(q)] = best
    pad = int(k) - kk
    if pad > 0:
        idx = np.pad(idx, ((0, 0), (0, pad)), constant_values=-1)
        score = np.pad(score.astype(np.float32), ((0, 0), (0, pad)), constant_values=np.nan)
    return idx, score.astype(np.float32)


def nearest_earlier(rows: np.ndarray, *, exclude_recent: int, distance: str,
                    block_size: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """Loop closure within one sequence: for every row i its nearest row j with
    ``j <= i - exclude_recent`` (and never i itself): (indices (N,), scores (N,)), scores as
    :func:`nearest` gives them; -1 / NaN where no row lies that far back. Rows must be
    :func:`prepare`-d. Exact, in blocks of ``block_size`` rows: memory block_size x N."""
    rows = prepare(rows, distance)
    n = len(rows)
    gap = max(int(exclude_recent), 1)
    idx = np.full(n, -1, np.int64)
    score = np.full(n, np.nan, np.float32)
    sq = (rows * rows).sum(1)
    for b0 in range(gap, n, block_size):  # rows before ``gap`` have nothing far enough back
        b1 = min(b0 + block_size, n)
        q = rows[b0:b1]
        earlier = rows[: b1 - gap]
        sim = q @ earlier.T
        key = -sim if distance == "cosine" else sq[None, : b1 - gap] - 2.0 * sim
        # row i may use columns 0 .. i - gap only
        allowed = np.arange(b1 - gap)[None, :] <= (np.arange(b0, b1) - gap)[:, None]
        key = np.where(allowed, key, np.inf)
        best = np.argmin(key, axis=1)
        idx[b0:b1] = best
        s = sim[np.arange(len(q)), best]
        if distance == "l2":
            s = np.sqrt(np.maximum(sq[best] - 2.0 * s + sq[b0:b1], 0))
        score[b0:b1] = s
    return idx, score
