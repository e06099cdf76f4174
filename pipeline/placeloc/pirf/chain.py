"""PIRF extraction (sec. 3.1): ratio-test matches chained back through an adaptive window.

``ratio_match(a, b)`` gives, for every row of ``a``, the index of its ratio-test match in
``b`` (or -1). A feature of frame t is a PIRF for window w when its match chain
t -> t-1 -> ... -> t-w is unbroken. The window adapts per frame, eq. (2): start at
``w_default``; while |P_t| < n_pmin decrement (down to 1); while |P_t| > n_pmax increment
(up to the history available). Choices where the paper is silent:

- The PIRF descriptor is the mean of the chained descriptors (the original PIRF papers
  average along the track; it damps per-frame noise).
- Frame 0 has no history, so P_0 is empty; frame t < w uses the window min(w, t).
- If even the largest window leaves more than n_pmax, the n_pmax strongest (detector
  response) are kept, so eq. (2)'s upper bound always holds; the lower bound cannot be
  forced (a blank frame has no PIRFs) and is left unmet when w = 1 still gives too few.
"""

from __future__ import annotations

import numpy as np

from placeloc.pirf.knn import bf_knn2
from placeloc.pirf.mapping import ratio_ok


def ratio_match(a: np.ndarray, b: np.ndarray, ratio: float) -> np.ndarray:
    """Lowe's ratio test, eq. (1): index into b of each row of a's match, -1 if none.

    Distances are squared, so the test is d1^2 < ratio^2 d2^2. With fewer than two
    candidates the test is undefined and nothing matches.
    """
    out = np.full(len(a), -1, np.int64)
    if len(a) == 0 or len(b) < 2:
        return out
    d2, idx = bf_knn2(a, b)
    ok = ratio_ok(d2, idx, ratio)
    out[ok] = idx[ok, 0]
    return out


def chain_lengths(matches: list[np.ndarray], max_w: int) -> tuple[np.ndarray, np.ndarray]:
    """Follow the newest frame's match chain back up to ``max_w`` steps.

    ``matches[-1]`` maps frame t's features into frame t-1, ``matches[-2]`` t-1 into t-2,
    and so on. Returns (length, trail): length[i] = unbroken steps from feature i (capped
    at max_w), trail[k, i] = its index in frame t-k (k = 0..max_w; -1 once broken).
    """
    cur = np.arange(len(matches[-1]))
    trail = np.full((max_w + 1, len(cur)), -1, np.int64)
    trail[0] = cur
    length = np.zeros(len(cur), np.int64)
    alive = np.ones(len(cur), bool)
    for k in range(1, max_w + 1):
        m = matches[-k]
        nxt = np.where(alive, m[np.where(alive, cur, 0)] if len(m) else -1, -1)
        alive &= nxt >= 0
        cur = np.where(alive, nxt, 0)
        trail[k] = np.where(alive, nxt, -1)
        length += alive
    return length, trail


def adaptive_window(length: np.ndarray, w_default: int, n_pmin: int, n_pmax: int, w_avail: int) -> int:
    """Window size per eq. (2), given every feature's chain length."""
    w_max = max(1, w_avail)
    w = min(max(1, w_default), w_max)

    def count(w: int) -> int:
        return int((length >= w).sum())

    if count(w) < n_pmin:
        while w > 1 and count(w) < n_pmin:
            w -= 1
    elif count(w) > n_pmax:
        while w < w_max and count(w) > n_pmax:
            w += 1
    return w


def extract_pirfs(descs: list[np.ndarray], responses: list[np.ndarray], matches: list[np.ndarray], w_default: int,
                  n_pmin: int, n_pmax: int, w_limit: int) -> tuple[np.ndarray, np.ndarray, int]:
    """PIRFs of the newest frame. ``descs``/``responses``: frames t-len+1..t; ``matches[k]``
    maps frame k's features into frame k-1 (``matches[0]`` is unused).

    Returns (pirf descriptors (n, d) float32, indices of the PIRFs in frame t, window used).
    """
    t_hist = len(descs) - 1
    dim = descs[-1].shape[1]
    if t_hist < 1 or len(descs[-1]) == 0:
        return np.zeros((0, dim), np.float32), np.zeros(0, np.int64), 0
    max_w = min(t_hist, max(w_limit, w_default))
    length, trail = chain_lengths(matches[len(matches) - max_w:], max_w)
    w = adaptive_window(length, w_default, n_pmin, n_pmax, max_w)
    sel = np.flatnonzero(length >= w)
    if len(sel) > n_pmax:
        sel = sel[np.argsort(-responses[-1][sel], kind="stable")[:n_pmax]]
        sel.sort()
    acc = np.zeros((len(sel), dim), np.float64)
    for k in range(w + 1):
        acc += descs[-1 - k][trail[k, sel]]
    return (acc / (w + 1)).astype(np.float32), sel, w


class PirfTracker:
    """PIRFs of a video, one frame at a time: keeps the last ``w_size_max + 1`` frames'
    descriptors, responses and frame-to-frame matches, and runs :func:`extract_pirfs`."""

    def __init__(self, *, ratio: float, w_size_default: int, w_size_max: int, n_pmin: int, n_pmax: int) -> None:
        self.ratio, self.w_default, self.w_max = ratio, w_size_default, w_size_max
        self.n_pmin, self.n_pmax = n_pmin, n_pmax
        self.descs: list[np.ndarray] = []
        self.resps: list[np.ndarray] = []
        self.matches: list[np.ndarray] = []

    def push(self, desc: np.ndarray, resp: np.ndarray) -> tuple[np.ndarray, int]:
        """Add the next frame's features; returns its PIRFs (n, d) and the window used."""
        pirf, _sel, w = self.push_selected(desc, resp)
        return pirf, w

    def push_selected(self, desc: np.ndarray, resp: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """:meth:`push`, also returning which of the frame's features each PIRF ends in (``sel``);
        ``self.matches[-1][sel]`` are then their features in the frame before."""
        self.matches.append(ratio_match(desc, self.descs[-1], self.ratio) if self.descs else np.full(len(desc), -1, np.int64))
        self.descs.append(desc)
        self.resps.append(resp)
        if len(self.descs) > self.w_max + 1:  # only the window's history is needed
            self.descs.pop(0)
            self.resps.pop(0)
            self.matches.pop(0)
        return extract_pirfs(self.descs, self.resps, self.matches, self.w_default, self.n_pmin, self.n_pmax, self.w_max)
