"""SeqSLAM's localize step on feature rows: difference matrix -> enhancement -> sequence search.

The difference matrix is computed block by block (query columns), each block with the
``before``/``after`` query columns a sequence window needs on either side, so memory is
bounded by ``block_size`` whatever the traverse length. Every block is enhanced and
searched as soon as it arrives; ``on_difference`` receives its raw columns (the stage
writes them to ``localize.h5``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from placeloc.seqslam.comparisons import difference_block
from placeloc.seqslam.search import (
    REVERSE_COST,
    SPEED_CHANGE_COST,
    STOP_COST,
    confidence,
    enhance_t,
    query_offsets,
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
    """One difference-matrix block (runs in a worker), (n_ref, hi - lo); ``ref`` is shared."""
    _, query_block, comparison = job
    return difference_block(ref, query_block, comparison)


def auto_velocity_scale(n_reference: int, n_query: int) -> float:
    """Reference frames per query frame if both traverses cover the same route: a query
    recorded at half the frame rate (half as many frames) moves 2 references per frame."""
    return n_reference / max(1, n_query)


def search_velocities(v_min: float, v_max: float, v_step: float, v_auto: bool, n_reference: int,
                      n_query: int, v_reverse: float = 0.0) -> np.ndarray:
    """The velocities the sequence search tries (scaled by :func:`auto_velocity_scale` with ``v_auto``)."""
    vels = velocities(v_min, v_max, v_step, v_reverse)
    return np.round(vels * auto_velocity_scale(n_reference, n_query), 9) if v_auto else vels


def block_spans(n_q: int, block: int, before: int, after: int) -> list[tuple[int, int, int, int]]:
    """``(c0, c1, lo, hi)`` per block of at most ``block`` query columns ``c0:c1``, with the
    columns ``lo:hi`` their windows read: ``before``/``after`` on either side and, near a
    traverse end, at least the ``before + after + 1`` frames nearest it, which a shifted
    window (``edges: shift``) uses there. Without those, a last block shorter than a
    window could not shift its queries' windows and left them unmatched (1056 queries
    with block_size 1024 and ds 120 left 32), so ``block_size`` changed results."""
    n_window = before + after + 1
    spans = []
    for c0 in range(0, n_q, block):
        c1 = min(n_q, c0 + block)
        lo = max(0, min(c0 - before, n_q - n_window))
        hi = min(n_q, max(c1 + after, n_window))
        spans.append((c0, c1, lo, hi))
    return spans


def _inline_map(fn: Callable, jobs: Iterable, shared: Any = None, describe: Any = None) -> Iterator[Any]:
    for job in jobs:
        yield fn(job, shared)


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
    exclude_recent: int | None,
    block_size: int,
    map_blocks: MapBlocks | None = None,
    on_difference: Callable[[int, int, np.ndarray], None] | None = None,
    on_enhanced: Callable[[int, int, int, np.ndarray], None] | None = None,
    progress: Callable[..., Iterable] | None = None,
    plain_k: int = 0,
) -> SequenceMatches:
    """Match every query row against the reference rows (features from ``extract``).

    ``v_auto`` scales the velocities by :func:`auto_velocity_scale`. The costs shape the
    ``flexible`` path (:class:`placeloc.seqslam.params.SeqSLAMParams`). ``exclude_recent``
    is for loop closure (``query is ref``): references within that
    many frames before the query are ignored; ``None`` otherwise. ``map_blocks`` runs the
    difference blocks (default: in this process); ``on_difference(c0, c1, d)`` gets the
    raw difference columns ``c0:c1`` as they are computed; ``on_enhanced(c0, c1, lo, et)``
    the enhanced block, query-major, its row 0 being query ``lo`` (the columns a sequence
    window needs on either side included), for what the caller keeps of it. ``plain_k`` > 0
    also ranks the ``plain_k`` best references with no separation (the standard Recall@N),
    from the same sequence scores.
    """
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
    # D blocks run on the executor (ref shipped once as shared; query slices made lazily, views inline);
    # enhancement, search and writing stay here, in order.
    jobs = ((span, query[span[2]:span[3]], comparison) for span in spans)
    blocks = (map_blocks or _inline_map)(difference_job, jobs, shared=ref,
                                         describe=lambda job: f"difference block, query columns {job[0][2]}:{job[0][3]}")
    # blocks first in zip: its exhaustion runs the executor's clean-up (release the shared input).
    pairs: Iterable = zip(blocks, spans)
    if progress is not None:
        pairs = progress(pairs, total=len(spans), desc="localize blocks")
    for d, (c0, c1, lo, _hi) in pairs:
        if on_difference is not None:
            on_difference(c0, c1, d[:, c0 - lo:c1 - lo])
        dt = np.ascontiguousarray(d.T)
        # single-image baseline on the raw differences
        sb, ss = single_image_best(dt[c0 - lo:c1 - lo], window, exclude_recent, c0)
        single_best[c0:c1], single_conf[c0:c1] = sb, ss
        et = enhance_t(dt, window)
        del dt, d
        if on_enhanced is not None:
            on_enhanced(c0, c1, lo, et)
        b, s = sequence_search(et, c0 - lo, c1 - lo, int(ds), vels, search, window, k, exclude_recent, lo,
                               shape=sequence_shape, edges=edges, speed_change_cost=speed_change_cost,
                               stop_cost=stop_cost, reverse_cost=reverse_cost,
                               plain=None if plain is None else (plain[0][c0:c1], plain[1][c0:c1]))
        candidates[c0:c1], scores[c0:c1] = b, s
    return SequenceMatches(candidates, scores, confidence(scores), single_best, single_conf, vels,
                           *(plain if plain is not None else (None, None)))
