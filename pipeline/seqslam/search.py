"""Local contrast enhancement (eq. 1) and sequence search (eqs. 2-3), numba kernels.

Matrix convention: ``D[r, q]``, rows = reference, columns = query, lower = more alike.
Kernels work on the transposed, query-major copy ``Dt[q, r]`` so that the inner loops walk
contiguous reference rows.

Trajectories (OpenSeqSLAM2's precomputed offsets): a trajectory is anchored at reference
``r`` for the current query ``T`` and passes through ``(T + t, r + round(V t))`` for the
query offsets ``t`` of the window: ``t = -ds..0`` (``causal``, the paper: only the past)
or ``t = -ds//2..ds - ds//2`` (``centred``, OpenSeqSLAM). The score is
``S(r, T) = min_V sum_t D^[r + round(V t), T + t]``; a trajectory that leaves the matrix
is not scored. The match is the ``r`` with the smallest score; its confidence compares it
with the best score outside ``+-window`` rows of it (see :func:`sequence_search`).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from placeloc.seqslam.params import SEQUENCE_SHAPES as SHAPES

INVALID = np.float32(np.inf)


def velocities(v_min: float, v_max: float, v_step: float) -> np.ndarray:
    n = int(math.floor((v_max - v_min) / v_step + 1e-9)) + 1
    return np.round(v_min + v_step * np.arange(n), 9)


def query_offsets(ds: int, search: str) -> np.ndarray:
    """Query offsets ``t`` of the window (ds + 1 frames, as ``sum_{T-ds}^{T}`` in eq. 2)."""
    if search == "causal":
        return np.arange(-ds, 1, dtype=np.int64)
    before = ds // 2
    return np.arange(-before, ds - before + 1, dtype=np.int64)


def trajectory_offsets(vels: np.ndarray, t_offsets: np.ndarray) -> np.ndarray:
    """``round(V t)`` for every velocity (rows) and query offset (columns)."""
    # Round half away from zero so +t and -t give mirror offsets.
    x = vels[:, None] * t_offsets[None, :].astype(np.float64)
    return (np.sign(x) * np.floor(np.abs(x) + 0.5)).astype(np.int64)


def enhancement_shift(window: int) -> float:
    """A z-score over n <= 2R+1 samples is >= -sqrt(n-1); adding sqrt(2R) makes D^ >= 0.

    A constant shift keeps every argmin (all trajectories have the same length) and makes
    the ratio-based confidence and the dissimilarity ratio meaningful after enhancement.
    """
    return math.sqrt(2 * window)


@numba.njit(parallel=True, cache=True)
def _enhance_t(dt: np.ndarray, window: int, shift: float, out: np.ndarray) -> None:
    nq, nr = dt.shape
    for q in numba.prange(nq):
        row = dt[q]
        c1 = np.zeros(nr + 1)
        c2 = np.zeros(nr + 1)
        for r in range(nr):
            x = np.float64(row[r])
            c1[r + 1] = c1[r] + x
            c2[r + 1] = c2[r] + x * x
        for r in range(nr):
            lo = max(0, r - window)
            hi = min(nr, r + window + 1)
            n = hi - lo
            mean = (c1[hi] - c1[lo]) / n
            var = (c2[hi] - c2[lo]) / n - mean * mean
            sd = math.sqrt(var) if var > 1e-12 else 0.0
            out[q, r] = ((row[r] - mean) / sd if sd > 0.0 else 0.0) + shift


def enhance(d: np.ndarray, window: int) -> np.ndarray:
    """Eq. (1), per query column over reference rows ``r-R..r+R`` (clipped at the ends),
    plus the constant :func:`enhancement_shift`. Input and output are ``D[r, q]``."""
    dt = np.ascontiguousarray(d.T, dtype=np.float32)
    out = np.empty_like(dt)
    _enhance_t(dt, int(window), float(enhancement_shift(window)), out)
    return out.T


def enhance_t(dt: np.ndarray, window: int) -> np.ndarray:
    """As :func:`enhance` but on and to the query-major ``Dt[q, r]``."""
    dt = np.ascontiguousarray(dt, dtype=np.float32)
    out = np.empty_like(dt)
    _enhance_t(dt, int(window), float(enhancement_shift(window)), out)
    return out




@numba.njit(cache=True, fastmath=True)
def _trajectory_scores(et: np.ndarray, T: int, t_off: np.ndarray, traj: np.ndarray, limit: int, s: np.ndarray) -> None:
    """``s[r] = min_V sum_t et[T + t, r + round(V t)]`` over trajectories inside the matrix."""
    nr = et.shape[1]
    nv, nt = traj.shape
    acc = np.empty(nr, dtype=np.float32)
    for v in range(nv):
        omin = traj[v, 0]
        omax = traj[v, 0]
        for j in range(nt):
            omin = min(omin, traj[v, j])
            omax = max(omax, traj[v, j])
        r_lo = max(0, -omin)
        r_hi = min(nr, nr - omax, limit)
        if r_hi <= r_lo:
            continue
        # Slices with non-negative loop indices: numba drops its negative-index handling
        # and the adds vectorise (same adds, same order, as a loop over r).
        a = acc[r_lo:r_hi]
        a[:] = 0.0
        for j in range(nt):
            o = traj[v, j]
            src = et[T + t_off[j], r_lo + o:r_hi + o]
            for i in range(r_hi - r_lo):
                a[i] += src[i]
        dst = s[r_lo:r_hi]
        for i in range(r_hi - r_lo):
            if a[i] < dst[i]:
                dst[i] = a[i]


@numba.njit(cache=True, fastmath=True)
def _cone_scores(et: np.ndarray, T: int, t_off: np.ndarray, traj: np.ndarray, limit: int, s: np.ndarray) -> None:
    """``s[r] = sum_t min_{o in cone(t)} et[T + t, r + o]``: at every query frame the best
    reference inside the cone the velocities span, chosen frame by frame."""
    nr = et.shape[1]
    nv, nt = traj.shape
    lo = np.empty(nt, np.int64)
    hi = np.empty(nt, np.int64)
    for j in range(nt):
        lo[j] = traj[0, j]
        hi[j] = traj[0, j]
        for v in range(nv):
            lo[j] = min(lo[j], traj[v, j])
            hi[j] = max(hi[j], traj[v, j])
    r_lo = 0
    r_hi = min(nr, limit)
    for j in range(nt):
        r_lo = max(r_lo, -lo[j])
        r_hi = min(r_hi, nr - hi[j])
    if r_hi <= r_lo:
        return
    acc = np.zeros(nr, dtype=np.float32)
    for j in range(nt):
        col = et[T + t_off[j]]
        for r in range(r_lo, r_hi):
            m = col[r + lo[j]]
            for o in range(lo[j] + 1, hi[j] + 1):
                m = min(m, col[r + o])
            acc[r] += m
    for r in range(r_lo, r_hi):
        s[r] = acc[r]


@numba.njit(cache=True)
def _top_k(s: np.ndarray, window: int, k: int, best: np.ndarray, scores: np.ndarray) -> None:
    """Greedy non-maximum suppression: the k best references at least window+1 apart.
    Destroys ``s``."""
    nr = s.shape[0]
    for kk in range(k):
        bi = -1
        bv = np.inf
        for r in range(nr):
            if s[r] < bv:
                bv = s[r]
                bi = r
        best[kk] = bi
        scores[kk] = bv
        if bi < 0:
            for rest in range(kk + 1, k):
                best[rest] = -1
                scores[rest] = np.inf
            break
        for r in range(max(0, bi - window), min(nr, bi + window + 1)):
            s[r] = np.inf


@numba.njit(cache=True)
def _shifted(t_off: np.ndarray, vels: np.ndarray, shift: int) -> tuple[np.ndarray, np.ndarray]:
    """Query offsets moved by ``shift`` frames and their trajectory offsets (same rounding
    as :func:`trajectory_offsets`)."""
    nv, nt = vels.shape[0], t_off.shape[0]
    t2 = t_off + shift
    traj = np.empty((nv, nt), np.int64)
    for v in range(nv):
        for j in range(nt):
            x = vels[v] * np.float64(t2[j])
            traj[v, j] = np.int64(np.sign(x) * np.floor(np.abs(x) + 0.5))
    return t2, traj


@numba.njit(parallel=True, cache=True, fastmath=True)
def _search(et: np.ndarray, q_lo: int, q_hi: int, t_off: np.ndarray, traj: np.ndarray, vels: np.ndarray,
            shift_edges: bool, window: int, k: int, exclude_after: np.ndarray, shape: int, best: np.ndarray,
            scores: np.ndarray) -> None:
    ncols, nr = et.shape
    nt = traj.shape[1]
    for qi in numba.prange(q_hi - q_lo):
        T = q_lo + qi  # column of the current query inside et
        s = np.full(nr, np.inf, dtype=np.float32)
        to = t_off
        tr = traj
        ok = T + t_off[0] >= 0 and T + t_off[nt - 1] < ncols
        if not ok and shift_edges and nt <= ncols:
            # near the ends of the traverse: the window of ds + 1 frames nearest the query
            sh = -(T + t_off[0]) if T + t_off[0] < 0 else ncols - 1 - (T + t_off[nt - 1])
            to, tr = _shifted(t_off, vels, sh)
            ok = True
        if ok:
            limit = exclude_after[qi]  # references >= limit are excluded (loop closure)
            if shape == 0:
                _trajectory_scores(et, T, to, tr, limit, s)
            elif shape == 1:
                _cone_scores(et, T, to, tr, limit, s)
            else:
                # hybrid: the cone proposes k regions, the trajectory score ranks inside them
                _cone_scores(et, T, to, tr, limit, s)
                cb = np.full(k, -1, np.int64)
                cs = np.full(k, np.inf, np.float32)
                _top_k(s, window, k, cb, cs)
                st = np.full(nr, np.inf, dtype=np.float32)
                _trajectory_scores(et, T, to, tr, limit, st)
                for r in range(nr):
                    s[r] = np.inf
                for kk in range(k):
                    if cb[kk] >= 0:
                        for r in range(max(0, cb[kk] - window), min(nr, cb[kk] + window + 1)):
                            s[r] = st[r]
        _top_k(s, window, k, best[qi], scores[qi])


def sequence_search(
    et: np.ndarray,
    q_lo: int,
    q_hi: int,
    ds: int,
    vels: np.ndarray,
    search: str,
    window: int,
    k: int,
    exclude_recent: int | None,
    query_index0: int,
    *,
    shape: str,
    edges: str,
) -> tuple[np.ndarray, np.ndarray]:
    """Search queries ``q_lo..q_hi-1`` (columns of ``et = Dt[q, r]``, enhanced).

    ``shape`` is how a sequence may run through the matrix (as in OpenSeqSLAM2):
    ``trajectory`` (straight lines of the given slopes, the original SeqSLAM), ``cone``
    (at each query frame the best reference anywhere between the slowest and the fastest
    line: tolerates speed changes inside the window) or ``hybrid`` (the cone proposes the
    ``k`` best regions, straight lines rank the references inside them).

    ``edges``: ``skip`` leaves queries whose window would leave the traverse unmatched
    (SeqSLAM, OpenSeqSLAM); ``shift`` uses the ds + 1 frames nearest them instead, so the
    first and last ds/2 queries get a (one-sided) sequence too.

    Returns ``best`` (n, k) reference indices (-1 = none) and their ``scores`` (n, k),
    ascending, the k best at least ``window + 1`` rows apart. ``exclude_recent`` (loop
    closure, reference == query) drops references ``r > T_global - exclude_recent`` where
    ``T_global = query_index0 + column``.
    """
    if edges not in ("skip", "shift"):
        raise ValueError(f"unknown edge handling {edges!r}; choose skip or shift")
    if shape not in SHAPES:
        raise ValueError(f"unknown sequence shape {shape!r}; choose one of {', '.join(SHAPES)}")
    t_off = query_offsets(ds, search)
    traj = trajectory_offsets(vels, t_off)
    n = q_hi - q_lo
    nr = et.shape[1]
    if exclude_recent is None:
        exclude_after = np.full(n, nr, np.int64)
    else:
        tg = query_index0 + np.arange(q_lo, q_hi)
        exclude_after = np.clip(tg - int(exclude_recent) + 1, 0, nr).astype(np.int64)
    best = np.full((n, k), -1, np.int64)
    scores = np.full((n, k), np.inf, np.float32)
    if n > 0:
        _search(np.ascontiguousarray(et, dtype=np.float32), q_lo, q_hi, t_off, traj, np.asarray(vels, np.float64),
                edges == "shift", int(window), int(k), exclude_after, SHAPES.index(shape), best, scores)
    return best, scores


def confidence(scores: np.ndarray) -> np.ndarray:
    """Match confidence from the two best (NMS-separated) scores: ``1 - S_best / S_second``.

    In [0, 1], higher = more distinct; 0 when there is no second candidate or no match.
    Scores are non-negative thanks to :func:`enhancement_shift`.
    """
    s1 = scores[:, 0].astype(np.float64)
    s2 = scores[:, 1].astype(np.float64) if scores.shape[1] > 1 else np.full_like(s1, np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = 1.0 - s1 / s2
    c[~np.isfinite(s1) | ~np.isfinite(s2) | (s2 <= 0)] = 0.0
    return np.clip(c, 0.0, 1.0)


def single_image_best(dt: np.ndarray, window: int, exclude_recent: int | None, q0: int) -> tuple[np.ndarray, np.ndarray]:
    """Single-image baseline: best reference per query on raw differences ``dt[q, r]``
    (query-major), confidence as for sequences: ``1 - best / best outside +-window``
    (differences are >= 0 for every comparison). ``q0`` is the global index of row 0, for
    ``exclude_recent`` (loop closure)."""
    n, nr = dt.shape
    rows = np.arange(n)[:, None]
    x = dt
    if exclude_recent is not None:
        x = dt.copy()
        limit = np.clip(q0 + np.arange(n) - exclude_recent + 1, 0, nr)
        x[np.arange(nr)[None, :] >= limit[:, None]] = np.inf
    best = np.argmin(x, axis=1)
    s1 = x[np.arange(n), best].astype(np.float64)
    x = x.copy() if x is dt else x
    x[rows, np.clip(best[:, None] + np.arange(-window, window + 1)[None, :], 0, nr - 1)] = np.inf
    s2 = x.min(axis=1).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        conf = 1.0 - np.maximum(s1, 0) / s2
    conf[~np.isfinite(conf) | ~np.isfinite(s1)] = 0.0
    best[~np.isfinite(s1)] = -1
    return best, np.clip(conf, 0, 1)
