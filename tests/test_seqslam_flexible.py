"""Known answers for the flexible sequence search: a path whose speed may change inside the window."""

from __future__ import annotations

import itertools
from typing import Callable

import numpy as np
import pytest

from placeloc.seqslam.matching import sequence_match
from placeloc.seqslam.search import (
    INVALID,
    REVERSE_COST,
    SPEED_CHANGE_COST,
    STOP_COST,
    UNRELATED_CHANGE,
    StopModel,
    _flexible_scores,
    flexible_model,
    query_offsets,
    segment_length,
    sequence_search,
    trajectory_offsets,
    velocities,
)


def _brute_flexible(et: np.ndarray, T: int, t_off: np.ndarray, vels: np.ndarray, cost: float, stop: float,
                    reverse: float = 0.0) -> np.ndarray:
    """Every chain of segment speeds written out, for every reference: the cheapest path
    through (T, r) (the definition the dynamic programme must reproduce). With 0 among the
    speeds, every frame but the anchor counts around its column's mean by its novelty (its
    change from the frame before it on the path, over that of two unrelated columns), and
    a segment that stands still pays ``stop`` per unit of the query's change meanwhile; one
    that drives backwards (a negative speed) pays ``reverse`` per frame-to-frame step."""
    nr = et.shape[1]
    seg = segment_length(vels)
    speeds = np.unique(vels)
    stops = (speeds == 0).any()  # standing still: frames count by their novelty
    before, after = -int(t_off[0]), int(t_off[-1])

    def change(f: int, g: int) -> float:
        return float(np.abs(et[f].astype(np.float64) - et[g]).mean())

    def chains(n_frames: int, d: int) -> list[tuple[float, np.ndarray, np.ndarray, np.ndarray, float]]:
        """(first speed, reference offsets, frames, still?, cost) of every chain on one side."""
        n_seg = -(-n_frames // seg)
        out = []
        for vs in itertools.product(speeds, repeat=n_seg):
            pos, still, back, p = [], [], [], 0
            for j, v in enumerate(vs):
                o = trajectory_offsets(np.array([v]), np.arange(seg + 1))[0]
                pos += [p + int(o[t]) for t in range(min(seg, n_frames - j * seg))]
                still += [v == 0] * min(seg, n_frames - j * seg)
                back += [v < 0] * min(seg, n_frames - j * seg)
                p += int(o[seg])
            frames = T + d * np.arange(n_frames)
            c = sum(abs(vs[j] - vs[j + 1]) for j in range(n_seg - 1)) * cost * seg
            # standing from each still frame to the next frame on the path (the next
            # segment's first frame included: it starts where a still segment ends)
            c += sum(stop * change(frames[t], frames[t + 1]) for t in range(n_frames - 1) if still[t])
            c += reverse * sum(1 for t in range(n_frames - 1) if back[t])
            out.append((vs[0], d * np.array(pos), frames, np.array(still), c))
        return out

    def values(frames: np.ndarray, refs: np.ndarray, still: np.ndarray) -> np.ndarray:
        """Sum over the path of each frame's value, (n_ref,) for refs (n_ref, n_frames)."""
        total = np.zeros(len(refs))
        for t, f in enumerate(frames):
            x = et[f, np.clip(refs[:, t], 0, nr - 1)].astype(np.float64)
            if stops and t > 0:
                w = min(1.0, change(f, frames[t - 1]) / UNRELATED_CHANGE)
                m = float(et[f].astype(np.float64).mean())
                x = m + w * (x - m)
            total += x
        return total

    s = np.full(nr, np.inf)
    r = np.arange(nr)[:, None]
    fwd_chains, back_chains = chains(after + 1, +1), chains(before + 1, -1)
    fwd_vals = [values(fr, r + p, st) for _, p, fr, st, _ in fwd_chains]
    back_vals = [values(fr, r + p, st) for _, p, fr, st, _ in back_chains]
    for (v1, p1, _, _, c1), x1 in zip(fwd_chains, fwd_vals):
        for (v2, p2, _, _, c2), x2 in zip(back_chains, back_vals):
            inside = np.concatenate([r + p1, r + p2], axis=1)
            ok = (inside.min(axis=1) >= 0) & (inside.max(axis=1) < nr)
            total = x1 + x2 - et[T] + c1 + c2 + cost * seg * abs(v1 - v2)
            s = np.where(ok, np.minimum(s, total), s)
    return s


# ---------------------------------------------------------------------------------------
# The flexible search in NumPy, as it shipped before it was compiled: the reference the
# compiled kernel (placeloc.seqslam.flexible) must reproduce bit for bit (same adds, same
# order, same float32 rounding), on chunks of anchors at once.
# ---------------------------------------------------------------------------------------

def _numpy_l1_envelope(g: np.ndarray, vels: np.ndarray, cost: float) -> np.ndarray:
    """In place, ``g[v] <- min_v' g[v'] + cost * |v - v'|`` over the first axis (velocities
    sorted ascending): two passes, as a distance transform, instead of all pairs."""
    tmp = np.empty_like(g[0])
    for i in range(1, len(vels)):
        np.add(g[i - 1], np.float32(cost * (vels[i] - vels[i - 1])), out=tmp)
        np.minimum(g[i], tmp, out=g[i])
    for i in range(len(vels) - 2, -1, -1):
        np.add(g[i + 1], np.float32(cost * (vels[i + 1] - vels[i])), out=tmp)
        np.minimum(g[i], tmp, out=g[i])
    return g


def _numpy_chain_side(et: np.ndarray, rows: tuple[int, int], n_frames: int, seg: int, vels: np.ndarray, bend_cost: float,
                direction: int, stops: StopModel | None, stop_cost: float, reverse_cost: float = 0.0,
                on_first: Callable[[int, np.ndarray], None] | None = None) -> np.ndarray | None:
    """Best path over ``n_frames`` query frames from the anchor ``(T, r)`` onwards
    (``direction`` +1: later queries, higher references; -1: earlier and lower), per first
    velocity: ``g[v, T - a, r]``. The path is a chain of straight segments of ``seg``
    frames (the last one shorter), each with its own velocity, each starting where the
    previous one's line ends (``round(v * seg)`` further); a change of velocity between
    segments costs ``bend_cost * |dv|``. Solved from the far end inwards (Viterbi over
    segments) for a chunk of anchors at once; inf where the path would leave the matrix.
    With ``stops`` (velocities that include 0), frames and standing still are scored as
    :class:`StopModel` says. A negative velocity drives backwards (the reference position
    falls as the query goes on) and pays ``reverse_cost`` for every frame-to-frame step it
    does so.
    With ``on_first``, the first segment's array of each velocity goes to
    ``on_first(v_index, array)`` (which may overwrite it) instead of being returned."""
    a, b = rows
    n, nr = b - a, et.shape[1]
    nv = len(vels)
    n_seg = -(-n_frames // seg)
    lengths = [seg] * (n_seg - 1) + [n_frames - (n_seg - 1) * seg]
    offs = trajectory_offsets(vels, np.arange(max(lengths) + 1, dtype=np.int64))  # round(v t), t >= 0
    quiet = et if stops is None else stops.quiet_fwd if direction > 0 else stops.quiet_back
    h = None
    g: np.ndarray | None = None
    for j in range(n_seg - 1, -1, -1):  # the outermost segment first
        start, length = j * seg, lengths[j]
        stream = j == 0 and on_first is not None
        g = np.empty((1 if stream else nv, n, nr), np.float32)
        for vi in range(nv):
            out = g[0 if stream else vi]
            o = offs[vi]
            src = quiet
            end = int(o[length]) if h is not None else int(o[length - 1])  # furthest reference step used
            if abs(end) >= nr:
                out[:] = INVALID
            else:
                # references whose line stays inside the matrix (it runs from 0 to `end`)
                lo, hi = (max(0, -end), nr - max(0, end)) if direction > 0 else (max(0, end), nr + min(0, end))
                part = out[:, lo:hi]
                f = a + direction * start
                np.copyto(part, (et if j == 0 else src)[f:f + n, lo:hi])  # the anchor counts in full
                for t in range(1, length):
                    f, sh = a + direction * (start + t), direction * int(o[t])
                    part += src[f:f + n, lo + sh:hi + sh]
                if h is not None:
                    sh = direction * end
                    part += h[vi, :, lo + sh:hi + sh]
                if stops is not None and vels[vi] == 0 and stop_cost > 0:
                    m = length if h is not None else length - 1  # frame-to-frame steps it stands through
                    f = a + direction * start
                    run = stops.running
                    c = run[f + m:f + m + n] - run[f:f + n] if direction > 0 else run[f:f + n] - run[f - m:f - m + n]
                    part += (stop_cost * c).astype(np.float32)[:, None]
                if vels[vi] < 0 and reverse_cost > 0:
                    part += np.float32(reverse_cost * (length if h is not None else length - 1))
                out[:, hi:] = INVALID
                out[:, :lo] = INVALID
            if stream:
                on_first(vi, out)
        if j > 0:
            h = _numpy_l1_envelope(g, vels, bend_cost)
    return None if on_first is not None else g


def _numpy_flexible_scores(et: np.ndarray, rows: tuple[int, int], t_off: np.ndarray, vels: np.ndarray,
                     speed_change_cost: float = SPEED_CHANGE_COST, stop_cost: float = STOP_COST,
                     stops: StopModel | None = None, reverse_cost: float = REVERSE_COST) -> np.ndarray:
    """``s[q, r]``: the cheapest path through ``(T, r)`` over the window ``T + t_off``
    whose speed may change every :func:`segment_length` frames, within the velocity bounds
    ``vels``, at ``speed_change_cost`` per frame of bend. With 0 among ``vels`` it may also
    stand still where the query does (:class:`StopModel`, ``stop_cost``); otherwise every
    frame counts as it is. Negative ``vels`` let it drive backwards, at ``reverse_cost``
    per frame. The window's two halves meet at the anchor:
    backward from it (per velocity, relaxed by the cost of a change), then forward from
    it, one velocity at a time, with a change of speed at the anchor costed like any other."""
    a, b = rows
    seg, vels, stops, bend, before, after = flexible_model(et, t_off, vels, speed_change_cost, stops)
    back = _numpy_chain_side(et, rows, before + 1, seg, vels, bend, -1, stops, float(stop_cost), float(reverse_cost))
    _numpy_l1_envelope(back, vels, bend)
    s = np.full((b - a, et.shape[1]), INVALID, np.float32)

    def take(vi: int, fwd: np.ndarray) -> None:
        fwd += back[vi]
        np.minimum(s, fwd, out=s)

    _numpy_chain_side(et, rows, after + 1, seg, vels, bend, +1, stops, float(stop_cost), float(reverse_cost), on_first=take)
    s -= et[a:b]  # the anchor frame was counted by both halves
    return s


@pytest.mark.parametrize("search,ds,v_min", [("centred", 8, 0.0), ("causal", 5, 0.0), ("centred", 5, 0.0),
                                             ("centred", 8, 0.5), ("centred", 6, -1.0), ("causal", 5, -0.5)])
def test_dynamic_programme_equals_every_chain_written_out(search, ds, v_min):
    rng = np.random.default_rng(0)
    et = rng.random((14, 20)).astype(np.float32)
    et[5] = et[4]  # the query stands still for a frame
    vels = velocities(v_min, 1.5, 0.5)  # segments of 2 frames; with v_min 0 standing still
    t_off = query_offsets(ds, search)
    rows = (-int(t_off[0]), 14 - int(t_off[-1]))
    s = _flexible_scores(et, rows, t_off, vels, 0.3, 0.7, reverse_cost=0.4)
    for T in range(*rows):
        np.testing.assert_allclose(s[T - rows[0]], _brute_flexible(et, T, t_off, vels, 0.3, 0.7, 0.4), rtol=1e-5)


def _planted(speeds: np.ndarray, n_ref: int, seed: int, gone: np.ndarray | None = None,
             snr: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """D (query-major) with the path a query moving at ``speeds`` traces planted in it:
    zeros in uniform 0.6-1.0 noise, or (``snr``) Gaussian noise lowered by ``snr`` standard
    deviations on the path, as enhanced real differences look. A query that has not moved
    since its last frame sees that frame again (its column repeats). Queries in ``gone``
    (a detour) see nothing of the reference."""
    rng = np.random.default_rng(seed)
    path = 20 + np.floor(np.concatenate([[0.0], np.cumsum(speeds[:-1])]) + 0.5).astype(np.int64)
    seen = np.flatnonzero(np.ones(len(speeds), bool) if gone is None else ~gone)
    if snr is None:
        et = rng.uniform(0.6, 1.0, (len(speeds), n_ref)).astype(np.float32)
        et[seen, path[seen]] = 0.0
    else:
        et = (rng.normal(0, 1, (len(speeds), n_ref)) + 4).astype(np.float32)
        et[seen, path[seen]] -= snr
    for q in range(1, len(speeds)):
        if path[q] == path[q - 1] and (gone is None or gone[q] == gone[q - 1]):
            et[q] = et[q - 1]
    return et, path


def _search(et: np.ndarray, shape: str, vels: np.ndarray, ds: int = 20) -> np.ndarray:
    best, _ = sequence_search(et, 0, len(et), ds, vels, "centred", 5, 2, None, 0, shape=shape, edges="shift")
    return best[:, 0]


# speed steps, a stop of 50 frames, a 0.5x and a 2x stretch: all inside one route
SPEEDS = np.concatenate([np.full(60, 1.0), np.full(50, 2.0), np.zeros(50), np.full(80, 0.5), np.full(60, 1.5),
                         np.full(60, 1.0)])


def test_flexible_follows_speed_steps_a_stop_and_half_and_double_speed():
    et, path = _planted(SPEEDS, 420, seed=1)
    flexible = _search(et, "flexible", velocities(0.0, 2.0, 0.1))
    # every query, through the steps and the stop, lands within one frame of its place
    # (fractional speeds are rounded along the segment, so one frame is the resolution)
    assert np.abs(flexible - path).max() <= 1
    assert (flexible == path).mean() > 0.95


def test_flexible_beats_straight_lines_when_the_path_is_faint():
    # the path 1.5 standard deviations below the noise and a speed that changes every 30
    # frames, under a 61-frame window: a straight line collects the evidence of one
    # stretch, a bending path that of the whole window
    speeds = np.repeat([1.0, 2.0, 0.5, 1.5, 0.7, 1.8, 1.0, 0.5, 2.0, 1.2, 0.6, 1.6], 30)
    et, path = _planted(speeds, int(speeds.sum()) + 60, seed=2, snr=1.5)
    flexible = _search(et, "flexible", velocities(0.5, 2.0, 0.1), ds=60)
    line = _search(et, "trajectory", velocities(0.5, 2.0, 0.1), ds=60)
    assert (np.abs(flexible - path) <= 2).mean() >= 0.93
    assert (np.abs(line - path) <= 2).mean() <= 0.80


def test_flexible_stands_still_through_a_stop_only_when_zero_speed_is_allowed():
    speeds = np.concatenate([np.full(40, 1.0), np.zeros(50), np.full(40, 1.0)])
    et, path = _planted(speeds, 200, seed=2)
    assert np.abs(_search(et, "flexible", velocities(0.0, 1.5, 0.1)) - path).max() <= 1
    moving = _search(et, "flexible", velocities(0.5, 1.5, 0.1))
    assert (np.abs(moving - path) > 2).sum() >= 10  # cannot stop: drifts during the stop


def test_flexible_rejoins_after_a_detour_that_leaves_the_reference():
    # 15 query frames off the route, coming back to where it left (a loop round a block)
    speeds = np.concatenate([np.full(80, 1.0), np.zeros(15), np.full(80, 1.0)])
    gone = np.zeros(len(speeds), bool)
    gone[81:95] = True
    et, path = _planted(speeds, 220, seed=3, gone=gone)
    on_route = ~gone
    flexible = _search(et, "flexible", velocities(0.0, 2.0, 0.1))
    # every query on the route, those whose window spans the detour included
    assert np.abs(flexible - path)[on_route].max() <= 1


def test_steady_speed_scores_as_the_straight_line_does():
    # at one constant speed the best flexible path is the straight line: same matches, same scores
    et, path = _planted(np.full(150, 1.0), 200, seed=4)
    vels = velocities(0.8, 1.2, 0.1)
    kw = dict(window=5, k=2, exclude_recent=None, query_index0=0, edges="skip")
    fb, fs = sequence_search(et, 0, 150, 20, vels, "centred", shape="flexible", **kw)
    tb, ts = sequence_search(et, 0, 150, 20, vels, "centred", shape="trajectory", **kw)
    inside = np.arange(10, 140)
    np.testing.assert_array_equal(fb[inside, 0], path[inside])
    np.testing.assert_array_equal(tb[inside, 0], path[inside])
    assert (fs[inside, 0] == 0).all() and (ts[inside, 0] == 0).all()
    assert (fb[:10] == -1).all()  # edges skipped as for every shape


def test_flexible_chunks_and_edges_agree_with_one_query_at_a_time():
    rng = np.random.default_rng(5)
    et = rng.random((70, 90)).astype(np.float32)
    vels = velocities(0.0, 2.0, 0.25)
    t_off = query_offsets(12, "centred")
    best, scores = sequence_search(et, 0, 70, 12, vels, "centred", 3, 3, None, 0, shape="flexible", edges="shift")
    for T in (0, 3, 6, 30, 63, 69):
        sh = 0
        if T + t_off[0] < 0:
            sh = -(T + int(t_off[0]))
        elif T + t_off[-1] > 69:
            sh = 69 - (T + int(t_off[-1]))
        s = _flexible_scores(et, (T, T + 1), t_off + sh, vels, 0.5)[0]
        assert best[T, 0] == int(np.argmin(s))
        assert scores[T, 0] == pytest.approx(float(s.min()), rel=1e-5)


@pytest.mark.parametrize("v_min", [0.0, 0.5])
def test_block_size_never_changes_a_flexible_result(v_min):
    # the stop model measures each frame's novelty inside its own window, so cutting the
    # queries into blocks (localize, evaluate) gives the same matches and scores
    rng = np.random.default_rng(6)
    ref = rng.integers(0, 256, (120, 32), dtype=np.uint8)
    places = np.repeat(np.arange(10, 110, 2), 2)[:90]  # half speed: every frame twice
    query = np.clip(ref[places].astype(int) + rng.integers(-40, 41, (len(places), 32)), 0, 255).astype(np.uint8)
    common = dict(comparison="sad", enhance_window=4, ds=16, v_min=v_min, v_max=1.5, v_step=0.25, v_auto=False,
                  search="centred", sequence_shape="flexible", edges="shift", top_k=3, exclude_recent=None)
    one = sequence_match(ref, query, block_size=1000, **common)
    cut = sequence_match(ref, query, block_size=20, **common)
    np.testing.assert_array_equal(one.candidates, cut.candidates)
    np.testing.assert_array_equal(one.scores, cut.scores)
    assert (np.abs(one.candidates[:, 0] - places) <= 2).mean() > 0.9


@pytest.mark.parametrize("v_min,v_max,v_step,v_reverse,search,ds", [
    (0.5, 2.0, 0.1, 0.0, "centred", 30),  # the Nordland preset's shape: moving only
    (0.0, 2.0, 0.25, 0.0, "centred", 21),  # standing still (the stop model)
    (0.3, 1.5, 0.3, 1.0, "causal", 17),  # backwards too
    (1.0, 1.0, 0.1, 0.0, "centred", 9),  # one speed: one segment a side
    (0.0, 1.0, 0.5, 0.5, "centred", 6),  # everything, short segments
])
def test_compiled_kernel_is_bit_identical_to_the_numpy_formulation(v_min, v_max, v_step, v_reverse, search, ds):
    rng = np.random.default_rng(11)
    et = (rng.normal(0, 1, (90, 130)) + 3).astype(np.float32)
    et[40:48] = et[39]  # a stop, so the stop model has something to do
    vels = velocities(v_min, v_max, v_step, v_reverse)
    t_off = query_offsets(ds, search)
    rows = (-int(t_off[0]), 90 - int(t_off[-1]))
    for costs in [(SPEED_CHANGE_COST, STOP_COST, REVERSE_COST), (0.3, 0.7, 0.4), (0.0, 0.0, 0.0)]:
        compiled = _flexible_scores(et, rows, t_off, vels, *costs[:2], reverse_cost=costs[2])
        numpy = _numpy_flexible_scores(et, rows, t_off, vels, *costs[:2], reverse_cost=costs[2])
        assert np.isfinite(compiled).any()
        np.testing.assert_array_equal(compiled, numpy)
        one = _flexible_scores(et, (rows[0] + 3, rows[0] + 4), t_off, vels, *costs[:2], reverse_cost=costs[2])
        np.testing.assert_array_equal(one[0], numpy[3])  # a row does not depend on its chunk
        for tile in (1, 7, 33, 129):  # nor on the tile of references (a tile narrower than its reach included)
            tiled = _flexible_scores(et, rows, t_off, vels, *costs[:2], reverse_cost=costs[2], tile=tile)
            np.testing.assert_array_equal(tiled, numpy)


@pytest.mark.parametrize("vels", [
    np.round(velocities(0.3, 4.0, 0.1) * 0.93, 9),  # the Nordland preset's speeds, as v_auto scales them
    -velocities(0.3, 1.5, 0.1)[::-1],  # backward_paths' family
    velocities(0.0, 2.0, 0.1),  # standing still: the anchor's own segment is summed afresh
    velocities(0.3, 1.5, 0.1, 1.0),  # backwards and forwards in one path
])
def test_segment_sums_kept_between_anchors_give_the_same_bits(vels):
    # the preset's window (ds 120, centred): anchors a segment apart share all but one of
    # their segments' sums (placeloc.seqslam.flexible keeps them); a chunk of 50 anchors
    # reads kept sums for every anchor but the first of each residue, one anchor alone
    # sums its own; both must be the NumPy formulation's bits
    rng = np.random.default_rng(13)
    et = (rng.normal(0, 1, (171, 500)) + 3).astype(np.float32)
    et[80:95] = et[79]  # a stop, so the stop model has something to do
    t_off = query_offsets(120, "centred")
    rows = (60, 110)
    numpy = _numpy_flexible_scores(et, rows, t_off, vels, reverse_cost=0.3)
    assert np.isfinite(numpy).mean() > 0.2
    np.testing.assert_array_equal(_flexible_scores(et, rows, t_off, vels, reverse_cost=0.3), numpy)
    for T in (60, 71, 109):
        alone = _flexible_scores(et, (T, T + 1), t_off, vels, reverse_cost=0.3)
        np.testing.assert_array_equal(alone[0], numpy[T - rows[0]])
    tiled = _flexible_scores(et, rows, t_off, vels, reverse_cost=0.3, tile=64)
    np.testing.assert_array_equal(tiled, numpy)


def test_flexible_chunks_one_per_thread_within_the_byte_limit():
    from placeloc.seqslam.search import FLEXIBLE_CHUNK_BYTES, flexible_chunks

    # 1024 anchors of 3576 references on 2 threads: two chunks of 512 (7.3 MB of scores each)
    assert flexible_chunks(1024, 3576, threads=2) == [(0, 512), (512, 1024)]
    # at 35,768 references the chunk's scores stay within the limit: 117 anchors
    chunks = flexible_chunks(1024, 35768, threads=2)
    assert max(hi - lo for lo, hi in chunks) == FLEXIBLE_CHUNK_BYTES // (4 * 35768) == 117
    # every anchor once, in order, whatever the split
    for n, cols, threads in [(1024, 35768, 2), (7, 100, 16), (1, 10, 1), (1000, 3576, 3)]:
        chunks = flexible_chunks(n, cols, threads)
        assert [i for lo, hi in chunks for i in range(lo, hi)] == list(range(n))
        assert len(chunks) >= min(n, threads)
