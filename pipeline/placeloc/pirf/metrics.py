"""PIRF-nav2 figures of merit, plain arrays in and out.

- :func:`set_agreement`: Jaccard, precision and recall of approximate node vectors against
  exact ones (the paper's Table 3 compares m_ANN with m_BF this way);
- :func:`loop_closure_correct`: a loop closure is correct when the two frames stand within
  ``radius`` metres (the paper: :data:`PAPER_RADIUS_M`); :func:`loop_closure_correct_in_truth`
  the same judged by a loop-closure matrix (or CSV) as the ``loops`` contract reads it;
- :func:`accuracy_at_gap`: localization accuracy with a gap tolerance in nodes (Figs. 6-7).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from placeloc.evaluation.metrics import tail_count, tail_mean  # noqa: F401  (re-exported: PIRF reads them here)

# Sasaki and Hamagami count a loop closure correct when the matched node lies within 1 m of
# where the camera stands (sec. 5.1.3). Runs take their radius from ground_truth.radius;
# the experiments and the omni presets (configs/pirf*.yaml) set it to this.
PAPER_RADIUS_M = 1.0


def set_agreement(ptr_a: np.ndarray, wa: np.ndarray, ptr_b: np.ndarray, wb: np.ndarray) -> dict[str, float]:
    """Jaccard, precision, recall of vectors a (approximate) against b (exact), pooled over frames.

    Both are CSR-style: frame t's sorted, unique word ids are ``wa[ptr_a[t]:ptr_a[t + 1]]``.
    """
    inter = union = na = nb = 0
    for t in range(len(ptr_a) - 1):
        a = wa[ptr_a[t]:ptr_a[t + 1]]
        b = wb[ptr_b[t]:ptr_b[t + 1]]
        k = len(np.intersect1d(a, b, assume_unique=True))
        inter += k
        union += len(a) + len(b) - k
        na += len(a)
        nb += len(b)
    return {"jaccard": inter / union if union else float("nan"), "precision": inter / na if na else float("nan"),
            "recall": inter / nb if nb else float("nan")}


def loop_closure_correct(xy: np.ndarray, frames: np.ndarray, nodes: np.ndarray, radius: float) -> np.ndarray:
    """Per loop closure (frame t matched to node c): whether t and c stand within ``radius``."""
    if len(frames) == 0:
        return np.zeros(0, bool)
    return np.linalg.norm(xy[frames, :2] - xy[nodes, :2], axis=1) <= radius


def loop_closure_correct_in_truth(truth: Any, frames: np.ndarray, matches: np.ndarray, tolerance: int) -> np.ndarray:
    """Per loop closure (frame i matched to frame j, original indices): whether the truth
    matrix (scipy CSR, row i = the earlier frames that close a loop with i) has a one in
    row i within ``tolerance`` frames of j. What ``ground_truth.kind: matrix`` or ``csv``
    judges with; positions judge with :func:`loop_closure_correct`."""
    out = np.zeros(len(frames), bool)
    for k, (i, j) in enumerate(zip(np.asarray(frames).tolist(), np.asarray(matches).tolist())):
        row = truth.indices[truth.indptr[i]:truth.indptr[i + 1]]
        out[k] = bool(len(row)) and bool((np.abs(row - j) <= tolerance).any())
    return out


def nearest_true_earlier(truth: Any, frames: np.ndarray, matches: np.ndarray) -> np.ndarray:
    """Per loop closure: the true earlier frame (original index) nearest its match, -1 when
    the truth has none for that frame."""
    out = np.full(len(frames), -1, np.int64)
    for k, (i, j) in enumerate(zip(np.asarray(frames).tolist(), np.asarray(matches).tolist())):
        row = truth.indices[truth.indptr[i]:truth.indptr[i + 1]]
        if len(row):
            out[k] = int(row[np.argmin(np.abs(row - j))])
    return out


def accuracy_at_gap(best: np.ndarray, q_xy: np.ndarray, r_xy: np.ndarray, radius: float, gap: int) -> float:
    """Fraction of query frames whose matched node lies within ``gap`` nodes of a reference
    node that is within ``radius`` metres of the query's true position. Frames with no match count as wrong."""
    ok = 0
    for t, c in enumerate(best):
        if c < 0:
            continue
        near = np.linalg.norm(r_xy[:, :2] - q_xy[t, :2], axis=1) <= radius
        lo, hi = max(0, c - gap), min(len(r_xy), c + gap + 1)
        ok += bool(near[lo:hi].any())
    return ok / len(best) if len(best) else float("nan")


def nearest_earlier(xy: np.ndarray, frames: np.ndarray, eps: int) -> np.ndarray:
    """For each frame t, the earlier frame j < t - eps that stands nearest to it (-1: none):
    where a loop closure at t should have matched."""
    out = np.full(len(frames), -1, np.int64)
    for k, t in enumerate(frames):
        if t - eps > 0:
            out[k] = int(np.argmin(np.linalg.norm(xy[: t - eps, :2] - xy[t, :2], axis=1)))
    return out
