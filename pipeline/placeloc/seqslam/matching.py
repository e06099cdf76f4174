"""SeqSLAM's localize step on feature rows: difference matrix -> enhancement -> sequence search.

The difference matrix is computed block by block (query columns), each block with the
``before``/``after`` query columns a sequence window needs on either side, so memory is
bounded by ``block_size`` whatever the traverse length. Every block is enhanced and
searched as soon as it arrives; ``on_difference`` receives its raw columns (the stage
writes them to ``localize.h5``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from placeloc.core.imagework import local_to_original
from placeloc.seqslam.comparisons import L1_COMPARISONS, difference_block, mean_abs_difference
from placeloc.seqslam.l1 import run_threaded
from placeloc.seqslam.search import (
    REVERSE_COST,
    SPEED_CHANGE_COST,
    STOP_COST,
    confidence,
    enhance_t,
    query_offsets,
    row_chunks,
    sequence_search,
    single_image_best,
    velocities,
)

# (fn, jobs, shared, describe) -> results in job order; the executor's map has this shape.
MapBlocks = Callable[..., Iterator[Any]]


@dataclass
class SequenceMatches:
    """Per query (positions in the feature lists): ``candidates``/``scores`` (n, k) ranked
    sequence matches, ``confidence`` of the best, and the single-image baseline."""

    candidates: np.ndarray
    scores: np.ndarray
    confidence: np.ndarray
    single_best: np.ndarray
    single_confidence: np.ndarray
    velocities: np.ndarray
    # the plain ranking (no separation between candidates), when asked for with ``plain_k``
    plain_candidates: np.ndarray | None = None
    plain_scores: np.ndarray | None = None


def difference_job(job: tuple[tuple[int, int, int, int], np.ndarray, str], ref: np.ndarray) -> np.ndarray:
    """One difference-matrix block (runs in a worker), query-major: ``Dt[q, r]`` of shape
    (hi - lo, n_ref); ``ref`` is shared."""
    _, query_block, comparison = job
    return difference_block_t(ref, query_block, comparison)


def difference_block_t(ref: np.ndarray, query: np.ndarray, comparison: str) -> np.ndarray:
    """``difference_block(ref, query, comparison).T``, C-contiguous: the query-major block
    the enhancement and the search read. The L1 comparisons compute it in that order
    directly (their sums are exact integers, so either order gives the same bits); the
    others are transposed a band of rows per thread. At 3576 x 3576 the copy was 0.07 s of
    one core's localize."""
    if comparison in L1_COMPARISONS:
        return mean_abs_difference(query, ref)
    return _transposed(difference_block(ref, query, comparison))


def auto_velocity_scale(n_reference: int, n_query: int) -> float:
    """Reference frames per query frame if both traverses cover the same route: a query
    recorded at half the frame rate (half as many frames) moves 2 references per frame."""
    return n_reference / max(1, n_query)


def search_velocities(v_min: float, v_max: float, v_step: float, v_auto: bool, n_reference: int,
                      n_query: int, v_reverse: float = 0.0) -> np.ndarray:
    """The velocities the sequence search tries (scaled by :func:`auto_velocity_scale` with ``v_auto``)."""
    vels = velocities(v_min, v_max, v_step, v_reverse)
    return np.round(vels * auto_velocity_scale(n_reference, n_query), 9) if v_auto else vels


# A frame of a traverse stands (shows the same place as the frame that opened its run)
# when it differs from that frame by less than STILL_FRACTION of a moving frame's change,
# the MOVING_QUANTILE of the traverse's own frame-to-frame changes. A camera at rest differs from its
# last frame by noise only, a moving one by content: on nordland-dev (SAD, z-score
# patches) standing pairs change 0.03-0.05 and moving ones 0.6-1.0, so the cut (about
# 0.25) has a factor of 2.4 to the slowest moving pair and 5 to the busiest standing
# one. The quantile is high so that the scale stays a moving frame's while up to 90 % of
# the traverse stands (a median would fall into the stops once half the frames stand); a
# traverse that never moves gives a scale of 0 and nothing is collapsed.
STILL_FRACTION = 0.25
MOVING_QUANTILE = 0.9


