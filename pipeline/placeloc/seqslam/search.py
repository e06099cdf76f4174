"""Local contrast enhancement (eq. 1) and sequence search (eqs. 2-3).

Matrix convention: ``D[r, q]``, rows = reference, columns = query, lower = more alike.
Kernels work on the transposed, query-major copy ``Dt[q, r]`` so that each step is a slice
of contiguous reference rows, for a chunk of queries at once; chunks run on one thread per
core. The enhancement and the straight trajectories run as LLVM IR compiled by llvmlite
(:mod:`placeloc.seqslam.row_kernels`, bit-identical to the NumPy references kept here,
:func:`enhance_rows_numpy` and :func:`trajectory_scores_numpy`), and so does the ranking
(:func:`top_k_numpy`): in NumPy they were bound by
the GIL past two cores. They pay no numba start-up (about 0.7 s a process); the flexible
path's dynamic programme is compiled by numba (:mod:`placeloc.seqslam.flexible`). The cone
shapes stay NumPy.

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

import numpy as np

from placeloc.seqslam.l1 import n_threads, run_threaded
from placeloc.seqslam.params import SEQUENCE_SHAPES as SHAPES
from placeloc.seqslam.params import SeqSLAMParams
from placeloc.seqslam.row_kernels import enhance_rows, top_k, trajectory_scores

INVALID = np.float32(np.inf)


def velocities(v_min: float, v_max: float, v_step: float, v_reverse: float = 0.0) -> np.ndarray:
    """Speeds ``v_min..v_max`` in steps of ``v_step`` (reference frames per query frame),
    ascending; with ``v_reverse`` > 0 also the backward speeds ``-v_reverse..-v_min`` (from
    ``-v_step`` when ``v_min`` is 0), the forward ones mirrored: a path may back out as
    slowly as it may crawl forwards."""
    n = int(math.floor((v_max - v_min) / v_step + 1e-9)) + 1
    forward = np.round(v_min + v_step * np.arange(n), 9)
    if v_reverse <= 0:
        return forward
    slowest = max(float(v_min), float(v_step))
    n_back = int(math.floor((v_reverse - slowest) / v_step + 1e-9)) + 1
    backward = -np.round(slowest + v_step * np.arange(max(0, n_back)), 9)
    return np.concatenate([backward[::-1], forward])


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


# Bytes of float32 a chunk of rows holds. Chosen when the straight search, the
# enhancement and the ranking were NumPy (now compiled, :mod:`placeloc.seqslam.row_kernels`;
# not measured again since). On one thread, small chunks kept the straight search's running
# sums in L2: at 3576 references 0.26 s with 384 KB chunks (27 rows) against 0.40 s with
# 2 MB (one core of an H100 host). With two threads or more, those NumPy kernels held the
# GIL to dispatch each call, and threads queued for it woke one another through the OS, so
# each call needed more work: localize with the benchmark settings took 0.92-0.96 s of its
# own with 384 KB chunks on 2 cores against 0.80-0.85 s with 2 MB, and the search 0.25 s
# against 0.11 s on 16 cores (`python bench/scaling.py --cores`).
ROW_CHUNK_BYTES_ONE_THREAD = 384 << 10
ROW_CHUNK_BYTES = 2 << 20


def row_chunks(n_rows: int, n_cols: int, threads: int | None = None) -> list[tuple[int, int]]:
    """Split rows into chunks for ``threads`` threads (None: one per usable core) of about
    :data:`ROW_CHUNK_BYTES` of float32 (:data:`ROW_CHUNK_BYTES_ONE_THREAD` on one thread),
    4 to 512 rows."""
    per_chunk = ROW_CHUNK_BYTES_ONE_THREAD if (threads or n_threads()) == 1 else ROW_CHUNK_BYTES
    step = int(np.clip(per_chunk // max(1, 4 * n_cols), 4, 512))
    return [(i, min(n_rows, i + step)) for i in range(0, n_rows, step)]


# Rows per pass of the NumPy enhancement (the reference): its five float64 buffers of this many rows stay in a
# core's L2 cache (3576 references: 16 x 3577 x 8 B = 0.46 MB each) and are allocated once
# per chunk. Fresh temporaries of a whole chunk per step cost a page fault every 4 KB: at
# 3576 x 3576 on one core of an H100 host 0.47 s before, 0.24 s now.
ENHANCE_ROWS = 16


def _window_sums_into(c: np.ndarray, window: int, ends: np.ndarray, out: np.ndarray) -> None:
    """``out[:, r] = c[:, min(nr, r + R + 1)] - c[:, max(0, r - R)]`` for every column ``r``
    of running sums ``c`` (with a leading zero column): slices inside, the clipped ends
    (``ends``) apart."""
    nr = c.shape[1] - 1
    if nr > 2 * window:
        np.subtract(c[:, 2 * window + 1:], c[:, :nr - 2 * window], out=out[:, window:nr - window])
    out[:, ends] = c[:, np.minimum(nr, ends + window + 1)] - c[:, np.maximum(0, ends - window)]


def enhance_rows_numpy(dt: np.ndarray, window: int, shift: float, out: np.ndarray) -> None:
    """Eq. (1) along each row of ``dt`` (float64 running sums, as the z-score needs),
    :data:`ENHANCE_ROWS` rows at a time in buffers allocated once: the NumPy reference of
    the compiled :func:`placeloc.seqslam.row_kernels.enhance_rows`, which localize runs
    (0.04 s against 0.15 s at 3576 x 3576 on one core here, and free of the GIL)."""
    n, nr = dt.shape
    rows = min(ENHANCE_ROWS, n)
    x, mean, var, square = (np.empty((rows, nr)) for _ in range(4))
    c = np.zeros((rows, nr + 1))
    flat = np.empty((rows, nr), bool)
    r = np.arange(nr)
    ends = np.flatnonzero((r < window) | (r >= nr - window))
    count = (np.minimum(nr, r + window + 1) - np.maximum(0, r - window)).astype(np.float64)
    for i in range(0, n, rows):
        m = min(rows, n - i)
        xi, ci, mi, vi, si, fi = x[:m], c[:m], mean[:m], var[:m], square[:m], flat[:m]
        np.copyto(xi, dt[i:i + m])
        np.cumsum(xi, axis=1, out=ci[:, 1:])
        _window_sums_into(ci, window, ends, mi)
        # squares into their own buffer: a cumulative sum in place (input and output
        # overlapping) makes NumPy copy first, holding the GIL
        np.multiply(xi, xi, out=si)
        np.cumsum(si, axis=1, out=ci[:, 1:])
        _window_sums_into(ci, window, ends, vi)
        mi /= count
        vi /= count
        np.multiply(mi, mi, out=si)
        vi -= si
        # sd = sqrt(var) where var > 1e-12, else the z-score is 0
        np.greater(vi, 1e-12, out=fi)
        np.logical_not(fi, out=fi)
        np.copyto(vi, 1.0, where=fi)
        np.sqrt(vi, out=vi)
        xi -= mi
        xi /= vi
        np.copyto(xi, 0.0, where=fi)
        xi += shift
        out[i:i + m] = xi


def _enhance_into(dt: np.ndarray, window: int, out: np.ndarray) -> None:
    shift = float(enhancement_shift(window))

    def run(lo: int, hi: int) -> None:
        enhance_rows(dt[lo:hi], int(window), shift, out[lo:hi])

    run_threaded(run, row_chunks(dt.shape[0], dt.shape[1]))


def enhance(d: np.ndarray, window: int) -> np.ndarray:
    """Eq. (1), per query column over reference rows ``r-R..r+R`` (clipped at the ends),
    plus the constant :func:`enhancement_shift`. Input and output are ``D[r, q]``."""
    dt = np.ascontiguousarray(d.T, dtype=np.float32)
    out = np.empty_like(dt)
    _enhance_into(dt, window, out)
    return out.T


def enhance_t(dt: np.ndarray, window: int) -> np.ndarray:
    """As :func:`enhance` but on and to the query-major ``Dt[q, r]``."""
    dt = np.ascontiguousarray(dt, dtype=np.float32)
    out = np.empty_like(dt)
    _enhance_into(dt, window, out)
    return out


def trajectory_scores_numpy(et: np.ndarray, rows: tuple[int, int], t_off: np.ndarray, traj: np.ndarray) -> np.ndarray:
    """``s[q, r] = min_V sum_t et[T + t, r + round(V t)]`` for ``T`` in ``rows`` (all inside
    the matrix for these offsets); inf where a trajectory would leave it. The NumPy
    reference of the compiled :func:`placeloc.seqslam.row_kernels.trajectory_scores`, which
    the search runs."""
    a, b = rows
    nr = et.shape[1]
    s = np.full((b - a, nr), INVALID, np.float32)
    acc = np.empty((b - a, nr), np.float32)
    for offsets in traj:
        r_lo, r_hi = max(0, -int(offsets.min())), min(nr, nr - int(offsets.max()))
        if r_hi <= r_lo:
            continue
        part = acc[:, r_lo:r_hi]
        part[:] = 0.0
        for t, o in zip(t_off, offsets):  # same adds, same order, for every reference
            part += et[a + t:b + t, r_lo + o:r_hi + o]
        np.minimum(s[:, r_lo:r_hi], part, out=s[:, r_lo:r_hi])
    return s


def _cone_scores(et: np.ndarray, rows: tuple[int, int], t_off: np.ndarray, traj: np.ndarray) -> np.ndarray:
    """``s[q, r] = sum_t min_{o in cone(t)} et[T + t, r + o]``: at every query frame the best
    reference inside the cone the velocities span, chosen frame by frame."""
    a, b = rows
    nr = et.shape[1]
    lo, hi = traj.min(axis=0), traj.max(axis=0)
    r_lo, r_hi = max(0, int((-lo).max())), min(nr, int((nr - hi).min()))
    s = np.full((b - a, nr), INVALID, np.float32)
    if r_hi <= r_lo:
        return s
    acc = np.zeros((b - a, r_hi - r_lo), np.float32)
    for t, o_lo, o_hi in zip(t_off, lo, hi):
        best = et[a + t:b + t, r_lo + o_lo:r_hi + o_lo].copy()
        for o in range(o_lo + 1, o_hi + 1):
            np.minimum(best, et[a + t:b + t, r_lo + o:r_hi + o], out=best)
        acc += best
    s[:, r_lo:r_hi] = acc
    return s


# ---------------------------------------------------------------------------------------
# flexible: a path whose speed may change inside the window (dynamic programming)
# ---------------------------------------------------------------------------------------
# The defaults of the path's costs (their home and meaning: SeqSLAMParams). A change of
# speed by dv between two segments of L frames costs speed_change_cost * L * |dv|;
# standing still costs stop_cost per unit of the query's own change (:class:`StopModel`),
# so a stopped path is cheap only where the query itself stands still; driving backwards
# costs reverse_cost per frame, so a backward path must earn it. Enhanced values are
# z-scores, so all are in units of one frame's standard deviation.
SPEED_CHANGE_COST = SeqSLAMParams.speed_change_cost
STOP_COST = SeqSLAMParams.stop_cost
REVERSE_COST = SeqSLAMParams.reverse_cost
# The change between two unrelated z-scored columns, E|X - Y| for independent standard
# normals (2 / sqrt(pi)): a query frame that changes this much from the one before it is
# wholly new evidence; one that repeats it, none.
UNRELATED_CHANGE = 2.0 / math.sqrt(math.pi)


def segment_length(vels: np.ndarray) -> int:
    """Frames per straight segment of a flexible path: ``round(1 / v_step)``, the shortest
    run over which two neighbouring speeds end a whole reference frame apart (a shorter
    segment could not tell them apart); one segment per side for one speed. Standing
    still does not count (the gap between it and the slowest speed is no step)."""
    v = np.unique(np.asarray(vels, np.float64))
    v = v[v != 0]
    if len(v) < 2:
        return 1 << 30
    return max(1, int(round(1.0 / float(np.diff(v).min()))))


class StopModel:
    """What standing still costs and earns, from the query alone (``et[q, r]``, enhanced);
    used when the velocities include 0.

    A query that stops repeats (nearly) the same frame, so its enhanced column repeats:
    ``change[q] = mean_r |et[q, r] - et[q - 1, r]|`` is about 0 there and 0.6-0.8 between
    moving Nordland frames. Two things follow:

    - a path that stands still pays ``stop_cost * change`` for every frame it does so
      (``running``: running sums of ``change``), so it stops only where the query does;
    - a repeated frame is no new evidence: while standing still, a frame counts only by
      its novelty ``w = min(1, change / UNRELATED_CHANGE)``, around its column's mean
      (``quiet_fwd``/``quiet_back``: ``mean + w * (et - mean)``, novelty measured from the
      frame before it in the path's direction). Otherwise a reference that resembles every
      query (a "hub") would earn the same low value once per repeated frame and win the
      search wherever the query pauses.

    Every frame's novelty is measured against its neighbour inside the same window (the
    one nearer the anchor), so a result never depends on how queries were cut into blocks.
    """

    def __init__(self, et: np.ndarray) -> None:
        n = et.shape[0]
        change = np.zeros(n)
        step = max(1, (1 << 22) // max(1, et.shape[1]))
        for i in range(1, n, step):
            j = min(n, i + step)
            change[i:j] = np.abs(et[i:j] - et[i - 1:j - 1]).mean(axis=1, dtype=np.float64)
        self.running = np.cumsum(change)  # running[i] - running[f]: the query's change from frame f to i
        novelty = np.minimum(1.0, change / UNRELATED_CHANGE).astype(np.float32)[:, None]
        mean = et.mean(axis=1, dtype=np.float64).astype(np.float32)[:, None]
        self.quiet_fwd = mean + novelty * (et - mean)  # frame q after frame q - 1
        nb = np.empty_like(novelty)
        nb[:-1], nb[-1:] = novelty[1:], 1.0
        self.quiet_back = mean + nb * (et - mean)  # frame q before frame q + 1


def flexible_model(et: np.ndarray, t_off: np.ndarray, vels: np.ndarray, speed_change_cost: float,
                   stops: StopModel | None) -> tuple[int, np.ndarray, StopModel | None, float, int, int]:
    """The flexible path's model for a window ``t_off``: its segment length, the speeds
    (unique, ascending), the stop model (only when 0 is among the speeds), the cost of a
    change per unit of speed (``speed_change_cost`` per frame of a segment), and the frames
    before and after the anchor."""
    seg = segment_length(vels)
    vels = np.unique(np.asarray(vels, np.float64))
    if not (vels == 0).any():
        stops = None
    elif stops is None:
        stops = StopModel(et)
    bend = float(speed_change_cost) * min(seg, int(t_off[-1] - t_off[0]) + 1)
    return seg, vels, stops, bend, int(-t_off[0]), int(t_off[-1])


# References per tile of the compiled flexible search: the window's rows of a tile stay in
# the core's cache from one anchor to the next. A row of 3576 references fits whole; at
# 35,768 a whole row cost twice the time per matrix cell (bench_seqslam_full.py).
FLEXIBLE_TILE = 4096


# Bytes of float32 scores a chunk of the flexible search's anchors holds at most (per
# thread; with backward_paths twice). Anchors ``seg`` apart share their segments' sums
# (:mod:`placeloc.seqslam.flexible`), so a chunk gains from every anchor it holds: each
# thread takes one long chunk, cut shorter only so that its scores stay within this
# (at 35,768 references: 117 anchors).
FLEXIBLE_CHUNK_BYTES = 16 << 20


def flexible_chunks(n_rows: int, n_cols: int, threads: int | None = None) -> list[tuple[int, int]]:
    """Anchors of the flexible search split into chunks: as few as there are threads
    (None: one per usable core), of at most :data:`FLEXIBLE_CHUNK_BYTES` of float32 scores
    (``n_cols`` a row) each."""
    per_thread = -(-n_rows // max(1, threads or n_threads()))
    step = max(1, min(per_thread, FLEXIBLE_CHUNK_BYTES // max(1, 4 * n_cols)))
    return [(i, min(n_rows, i + step)) for i in range(0, n_rows, step)]


def _flexible_scores(et: np.ndarray, rows: tuple[int, int], t_off: np.ndarray, vels: np.ndarray,
                     speed_change_cost: float = SPEED_CHANGE_COST, stop_cost: float = STOP_COST,
                     stops: StopModel | None = None, reverse_cost: float = REVERSE_COST, tile: int | None = None) -> np.ndarray:
    """``s[q, r]``: the cheapest path through ``(T, r)`` over the window ``T + t_off``
    whose speed may change every :func:`segment_length` frames, within the velocity bounds
    ``vels``, at ``speed_change_cost`` per frame of bend. With 0 among ``vels`` it may also
    stand still where the query does (:class:`StopModel`, ``stop_cost``); otherwise every
    frame counts as it is. Negative ``vels`` let it drive backwards, at ``reverse_cost``
    per frame.

    Each half of the window is a chain of straight segments of ``seg`` frames (the last one
    shorter), each with its own speed, each starting where the previous one's line ends
    (``round(v * seg)`` further); a change of speed between segments costs
    ``bend * |dv|``. Each half is solved from its far end inwards (Viterbi over segments,
    relaxed over speeds by an L1 distance transform); the backward half first, then the
    forward one, whose first segment meets it at the anchor, with a change of speed there
    costed like any other. A path that would leave the matrix is not scored (inf). The
    arithmetic is compiled (:mod:`placeloc.seqslam.flexible`) and runs without the GIL, on
    ``tile`` references at a time (default :data:`FLEXIBLE_TILE`; any tile gives the same
    scores)."""
    from placeloc.seqslam.flexible import flexible_rows

    a, b = rows
    seg, vels, stops, bend, before, after = flexible_model(et, t_off, vels, speed_change_cost, stops)
    # round(v t) for t = 0 .. the longest segment (+1: where it ends)
    offs = np.ascontiguousarray(trajectory_offsets(vels, np.arange(min(seg, max(before, after) + 1) + 1, dtype=np.int64)))
    steps = np.array([np.float32(bend * (vels[i + 1] - vels[i])) for i in range(len(vels) - 1)] or [0.0], np.float32)
    et = np.ascontiguousarray(et, dtype=np.float32)
    if stops is None:
        quiet_back = quiet_fwd = et
        running = np.zeros(1)
    else:
        quiet_back, quiet_fwd, running = stops.quiet_back, stops.quiet_fwd, stops.running
    s = np.empty((b - a, et.shape[1]), np.float32)
    flexible_rows(et, np.ascontiguousarray(quiet_back, np.float32), np.ascontiguousarray(quiet_fwd, np.float32),
                  np.ascontiguousarray(running, np.float64), stops is not None, int(a), int(b), int(min(seg, 1 << 30)),
                  before, after, vels, offs, steps, float(stop_cost), float(reverse_cost), s,
                  int(tile or FLEXIBLE_TILE))
    return s


def _around(centres: np.ndarray, window: int, nr: int) -> np.ndarray:
    """Column indices ``centre - window .. centre + window`` per row, clipped to the matrix
    (a clipped index repeats the edge column, which lies inside the window anyway)."""
    return np.clip(centres[:, None] + np.arange(-window, window + 1), 0, nr - 1)


def _recent_limits(t_global: np.ndarray, exclude_recent: int, nr: int) -> np.ndarray:
    """Loop closure: the first reference each query (global index ``t_global``) may not match."""
    return np.clip(t_global - int(exclude_recent) + 1, 0, nr).astype(np.int64)


def _top_k(s: np.ndarray, window: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Greedy non-maximum suppression per row: the k best references at least window+1
    apart (ties: the first), -1 / inf when none is left. May destroy ``s``. Compiled
    (:func:`placeloc.seqslam.row_kernels.top_k`): in NumPy (:func:`top_k_numpy`) each pick
    held the GIL to index, and on 16 cores the ranking's threads queued for it."""
    return top_k(np.ascontiguousarray(s, dtype=np.float32), int(window), int(k))


