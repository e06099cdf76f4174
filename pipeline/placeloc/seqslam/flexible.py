"""The flexible path's dynamic programme (``search._flexible_scores``), compiled.

One call scores a range of anchor queries ``T`` against every reference. For each anchor
the backward half of the window is solved first (a Viterbi recursion over straight
segments, from the far end inwards, relaxed over speeds by an L1 distance transform),
then the forward half, whose first segment meets it at the anchor; the result is the
cheapest path through ``(T, r)`` for every ``r``. ``search._flexible_scores`` documents
the model; this module is its arithmetic only.

Why compiled: the same recursion in NumPy is hundreds of small array operations per chunk
of queries, so the GIL, not the cores, bounded it (on a 16-core machine 15.3 s on one core,
7.9-9.2 s on two, slower again past two). Here a whole chunk runs without the GIL, one
anchor row at a time, so its working set (three ``speeds x references`` arrays, 0.7 MB at
16 speeds and 3576 references) stays in the core's cache. The adds, their order and their
float32 rounding are those of the NumPy formulation, element by element (no fast-math,
no reassociation), so the scores are bit-identical to it (tests/test_seqslam_flexible.py
keeps the NumPy formulation as the reference).

A segment's own frames sum to the same values whichever anchor reads them (they depend
on its first frame only), and a segment adds them before the chain beyond it. So a chunk
takes its anchors ``seg`` apart and keeps each whole segment's sums for the anchors after
it: an anchor sums one new segment a side instead of all of them (the Nordland preset:
15 adds per matrix cell and speed a side instead of 60), the same adds in the same order.
Measured on one core, 512 anchors of a random 3576-reference matrix, 38 speeds: 1.08-1.18
ms an anchor against 1.30 ms at load 5.4-5.8 on 2 cores; the kept sums (3.8 MB a side)
are read back from the last-level cache, so the gain is less than the adds saved, and
depends on who else uses that cache (docs/seqslam.md, "Cost, and the whole route").

numba is imported only by a search with ``sequence_shape: flexible`` (the import costs about
0.4 s, a few per cent of such a search at Nordland's size); ``cache=True`` keeps the
machine code in placeloc's private numba cache (``core.caches``).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def _add(part: np.ndarray, src: np.ndarray, width: int) -> None:
    """``part += src`` over ``width`` elements (indices from 0, so no negative-index
    checks stand in the way of vectorising)."""
    for k in range(width):
        part[k] += src[k]


@njit(cache=True, nogil=True, inline="always")
def _add2(part: np.ndarray, a: np.ndarray, b: np.ndarray, width: int) -> None:
    """``part += a; part += b`` over ``width`` elements, in one pass."""
    for k in range(width):
        part[k] = (part[k] + a[k]) + b[k]


@njit(cache=True, nogil=True, inline="always")
def _add4(part: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, width: int) -> None:
    """``part += a``, then ``b``, ``c``, ``d``, in one pass."""
    for k in range(width):
        part[k] = (((part[k] + a[k]) + b[k]) + c[k]) + d[k]


@njit(cache=True, nogil=True, inline="always")
def _add8(part: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, e: np.ndarray, f: np.ndarray,
          g: np.ndarray, h: np.ndarray, width: int) -> None:
    """``part += a``, then ``b`` .. ``h``, in one pass."""
    for k in range(width):
        part[k] = (((((((part[k] + a[k]) + b[k]) + c[k]) + d[k]) + e[k]) + f[k]) + g[k]) + h[k]


@njit(cache=True, nogil=True, inline="always")
def _term(quiet: np.ndarray, h: np.ndarray, vi: int, i: int, n_rows: int, T: int, direction: int, start: int, lo: int,
          hi: int, offs: np.ndarray, h_shift: int) -> np.ndarray:
    """Term ``i`` a segment adds to its first frame: its frame ``i + 1`` (``i < n_rows``),
    else the best chain beyond it (``h[vi]``, ``h_shift`` references on)."""
    if i < n_rows:
        sh = direction * offs[vi, i + 1]
        return quiet[T + direction * (start + i + 1), lo + sh:hi + sh]
    return h[vi, lo + h_shift:hi + h_shift]


@njit(cache=True, nogil=True)
def _envelope_up(g: np.ndarray, steps: np.ndarray, i: int) -> None:
    """``g[v] <- min_v' g[v'] + cost * |v - v'|`` (speeds ascending) is two passes, up then
    down (``steps[i]``: the float32 cost between speed ``i`` and ``i + 1``); this is the
    upward one at speed ``i`` (> 0), once ``g[i - 1]`` has had it: ``g[i] <- min(g[i],
    g[i - 1] + steps[i - 1])``. :func:`_side` runs it on each speed's row as soon as the
    row is computed, while it is still in the core's cache (a pass over all rows afterwards
    read them back; the same minima, in the same order)."""
    c = steps[i - 1]
    prev, cur = g[i - 1], g[i]
    for r in range(g.shape[1]):
        x = prev[r] + c
        if x < cur[r]:
            cur[r] = x


@njit(cache=True, nogil=True)
def _envelope_down(g: np.ndarray, steps: np.ndarray) -> None:
    """The downward pass (:func:`_envelope_up`), after the upward one: ``g[i] <- min(g[i],
    g[i + 1] + steps[i])`` from the fastest speed down."""
    nv, nr = g.shape
    for i in range(nv - 2, -1, -1):
        c = steps[i]
        for r in range(nr):
            x = g[i + 1, r] + c
            if x < g[i, r]:
                g[i, r] = x


@njit(cache=True, nogil=True, inline="always")
def _accumulate(part: np.ndarray, quiet: np.ndarray, h: np.ndarray, vi: int, n_rows: int, n_terms: int, T: int,
                direction: int, start: int, lo: int, hi: int, offs: np.ndarray, hs: int) -> None:
    """``part += term 0, term 1, ..., term n_terms - 1`` (:func:`_term`), in that order, up to
    eight in one pass: the running sum stays in a register, and ``part`` is loaded and
    stored once a pass instead of once a term (measured: 15 % less time per anchor at 38
    speeds and 3576 references); the same adds in the same order, so the same bits."""
    width = hi - lo
    i = 0
    while i < n_terms:
        left = n_terms - i
        if left >= 8:
            _add8(part, _term(quiet, h, vi, i, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 1, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 2, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 3, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 4, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 5, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 6, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 7, n_rows, T, direction, start, lo, hi, offs, hs), width)
            i += 8
        elif left >= 4:
            _add4(part, _term(quiet, h, vi, i, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 1, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 2, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 3, n_rows, T, direction, start, lo, hi, offs, hs), width)
            i += 4
        elif left >= 2:
            _add2(part, _term(quiet, h, vi, i, n_rows, T, direction, start, lo, hi, offs, hs),
                  _term(quiet, h, vi, i + 1, n_rows, T, direction, start, lo, hi, offs, hs), width)
            i += 2
        else:
            _add(part, _term(quiet, h, vi, i, n_rows, T, direction, start, lo, hi, offs, hs), width)
            i += 1


@njit(cache=True, nogil=True, inline="always")
def _span(end: int, nr: int, direction: int) -> tuple[int, int]:
    """The references ``lo:hi`` whose line, running ``end`` references from them in
    ``direction``, stays inside the matrix."""
    if direction > 0:
        return max(0, -end), nr - max(0, end)
    return max(0, end), nr + min(0, end)


@njit(cache=True, nogil=True)
def _segment_sums(quiet: np.ndarray, f: int, seg: int, direction: int, offs: np.ndarray, out: np.ndarray) -> None:
    """``out[v, r]``: the sum of a whole segment's ``seg`` frames from frame ``f`` (its first
    frame from ``quiet`` too) along speed ``v`` from reference ``r``, in the order the
    segment adds them, where the segment stays inside the matrix (elsewhere untouched)."""
    nv, nr = out.shape
    for vi in range(nv):
        end = offs[vi, seg - 1]
        if abs(end) >= nr:
            continue
        lo, hi = _span(end, nr, direction)
        part = out[vi, lo:hi]
        first = quiet[f, lo:hi]
        for k in range(hi - lo):
            part[k] = first[k]
        _accumulate(part, quiet, out, vi, seg - 1, seg - 1, f, direction, 0, lo, hi, offs, 0)


@njit(cache=True, nogil=True)
def _side(et: np.ndarray, quiet: np.ndarray, running: np.ndarray, has_stops: bool, T: int, n_frames: int, seg: int,
          vels: np.ndarray, offs: np.ndarray, steps: np.ndarray, direction: int, stop_cost: float, reverse_cost: float,
          g: np.ndarray, h: np.ndarray, row: np.ndarray, back: np.ndarray, s: np.ndarray, stream: bool,
          relax_first: bool, share: bool, sums: np.ndarray, sums_of: np.ndarray) -> None:
    """One half of the window from the anchor ``T`` (``direction`` +1 later, -1 earlier):
    the best chain per first speed, ``[v, r]``, left in ``g`` after an even number of
    segment boundaries, else in ``h`` (the two swap at each). With ``stream``, the first
    segment of each speed goes into ``row``, is added to ``back[v]`` and folded into ``s``
    by a minimum instead. Every segment but the first is relaxed over speeds
    (:func:`_envelope_up`, :func:`_envelope_down`) before the next one reads it; with
    ``relax_first``, the first too.

    A whole segment's own sum (:func:`_segment_sums`) depends only on its first frame, not
    on the anchor, so anchors ``seg`` apart share all but one: with ``share``, ``sums[slot]`` keeps them,
    ``sums_of[slot]`` the first frame whose sums a slot holds (slot ``(f // seg) % len``).
    A segment then adds the chain beyond it to its sum, the last of its adds, as before.
    The anchor's own segment reads ``et`` for its first frame, so with the stop model
    (``quiet`` is not ``et``) it is summed afresh."""
    inf = np.float32(np.inf)
    nv, nr = g.shape
    n_seg = (n_frames + seg - 1) // seg
    last = n_frames - (n_seg - 1) * seg
    n_slots = sums.shape[0]
    have_h = False
    for j in range(n_seg - 1, -1, -1):  # the outermost segment first
        start = j * seg
        length = seg if j < n_seg - 1 else last
        streaming = stream and j == 0
        f = T + direction * start
        shared = share and length == seg and (j > 0 or not has_stops)
        slot = (f // seg) % n_slots
        if shared and sums_of[slot] != f:
            _segment_sums(quiet, f, seg, direction, offs, sums[slot])
            sums_of[slot] = f
        for vi in range(nv):
            out = row if streaming else g[vi]
            end = offs[vi, length] if have_h else offs[vi, length - 1]  # furthest reference step used
            if abs(end) >= nr:
                for r in range(nr):
                    out[r] = inf
            else:
                lo, hi = _span(end, nr, direction)
                width = hi - lo
                part = out[lo:hi]
                hs = direction * end
                if shared:
                    # the segment's sum, then the chain beyond it: the same adds in the same order
                    mine = sums[slot, vi, lo:hi]
                    if have_h:
                        beyond = h[vi, lo + hs:hi + hs]
                        for k in range(width):
                            part[k] = mine[k] + beyond[k]
                    else:
                        for k in range(width):
                            part[k] = mine[k]
                else:
                    first = et[f, lo:hi] if j == 0 else quiet[f, lo:hi]  # the anchor counts in full
                    for k in range(width):
                        part[k] = first[k]
                    # the segment's other frames, then the chain beyond it, added in that order
                    _accumulate(part, quiet, h, vi, length - 1, length - 1 + (1 if have_h else 0), T, direction,
                                start, lo, hi, offs, hs)
                if has_stops and vels[vi] == 0 and stop_cost > 0:
                    m = length if have_h else length - 1  # frame-to-frame steps it stands through
                    c = running[f + m] - running[f] if direction > 0 else running[f] - running[f - m]
                    add = np.float32(stop_cost * c)
                    for k in range(width):
                        part[k] += add
                if vels[vi] < 0 and reverse_cost > 0:
                    add = np.float32(reverse_cost * (length if have_h else length - 1))
                    for k in range(width):
                        part[k] += add
                for r in range(hi, nr):
                    out[r] = inf
                for r in range(0, lo):
                    out[r] = inf
            if streaming:
                for r in range(nr):
                    x = out[r] + back[vi, r]
                    if x < s[r]:
                        s[r] = x
            elif vi > 0 and (j > 0 or relax_first):
                _envelope_up(g, steps, vi)
        if j > 0 or (relax_first and not streaming):
            _envelope_down(g, steps)
        if j > 0:
            g, h = h, g
            have_h = True


@njit(cache=True, nogil=True)
def _rows(et: np.ndarray, quiet_back: np.ndarray, quiet_fwd: np.ndarray, running: np.ndarray, has_stops: bool,
          a: int, b: int, seg: int, before: int, after: int, vels: np.ndarray, offs: np.ndarray, steps: np.ndarray,
          stop_cost: float, reverse_cost: float, s: np.ndarray, c0: int, c1: int) -> None:
    """``s[T - a, :] = `` the scores of references ``c0..c1-1`` of ``et`` for anchors ``T = a..b-1``,
    every reference of ``et`` computed (the matrix's edges are its own). Anchors are taken
    ``seg`` apart (``a``, ``a + seg``, ..., then ``a + 1``, ...), so that each shares all
    but one of its segments' sums with the one before (:func:`_side`); each anchor's
    scores are its own, whatever the order."""
    nv, nr = len(vels), et.shape[1]
    inf = np.float32(np.inf)
    back = np.empty((nv, nr), np.float32)
    g = np.empty((nv, nr), np.float32)
    h = np.empty((nv, nr), np.float32)
    row = np.empty(nr, np.float32)
    acc = np.empty(nr, np.float32)
    n_back = (before + 1 + seg - 1) // seg
    n_fwd = (after + 1 + seg - 1) // seg
    seg_full = min(seg, max(before, after) + 1)  # a segment longer than both halves is never whole
    # kept sums pay where anchors `seg` apart follow one another; an anchor alone (the
    # shifted windows at the traverse's ends, collapse_stops' search) sums its segments
    # where it reads them, as it would every sum it keeps but once
    share = b - a >= 2 * seg_full
    kept = nr if share else 1
    sums_back = np.empty((n_back, nv if share else 1, kept), np.float32)
    sums_fwd = np.empty((n_fwd, nv if share else 1, kept), np.float32)
    sums_back_of = np.full(n_back, -1, np.int64)
    sums_fwd_of = np.full(n_fwd, -1, np.int64)
    # the backward half swaps its two buffers once per segment boundary: it ends in
    # `back` after an even number of swaps, else in `g`; the other one is free for the forward half
    even = (n_back - 1) % 2 == 0
    res = back if even else g
    free = g if even else back
    stride = min(seg_full, max(1, b - a))
    for r0 in range(stride):
        for T in range(a + r0, b, stride):
            # the backward half relaxed to its end (the forward half's first segment reads it)
            _side(et, quiet_back, running, has_stops, T, before + 1, seg, vels, offs, steps, -1, stop_cost,
                  reverse_cost, back, g, row, h, acc, False, True, share, sums_back, sums_back_of)
            for r in range(nr):
                acc[r] = inf
            _side(et, quiet_fwd, running, has_stops, T, after + 1, seg, vels, offs, steps, +1, stop_cost,
                  reverse_cost, free, h, row, res, acc, True, False, share, sums_fwd, sums_fwd_of)
            out = s[T - a]
            for r in range(c0, c1):
                out[r - c0] = acc[r] - et[T, r]  # the anchor frame was counted by both halves


@njit(cache=True, nogil=True)
def flexible_rows(et: np.ndarray, quiet_back: np.ndarray, quiet_fwd: np.ndarray, running: np.ndarray, has_stops: bool,
                  a: int, b: int, seg: int, before: int, after: int, vels: np.ndarray, offs: np.ndarray, steps: np.ndarray,
                  stop_cost: float, reverse_cost: float, s: np.ndarray, tile: int) -> None:
    """``s[T - a, r]`` for anchors ``T = a..b-1``: the cheapest flexible path through
    ``(T, r)`` over the window ``T - before .. T + after`` (``inf`` where none stays inside
    the matrix). ``vels`` ascending; ``offs[v, t] = round(vels[v] * t)``; ``steps``: the
    float32 cost of a change between neighbouring speeds; ``quiet_*``/``running``: the
    stop model's arrays (ignored unless ``has_stops``).

    References are taken ``tile`` at a time, every anchor of the chunk within a tile before
    the next tile, so the window's rows of a tile stay in the core's cache from one anchor
    to the next (121 rows of 35,768 references, 17 MB, do not: measured, twice the time per
    cell). A tile is computed with ``halo`` references on either side: each segment of the
    recursion reads the next one's result at most ``reach = max |round(v * seg)|``
    references away, so a value ``halo`` = reach x segments from the tile's cut is exact;
    those within it, treated as if the cut were the matrix's edge, are computed and dropped.
    Where the cut is the matrix's edge, it is the edge. Any tile gives the same scores."""
    nr = et.shape[1]
    reach = 0
    for vi in range(len(vels)):
        reach = max(reach, abs(offs[vi, min(seg, offs.shape[1] - 1)]))
    n_seg = max((before + 1 + seg - 1) // seg, (after + 1 + seg - 1) // seg)
    halo = reach * n_seg
    tile = max(1, tile)
    if tile + 2 * halo >= nr:
        _rows(et, quiet_back, quiet_fwd, running, has_stops, a, b, seg, before, after, vels, offs, steps, stop_cost,
              reverse_cost, s, 0, nr)
        return
    f0, f1 = a - before, b + after  # the rows the anchors' windows read
    for r0 in range(0, nr, tile):
        r1 = min(nr, r0 + tile)
        e0, e1 = max(0, r0 - halo), min(nr, r1 + halo)
        et_t = np.ascontiguousarray(et[f0:f1, e0:e1])
        qb_t = np.ascontiguousarray(quiet_back[f0:f1, e0:e1]) if has_stops else et_t
        qf_t = np.ascontiguousarray(quiet_fwd[f0:f1, e0:e1]) if has_stops else et_t
        run_t = running[f0:f1] if has_stops else running
        _rows(et_t, qb_t, qf_t, run_t, has_stops, a - f0, b - f0, seg, before, after, vels, offs, steps, stop_cost,
              reverse_cost, s[:, r0:r1], r0 - e0, r1 - e0)


def warm_up() -> None:
    """Load the compiled kernel (numba's import, its first dispatch and the cached machine
    code: about 0.7 s of Python holding the GIL) by scoring a 3 x 4 matrix with the argument
    types a search uses. ``sequence_match`` runs it on a thread while the first difference
    block is computed (its kernel releases the GIL), so the two overlap where there is a
    second core."""
    et = np.ones((3, 4), np.float32)
    vels = np.array([0.5, 1.0])
    offs = np.zeros((2, 3), np.int64)
    flexible_rows(et, et, et, np.zeros(1), False, 1, 2, 2, 1, 1, vels, offs, np.zeros(1, np.float32), 0.0, 0.0,
                  np.empty((1, 4), np.float32), 4096)