def frame_changes(features: np.ndarray, comparison: str, chunk: int = 32) -> np.ndarray:
    """``change[i]``: the comparison's difference between frames ``i - 1`` and ``i`` of one
    traverse (``change[0]`` = inf), from the diagonal of small difference blocks."""
    n = len(features)
    change = np.full(n, np.inf)
    for i in range(1, n, chunk):
        j = min(n, i + chunk)
        change[i:j] = np.diagonal(difference_block(features[i - 1:j - 1], features[i:j], comparison))
    return change


def standing_runs(features: np.ndarray, comparison: str) -> tuple[np.ndarray, np.ndarray]:
    """One traverse with every standing run collapsed to its first frame: ``first`` (the
    frames kept, ascending) and ``run_of`` (per frame, the position in ``first`` of the
    frame whose match it takes). A run grows while each next frame stays within the
    still threshold of the run's *first* frame (:data:`STILL_FRACTION`), so a slow crawl
    whose frames drift a little each never collapses into one frame."""
    n = len(features)
    change = frame_changes(features, comparison)
    if n < 2:
        return np.arange(n), np.arange(n)
    threshold = STILL_FRACTION * float(np.quantile(change[1:], MOVING_QUANTILE))
    opens = change >= threshold  # frame 0 opens the first run (its change is inf)
    still = np.flatnonzero(~opens)
    i = 0
    while i < len(still):
        # a stretch of frames each close to the one before: check them against the run's first frame
        j = i
        while j + 1 < len(still) and still[j + 1] == still[j] + 1:
            j += 1
        start, stop = int(still[i]) - 1, int(still[j]) + 1
        while start + 1 < stop:
            d = difference_block(features[start:start + 1], features[start + 1:stop], comparison)[0]
            far = np.flatnonzero(d >= threshold)
            if len(far) == 0:
                break
            start = start + 1 + int(far[0])  # drifted too far: a new run opens here
            opens[start] = True
        i = j + 1
    first = np.flatnonzero(opens)
    return first, np.cumsum(opens) - 1


def stop_answers(full_best: np.ndarray, stop_best: np.ndarray, first: np.ndarray, run_of: np.ndarray,
                 ref_run_of: np.ndarray) -> np.ndarray:
    """Which query frames take the collapsed search's answer (``collapse_stops``): the
    frames a standing run repeats (not its first frame, which keeps its own answer: the
    traverses' runs may open a frame apart, and that frame may still be moving in the
    other), where

    - the run's answer ``stop_best`` (per query frame, original reference frames) lies
      between the full search's answers ``full_best`` at the run's first frame and at the
      frame after the run (the traverse's last frame for a run that ends it): a stopped
      vehicle is where it arrived and where it leaves from. A stop the query makes alone
      is bracketed so (the full search gets the frames around a stop right, the collapsed
      one the stop); where the query only looks still while it moves (backing out or
      bursting through a station) the collapsed answer leaves the bracket;
    - and a reference frame that moves (a run of one frame, ``ref_run_of``: per reference
      frame, its run among the reference's standing runs, :func:`standing_runs`) lies
      between the frame's own full answer and the collapsed one. Where nothing but
      standing reference lies between them (the same run, neighbouring runs, or runs of a
      station that one traverse splits in two), the two show the same place, and the full
      answer is the finer one: inside a station where both traverses stand it is the
      synchronous frame, where the collapsed answer is the station's first (or the kept
      frame just before it, where the query's run opens a frame early: nordland-dev's
      winter run opens at 249, the summer one at 250). Where the reference moves, the
      full answer keeps to within one frame of the collapsed one or gives way.

    A run with no full answer (-1) at either end has no bracket and keeps the full
    answers; a repeated frame with none of its own takes a bracketed collapsed answer."""
    n = len(run_of)
    repeats = first[run_of] != np.arange(n)
    a = full_best[first[run_of]]
    b = full_best[np.append(first[1:], n - 1)[run_of]]
    # moving[k]: reference runs of one frame among runs 0..k-1
    moving = np.concatenate([[0], np.cumsum(np.bincount(ref_run_of) == 1)])
    k_full, k_stop = ref_run_of[np.maximum(full_best, 0)], ref_run_of[np.maximum(stop_best, 0)]
    lo, hi = np.minimum(k_full, k_stop), np.maximum(k_full, k_stop)
    moving_between = moving[np.maximum(hi, lo + 1)] - moving[lo + 1]  # runs lo+1..hi-1; 0 where hi - lo <= 1
    agree = (full_best >= 0) & (moving_between == 0)
    return (repeats & (a >= 0) & (b >= 0) & (stop_best >= np.minimum(a, b)) & (stop_best <= np.maximum(a, b))
            & ~agree)