def top_k_numpy(s: np.ndarray, window: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The NumPy reference of :func:`_top_k` (what the compiled kernel is tested against).
    Destroys ``s``."""
    n, nr = s.shape
    best = np.full((n, k), -1, np.int64)
    scores = np.full((n, k), INVALID, np.float32)
    rows = np.arange(n)
    for kk in range(k):
        bi = np.argmin(s, axis=1)
        bv = s[rows, bi]
        found = bv < INVALID
        if not found.any():
            break
        best[found, kk], scores[found, kk] = bi[found], bv[found]
        s[rows[found][:, None], _around(bi[found], window, nr)] = INVALID
    return best, scores


def backward_velocities(vels: np.ndarray, v_max: float) -> np.ndarray:
    """The speeds of ``backward_paths``' family: the forward ``vels`` up to ``v_max``,
    negated, ascending (a vehicle backs out slower than it may drive; the family's cost
    is proportional to its speeds). Its segments are the forward family's: the step
    between speeds is the same."""
    v = np.asarray(vels, np.float64)
    return -v[v <= v_max + 1e-9][::-1]


def _scores(et: np.ndarray, rows: tuple[int, int], t_off: np.ndarray, traj: np.ndarray, shape: str, window: int,
            k: int, limit: np.ndarray, vels: np.ndarray | None = None, flexible: dict | None = None) -> np.ndarray:
    """Sequence scores of queries ``rows`` for one set of offsets; references ``>= limit``
    (per query) are excluded. ``flexible``: keyword arguments of :func:`_flexible_scores`."""
    if shape == "flexible":
        costs = dict(flexible or {})
        backward = costs.pop("backward_paths", False)
        back = backward_velocities(vels, costs.pop("backward_v_max", math.inf))
        s = _flexible_scores(et, rows, t_off, vels, **costs)
        if backward and len(back):  # the paths that drive backwards throughout
            np.minimum(s, _flexible_scores(et, rows, t_off, back, **{**costs, "stops": None}), out=s)
    elif shape == "trajectory":
        s = trajectory_scores(et, rows, t_off, traj)
    elif shape == "cone":
        s = _cone_scores(et, rows, t_off, traj)
    else:
        # hybrid: the cone proposes k regions, the trajectory score ranks inside them
        cone = _cone_scores(et, rows, t_off, traj)
        _exclude(cone, limit)
        regions, _ = _top_k(cone, window, k)
        line = trajectory_scores(et, rows, t_off, traj)
        s = np.full_like(line, INVALID)
        for kk in range(k):
            ok = regions[:, kk] >= 0
            q = np.nonzero(ok)[0][:, None]
            cols = _around(regions[ok, kk], window, s.shape[1])
            s[q, cols] = line[q, cols]
    _exclude(s, limit)
    return s


def _exclude(s: np.ndarray, limit: np.ndarray) -> None:
    nr = s.shape[1]
    if (limit < nr).any():
        s[np.arange(nr)[None, :] >= limit[:, None]] = INVALID


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
    speed_change_cost: float = SPEED_CHANGE_COST,
    stop_cost: float = STOP_COST,
    reverse_cost: float = REVERSE_COST,
    backward_paths: bool = False,
    backward_v_max: float = math.inf,
    plain: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Search queries ``q_lo..q_hi-1`` (columns of ``et = Dt[q, r]``, enhanced).

    ``shape`` is how a sequence may run through the matrix (as in OpenSeqSLAM2):
    ``trajectory`` (straight lines of the given slopes, the original SeqSLAM), ``cone``
    (at each query frame the best reference anywhere between the slowest and the fastest
    line: tolerates speed changes inside the window) or ``hybrid`` (the cone proposes the
    ``k`` best regions, straight lines rank the references inside them).

    ``flexible`` (a path whose speed may change every few frames within the velocity
    bounds, at ``speed_change_cost`` per frame of bend, and that may stand still where the
    query does, at ``stop_cost``: follows slow-downs, stops and bursts; see
    :func:`_flexible_scores`). ``backward_paths`` (flexible, forward ``vels`` only) scores
    a second family of paths over the same window that drive backwards throughout (the
    speeds negated, ``reverse_cost`` per frame) and keeps, per reference, the better of
    the two: a query that backs out is followed where its window does, and no path ever
    folds over the references (turning round inside a window is not in either family).
    The backward family's speeds are those of ``vels`` up to ``backward_v_max``
    (:func:`backward_velocities`; in the units of ``vels``, already scaled).

    ``edges``: ``skip`` leaves queries whose window would leave the traverse unmatched
    (SeqSLAM, OpenSeqSLAM); ``shift`` uses the ds + 1 frames nearest them instead, so the
    first and last ds/2 queries get a (one-sided) sequence too.

    Returns ``best`` (n, k) reference indices (-1 = none) and their ``scores`` (n, k),
    ascending, the k best at least ``window + 1`` rows apart. ``exclude_recent`` (loop
    closure, reference == query) drops references ``r > T_global - exclude_recent`` where
    ``T_global = query_index0 + column``.

    ``plain`` (optional): two arrays (n, p) filled with the plain ranking, the p best
    references with no separation (neighbours allowed; the standard Recall@N), from the
    same scores (for ``hybrid``, whose scores depend on the separation, scored again).
    """
    if edges not in ("skip", "shift"):
        raise ValueError(f"unknown edge handling {edges!r}; choose skip or shift")
    if shape not in SHAPES:
        raise ValueError(f"unknown sequence shape {shape!r}; choose one of {', '.join(SHAPES)}")
    if backward_paths and (shape != "flexible" or (np.asarray(vels) <= 0).any()):
        raise ValueError("backward_paths needs the flexible shape and forward speeds only (v_min > 0, v_reverse 0)")
    t_off = query_offsets(ds, search)
    traj = trajectory_offsets(vels, t_off)
    n = q_hi - q_lo
    nr = et.shape[1]
    if exclude_recent is None:
        exclude_after = np.full(n, nr, np.int64)
    else:
        exclude_after = _recent_limits(query_index0 + np.arange(q_lo, q_hi), exclude_recent, nr)
    best = np.full((n, k), -1, np.int64)
    scores = np.full((n, k), INVALID, np.float32)
    if n == 0:
        return best, scores
    et = np.ascontiguousarray(et, dtype=np.float32)
    ncols, nt = et.shape[0], len(t_off)
    window, k = int(window), int(k)
    flexible = None
    if shape == "flexible":
        flexible = {"speed_change_cost": float(speed_change_cost), "stop_cost": float(stop_cost),
                    "reverse_cost": float(reverse_cost), "stops": StopModel(et) if (np.asarray(vels) == 0).any() else None,
                    "backward_paths": bool(backward_paths), "backward_v_max": float(backward_v_max)}
    # Queries whose whole window lies inside the matrix share the offsets: scored in
    # chunks of rows, one thread per core. The few near the ends are skipped or, with
    # edges: shift, scored one by one with the ds + 1 frames nearest them.
    first = max(q_lo, -int(t_off[0]))
    last = min(q_hi, ncols - int(t_off[-1]))
    inner = (first, last) if first < last else (q_lo, q_lo)

    def rank(rows: slice, s: np.ndarray, t2: np.ndarray, traj2: np.ndarray) -> None:
        """The separated top k (and the plain ranking) of queries ``rows`` from their scores ``s``."""
        if plain is not None:
            p_k = plain[0].shape[1]
            s_plain = s.copy() if shape != "hybrid" else _scores(
                et, (rows.start + q_lo, rows.stop + q_lo), t2, traj2, shape, 0, p_k, exclude_after[rows], vels, flexible)
            plain[0][rows], plain[1][rows] = _top_k(s_plain, 0, p_k)
        best[rows], scores[rows] = _top_k(s, window, k)

    def run(lo: int, hi: int) -> None:
        a, b = inner[0] + lo, inner[0] + hi
        rows = slice(a - q_lo, b - q_lo)
        rank(rows, _scores(et, (a, b), t_off, traj, shape, window, k, exclude_after[rows], vels, flexible), t_off, traj)

    n_inner = inner[1] - inner[0]
    chunks = flexible_chunks(n_inner, nr) if shape == "flexible" else row_chunks(n_inner, nr)
    run_threaded(run, chunks)
    if edges == "shift" and nt <= ncols:
        edge = [*range(q_lo, inner[0]), *range(max(inner[1], inner[0]), q_hi)]

        def run_edge(lo: int, hi: int) -> None:
            for T in edge[lo:hi]:
                sh = -(T + int(t_off[0])) if T + int(t_off[0]) < 0 else ncols - 1 - (T + int(t_off[-1]))
                t2 = t_off + sh
                traj2 = trajectory_offsets(vels, t2)
                rows = slice(T - q_lo, T - q_lo + 1)
                rank(rows, _scores(et, (T, T + 1), t2, traj2, shape, window, k, exclude_after[rows], vels, flexible), t2, traj2)

        # each edge query has its own window: one at a time, spread over the cores (for the
        # flexible search the 2 x 60 edges of a Nordland preset run were 0.2 s on one core)
        run_threaded(run_edge, [(i, min(len(edge), i + 8)) for i in range(0, len(edge), 8)])
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
    x = np.array(dt, dtype=np.float32, order="C")  # a copy: the ranking destroys it
    if exclude_recent is not None:
        _exclude(x, _recent_limits(q0 + np.arange(n), exclude_recent, nr))
    # the best, and the best outside +-window of it: the separated ranking's first two
    picks, two = _top_k(x, window, 2)
    best = picks[:, 0]
    s1, s2 = two[:, 0].astype(np.float64), two[:, 1].astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        conf = 1.0 - np.maximum(s1, 0) / s2
    conf[~np.isfinite(conf) | ~np.isfinite(s1)] = 0.0
    best[~np.isfinite(s1)] = -1
    return best, np.clip(conf, 0, 1)