def window_columns(c0: int, c1: int, n: int, before: int, after: int) -> tuple[int, int]:
    """The columns ``lo:hi`` (of ``n``) the windows of queries ``c0:c1`` read: ``before``/
    ``after`` on either side and, near a traverse end, at least the ``before + after + 1``
    frames nearest it, which a shifted window (``edges: shift``) uses there."""
    n_window = before + after + 1
    return max(0, min(c0 - before, n - n_window)), min(n, max(c1 + after, n_window))


def block_spans(n_q: int, block: int, before: int, after: int) -> list[tuple[int, int, int, int]]:
    """``(c0, c1, lo, hi)`` per block of at most ``block`` query columns ``c0:c1``, with the
    columns ``lo:hi`` their windows read (:func:`window_columns`). Without the frames a
    shifted window needs, a last block shorter than a window could not shift its queries'
    windows and left them unmatched (1056 queries with block_size 1024 and ds 120 left
    32), so ``block_size`` changed results."""
    spans = []
    for c0 in range(0, n_q, block):
        c1 = min(n_q, c0 + block)
        spans.append((c0, c1, *window_columns(c0, c1, n_q, before, after)))
    return spans


def collapsed_groups(run_of: np.ndarray, n_kept: int, before: int, after: int,
                     block_size: int) -> list[tuple[np.ndarray, int, int]]:
    """The kept frames :func:`collapsed_answers` searches (those that stand for others) in
    groups: consecutive ones whose windows overlap, spanning fewer than ``block_size``
    kept frames; each with the kept columns ``lo:hi`` its windows read
    (:func:`window_columns`)."""
    need = np.flatnonzero(np.bincount(run_of, minlength=n_kept) > 1)
    n_window = before + after + 1
    groups = []
    i = 0
    while i < len(need):
        j = i
        while j + 1 < len(need) and need[j + 1] - need[j] <= n_window and need[j + 1] - need[i] < block_size:
            j += 1
        groups.append((need[i:j + 1], *window_columns(int(need[i]), int(need[j]) + 1, n_kept, before, after)))
        i = j + 1
    return groups


def _inline_map(fn: Callable, jobs: Iterable, shared: Any = None, describe: Any = None) -> Iterator[Any]:
    for job in jobs:
        yield fn(job, shared)


# Per block, between the threaded kernels, the query-major copy of D and the single-image
# baseline ran on one thread: 0.27 s and 0.09 s a block of 1024 queries at 35,768 references
# (12.6 s over the whole route), which 16 cores would wait for. Both go by rows over the cores.
def _transposed(d: np.ndarray) -> np.ndarray:
    """``np.ascontiguousarray(d.T)``, copied a band of rows per thread (NumPy's copy releases the GIL)."""
    out = np.empty((d.shape[1], d.shape[0]), d.dtype)

    def copy(lo: int, hi: int) -> None:
        out[lo:hi] = d[:, lo:hi].T

    run_threaded(copy, row_chunks(*out.shape))
    return out


def _single_best_into(dt: np.ndarray, window: int, exclude_recent: int | None, q0: int, best: np.ndarray,
                      conf: np.ndarray) -> None:
    """:func:`placeloc.seqslam.search.single_image_best` of the rows of ``dt`` (query ``q0``
    first) into ``best`` and ``conf``, a band of rows per thread (rows are independent)."""
    def part(lo: int, hi: int) -> None:
        best[lo:hi], conf[lo:hi] = single_image_best(dt[lo:hi], window, exclude_recent, q0 + lo)

    run_threaded(part, row_chunks(*dt.shape))


def _load_kernels_meanwhile(flexible: bool) -> None:
    """Load the compiled kernels on a thread while the first difference block is computed:
    the enhancement's, the search's and the ranking's (llvmlite's library and the cached
    machine code, 40-90 ms, which a comparison other than the L1 ones does not load
    before), and with ``flexible`` numba's flexible search (about 0.7 s). Measured on 2
    cores (Nordland preset, 3576 x 3576, ``placeloc localize`` as a process, three runs
    each, load about 1): 5.37-5.57 s wall with, 5.53-5.69 s without."""
    import threading

    def load() -> None:
        try:  # the searches load them again and report what fails
            from placeloc.seqslam.row_kernels import warm_up

            warm_up()
            if flexible:  # numba's import too happens here, off the main thread
                from placeloc.seqslam.flexible import warm_up as warm_up_flexible

                warm_up_flexible()
        except Exception:  # noqa: BLE001
            pass

    threading.Thread(target=load, name="placeloc-load-kernels", daemon=True).start()


def sequence_match(
    ref: np.ndarray,
    query: np.ndarray,
    *,
    comparison: str,
    enhance_window: int,
    ds: int,
    v_min: float,
    v_max: float,
    v_step: float,
    v_auto: bool,
    search: str,
    sequence_shape: str,
    edges: str,
    top_k: int,
    speed_change_cost: float = SPEED_CHANGE_COST,
    stop_cost: float = STOP_COST,
    reverse_cost: float = REVERSE_COST,
    v_reverse: float = 0.0,
    collapse_stops: bool = False,
    backward_paths: bool = False,
    backward_v_max: float = math.inf,
    exclude_recent: int | None,
    block_size: int,
    map_blocks: MapBlocks | None = None,
    on_difference: Callable[[int, int, np.ndarray], None] | None = None,
    on_enhanced: Callable[[int, int, np.ndarray], None] | None = None,
    progress: Callable[..., Iterable] | None = None,
    plain_k: int = 0,
) -> SequenceMatches:
    """Match every query row against the reference rows (features from ``extract``).

    ``v_auto`` scales the velocities by :func:`auto_velocity_scale`. The costs shape the
    ``flexible`` path (:class:`placeloc.seqslam.params.SeqSLAMParams`); ``backward_paths``
    adds the family of paths that drive backwards throughout (see
    :func:`placeloc.seqslam.search.sequence_search`), at the speeds up to
    ``backward_v_max`` (after ``v_auto``'s scaling, which the limit itself does not take:
    see :class:`placeloc.seqslam.params.SeqSLAMParams`). ``collapse_stops``: after the search
    over every frame, the query's standing runs (:func:`standing_runs`) are searched
    again with both traverses' runs collapsed (:func:`collapsed_answers`), and the frames
    a run repeats take that answer where :func:`stop_answers` finds it between the first
    search's answers around the run and a moving reference frame lies between it and
    the frame's own. The repeated frames of a stop carry no new evidence
    of place; without them the sequence on either side of a query's stop is one window.
    The second search takes the differences it reads from the full search's blocks as
    they pass (:class:`CollapsedSearch`). ``exclude_recent`` is for loop closure (``query is ref``): references within
    that many frames before the query are ignored; ``None`` otherwise (and
    ``collapse_stops`` must then be off: the exclusion counts the traverse's own frames). ``map_blocks`` runs the difference blocks
    (default: in this process); ``on_difference(c0, c1, d)`` gets the raw difference
    columns of queries ``c0:c1`` as they are computed (a view, reference-major);
    ``on_enhanced(c0, c1, e)`` their enhanced rows, query-major. ``plain_k`` > 0 also ranks the ``plain_k`` best references
    with no separation (the standard Recall@N), from the same sequence scores.
    """
    if collapse_stops and exclude_recent is not None:
        raise ValueError("collapse_stops needs a query traverse: loop closure's exclude_recent counts its frames")
    n_q = len(query)
    window, k, block = int(enhance_window), int(top_k), int(block_size)
    vels = search_velocities(v_min, v_max, v_step, v_auto, len(ref), n_q, v_reverse)
    t_off = query_offsets(int(ds), search)
    before, after = int(-t_off.min()), int(t_off.max())
    candidates = np.full((n_q, k), -1, np.int64)
    scores = np.full((n_q, k), np.inf, np.float32)
    single_best = np.full(n_q, -1, np.int64)
    single_conf = np.zeros(n_q, np.float64)
    plain = (np.full((n_q, plain_k), -1, np.int64), np.full((n_q, plain_k), np.inf, np.float32)) if plain_k > 0 else None
    spans = block_spans(n_q, block, before, after)
    # collapse_stops: the query's standing runs are known from its features alone, so its
    # second search takes the differences it reads from the full search's blocks as they
    # pass, and searches each group of kept frames once all of them have passed
    collapsed: CollapsedSearch | None = None
    ref_run_of = np.zeros(0, np.int64)
    if collapse_stops:
        first, run_of = standing_runs(query, comparison)
        if (np.bincount(run_of, minlength=len(first)) > 1).any():
            ref_first, ref_run_of = standing_runs(ref, comparison)
            collapsed = collapsed_search(ref, query, first, run_of, ref_first, comparison=comparison,
                                         enhance_window=window, ds=ds, v_min=v_min, v_max=v_max, v_step=v_step,
                                         v_auto=v_auto, search=search, sequence_shape=sequence_shape, edges=edges,
                                         top_k=k, speed_change_cost=speed_change_cost, stop_cost=stop_cost,
                                         reverse_cost=reverse_cost, v_reverse=v_reverse, block_size=block,
                                         plain_k=plain_k)
    _load_kernels_meanwhile(flexible=sequence_shape == "flexible")
    # D blocks run on the executor (ref shipped once as shared; query rows taken lazily, views inline);
    # enhancement, search and writing stay here, in order.
    jobs = ((span, query[span[2]:span[3]], comparison) for span in spans)
    blocks = (map_blocks or _inline_map)(difference_job, jobs, shared=ref,
                                         describe=lambda job: f"difference block, query columns {job[0][2]}:{job[0][3]}")
    # blocks first in zip: its exhaustion runs the executor's clean-up (release the shared input).
    pairs: Iterable = zip(blocks, spans)
    if progress is not None:
        pairs = progress(pairs, total=len(spans), desc="localize blocks")
    for dt, (c0, c1, lo, _hi) in pairs:
        s0, s1 = c0 - lo, c1 - lo
        if on_difference is not None:
            on_difference(c0, c1, dt[s0:s1].T)
        # single-image baseline on the raw differences
        _single_best_into(dt[s0:s1], window, exclude_recent, c0, single_best[c0:c1], single_conf[c0:c1])
        if collapsed is not None:
            collapsed.take(lo, dt)
        et = enhance_t(dt, window)
        del dt
        if on_enhanced is not None:
            on_enhanced(c0, c1, et[s0:s1])
        b, s = sequence_search(et, s0, s1, int(ds), vels, search, window, k, exclude_recent, lo,
                               shape=sequence_shape, edges=edges, speed_change_cost=speed_change_cost,
                               stop_cost=stop_cost, reverse_cost=reverse_cost, backward_paths=backward_paths,
                               backward_v_max=backward_v_max,
                               plain=None if plain is None else (plain[0][c0:c1], plain[1][c0:c1]))
        candidates[c0:c1], scores[c0:c1] = b, s
    conf = confidence(scores)
    if collapsed is not None:
        stop = collapsed.answers()
        take = stop_answers(candidates[:, 0], stop.candidates[:, 0], collapsed.first, collapsed.run_of, ref_run_of)
        candidates[take], scores[take], conf[take] = stop.candidates[take], stop.scores[take], stop.confidence[take]
        if plain is not None and stop.plain_candidates is not None and stop.plain_scores is not None:
            plain[0][take], plain[1][take] = stop.plain_candidates[take], stop.plain_scores[take]
    return SequenceMatches(candidates, scores, conf, single_best, single_conf, vels,
                           *(plain if plain is not None else (None, None)))


def collapsed_search(ref: np.ndarray, query: np.ndarray, first: np.ndarray, run_of: np.ndarray, ref_first: np.ndarray,
                     **settings: Any) -> CollapsedSearch:
    """The search of ``collapse_stops`` (:class:`CollapsedSearch`), ready to take the full
    search's difference blocks (a module-level function, so that a test can replace it)."""
    return CollapsedSearch(ref, query, first, run_of, ref_first, **settings)


def collapsed_answers(ref: np.ndarray, query: np.ndarray, first: np.ndarray, run_of: np.ndarray, ref_first: np.ndarray,
                      **settings: Any) -> SequenceMatches:
    """:class:`CollapsedSearch`'s answers, every difference it reads computed by itself."""
    return CollapsedSearch(ref, query, first, run_of, ref_first, **settings).answers()


class CollapsedSearch:
    """The search of ``collapse_stops``: the query's kept frames ``first`` (``run_of`` from
    :func:`standing_runs`) against the reference's kept frames ``ref_first`` (its own
    standing runs), speeds scaled by the collapsed lengths with ``v_auto``. Only the kept
    frames that stand for others are searched (one thread each), each with the kept
    frames its window reads, in groups spanning fewer than ``block_size`` kept frames
    (:func:`collapsed_groups`); every query frame gets its kept frame's answer (original
    reference frames; -1 and no confidence for frames of no standing run). Without
    ``backward_paths``: a vehicle that stands does not back out meanwhile, and a query
    backing out through a stretch that looks still is left to the full search
    (:func:`stop_answers`).

    :meth:`take` receives the full search's query-major difference blocks as they pass
    and keeps the rows of the frames a group reads (against the kept reference frames);
    a group is searched as soon as all of its rows are kept, and its rows are dropped
    once no later group reads them, so at most about two blocks' worth are held.
    :meth:`answers` searches the groups left, computing the differences they lack (the
    same values: each difference is one pair's, whatever block it was computed in). At
    3576 x 3576 with the Nordland preset, when at most one block's worth was kept,
    computing the rest again cost 0.47-0.68 s CPU of the switch's 0.64-0.90 s."""

    def __init__(self, ref: np.ndarray, query: np.ndarray, first: np.ndarray, run_of: np.ndarray,
                 ref_first: np.ndarray, *, comparison: str, enhance_window: int, ds: int, v_min: float, v_max: float,
                 v_step: float, v_auto: bool, search: str, sequence_shape: str, edges: str, top_k: int,
                 speed_change_cost: float, stop_cost: float, reverse_cost: float, v_reverse: float, block_size: int,
                 plain_k: int = 0) -> None:
        self.ref_kept = np.ascontiguousarray(ref[ref_first])
        self.query, self.first, self.run_of, self.ref_first = query, first, run_of, ref_first
        self.comparison, self.window, self.ds, self.k = comparison, int(enhance_window), int(ds), int(top_k)
        self.vels = search_velocities(v_min, v_max, v_step, v_auto, len(ref_first), len(first), v_reverse)
        self.search_kw = dict(shape=sequence_shape, edges=edges, speed_change_cost=speed_change_cost,
                              stop_cost=stop_cost, reverse_cost=reverse_cost)
        self.search = search
        t_off = query_offsets(int(ds), search)
        n_kept = len(first)
        self.groups = collapsed_groups(run_of, n_kept, int(-t_off.min()), int(t_off.max()), int(block_size))
        self.next = 0  # the first group not searched yet
        self.rows: dict[int, np.ndarray] = {}  # query frame -> its differences to the kept reference frames
        self.wanted = np.zeros(len(query), bool)  # the query frames the groups read
        for _, lo, hi in self.groups:
            self.wanted[first[lo:hi]] = True
        self.candidates = np.full((n_kept, self.k), -1, np.int64)
        self.scores = np.full((n_kept, self.k), np.inf, np.float32)
        self.plain = (np.full((n_kept, plain_k), -1, np.int64),
                      np.full((n_kept, plain_k), np.inf, np.float32)) if plain_k > 0 else None

    def take(self, q0: int, dt: np.ndarray) -> None:
        """Keep what the groups read of the differences ``dt`` of query frames ``q0..``
        (query-major, every reference frame), then search every group now complete."""
        mine = np.flatnonzero(self.wanted[q0:q0 + len(dt)]) + q0
        mine = mine[[int(q) not in self.rows for q in mine]]
        if len(mine):
            kept = dt[np.ix_(mine - q0, self.ref_first)]
            for q, row in zip(mine, kept):
                self.rows[int(q)] = row
        self._search_groups(compute=False)

    def answers(self) -> SequenceMatches:
        """Every query frame's answer (the groups not searched yet computing the differences they lack)."""
        self._search_groups(compute=True)
        run_of, n_q = self.run_of, len(self.query)
        candidates = local_to_original(self.ref_first, self.candidates)
        plain = None
        if self.plain is not None:
            plain = (local_to_original(self.ref_first, self.plain[0])[run_of], self.plain[1][run_of])
        return SequenceMatches(candidates[run_of], self.scores[run_of], confidence(self.scores)[run_of],
                               np.full(n_q, -1, np.int64), np.zeros(n_q), self.vels,
                               *(plain if plain is not None else (None, None)))

    def _search_groups(self, compute: bool) -> None:
        """Search the groups in order while their rows are kept (or, with ``compute``, all
        of them), then drop the rows no later group reads."""
        while self.next < len(self.groups):
            need, lo, hi = self.groups[self.next]
            frames = self.first[lo:hi]
            if all(int(q) in self.rows for q in frames):
                dt = np.stack([self.rows[int(q)] for q in frames])
            elif compute:
                dt = difference_block_t(self.ref_kept, self.query[frames], self.comparison)
            else:
                return
            self._search(need, lo, dt)
            self.next += 1
            keep_from = self.first[self.groups[self.next][1]] if self.next < len(self.groups) else len(self.query)
            for q in [q for q in self.rows if q < keep_from]:
                del self.rows[q]

    def _search(self, need: np.ndarray, lo: int, dt: np.ndarray) -> None:
        """The kept frames ``need`` of a group whose windows read the kept columns from
        ``lo`` on, ``dt`` their differences."""
        et = enhance_t(dt, self.window)
        del dt
        plain = self.plain

        def one(c: int, c1: int) -> None:
            # only the kept frames that stand for others: on nordland-dev tiled to 3576
            # frames, 86 of the 1462 a group spans. A query's answer depends on its own
            # window alone, so searching it alone gives the same answer.
            self.candidates[c:c1], self.scores[c:c1] = sequence_search(
                et, c - lo, c1 - lo, self.ds, self.vels, self.search, self.window, self.k, None, lo,
                plain=None if plain is None else (plain[0][c:c1], plain[1][c:c1]), **self.search_kw)

        run_threaded(one, [(int(c), int(c) + 1) for c in need])
