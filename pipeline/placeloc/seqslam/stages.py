"""SeqSLAM on the staged pipeline: extract -> (no dictionary, no index) -> localize -> evaluate.

Thin: each stage reads its inputs through ``ctx``, calls the numerical modules
(:mod:`.features`, :mod:`.matching`, :mod:`.search`) with explicit keyword arguments taken
from ``ctx.params`` and writes what they return.

Artifacts:

- ``extract.h5``: per traverse (``reference/``, ``query/``) the ``features`` the chosen
  comparison works on (one row per image), the ``thumbnails``, image ``names``, their
  original positions ``index`` and the ``skipped`` files.
- ``localize.h5``: the result contract in ``result`` (``ranked``; ``loops`` without a
  query traverse; :mod:`placeloc.evaluation.contracts`), and SeqSLAM's own arrays:
  ``difference`` D[r, q] (rows = reference, columns = query, lower = more alike; chunked,
  written block by block), ``candidates``/``scores`` (n_query, K) ranked sequence matches
  and ``confidence`` of the best (positions in the extracted lists), and the single-image
  baseline ``single_best``/``single_confidence``. Side output ``matches.csv``.
- evaluate is the contract's; :func:`evaluate_extra` adds the standard (unseparated)
  sequence ranking, the dissimilarity ratios, the single-image figures and
  ``difference_matrix.png``.
"""

from __future__ import annotations

import logging
from typing import Any

import h5py
import numpy as np

from placeloc.core.common_params import GroundTruthParams
from placeloc.core.imagework import extract_images
from placeloc.core.methods import Method, Stage
from placeloc.evaluation.ground_truth import band_of
from placeloc.evaluation.metrics import dissimilarity_ratios, split_row_minima, summarise_ratios
from placeloc.seqslam import resources as seqslam_resources
from placeloc.seqslam.features import feature_work
from placeloc.seqslam.params import SeqSLAMParams

log = logging.getLogger("placeloc")

# the difference-matrix picture: at most this many references and queries (every stride-th)
PLOT_SIDE = 800
# the plain ranking's length: at least the largest default N of Recall@N (ground_truth.recall_at)
PLAIN_RANKING_K = max(GroundTruthParams().recall_at)


def _check(config: dict) -> None:
    from placeloc.core.config import ConfigError
    from placeloc.core.descriptors import check_descriptor_pair

    p = config["seqslam"]
    if p["v_max"] < p["v_min"]:
        raise ConfigError("seqslam velocities: need v_min <= v_max, e.g. v_min 0.8, v_max 1.2")
    has_query = config.get("query") is not None
    if p["descriptors_query"] is not None and p["descriptors_reference"] is None:
        raise ConfigError("seqslam.descriptors_query is set but seqslam.descriptors_reference is not; give both")
    if p["descriptors_reference"] is not None and has_query and p["descriptors_query"] is None:
        raise ConfigError("seqslam.descriptors_reference is set but seqslam.descriptors_query is not: the query "
                          "images need descriptors too")
    if p["backward_paths"] and (p["sequence_shape"] != "flexible" or p["v_min"] <= 0 or p["v_reverse"] > 0):
        raise ConfigError("seqslam.backward_paths needs sequence_shape: flexible with forward speeds only (v_min > 0, "
                          "v_reverse: 0); set backward_paths: false or change those keys")
    if p["collapse_stops"] and not has_query:
        raise ConfigError("seqslam.collapse_stops needs a query traverse (loop closure's exclude_recent counts the "
                          "traverse's own frames); set collapse_stops: false or give query.images")
    check_descriptor_pair(p["descriptors_reference"], p["descriptors_query"], "seqslam.descriptors")


# ---------------------------------------------------------------------------------------
# extract
# ---------------------------------------------------------------------------------------
def extract(ctx: Any) -> None:
    """Features of every image through the engine (:mod:`placeloc.core.imagework`): the
    ``thumbnails`` and the comparison's ``features``, one row per kept image."""
    p: SeqSLAMParams = ctx.params
    if p.descriptors_reference is not None:
        _extract_descriptors(ctx)
        return
    ctx.out.attrs["comparison"] = p.comparison
    extract_images(ctx, feature_work(thumbnail_size=p.thumbnail, comparison=p.comparison, patch=p.patch,
                                     normalisation=p.normalisation, gaussian_sigma=p.gaussian_sigma,
                                     ocm_epsilon=p.ocm_epsilon, images_per_task=int(p.images_per_task)))


def _extract_descriptors(ctx: Any) -> None:
    """Bring-your-own descriptors: rows loaded from files, one per listed image (images are not read)."""
    from placeloc.seqslam.descriptors import load_descriptors, prepare_descriptors

    p: SeqSLAMParams = ctx.params
    ctx.out.attrs["comparison"] = p.descriptor_distance
    for role, images in ctx.images.items():
        path = p.descriptors_reference if role == "reference" else p.descriptors_query
        mat = prepare_descriptors(load_descriptors(path, len(images.paths), role), p.descriptor_distance)
        g = ctx.out.create_group(role)
        g.create_dataset("features", data=mat)
        g.create_dataset("names", data=np.array([x.name for x in images.paths], dtype=object), dtype=h5py.string_dtype())
        g.create_dataset("index", data=np.arange(len(mat), dtype=np.int64))
        g.attrs["source"] = f"{images.source} (descriptors {path})"
        g.attrs["n_listed"] = len(images.paths)
        g.create_dataset("skipped", data=np.array([], dtype=object), dtype=h5py.string_dtype())


# ---------------------------------------------------------------------------------------
# localize
# ---------------------------------------------------------------------------------------
def localize(ctx: Any) -> None:
    """Sequence matching; writes the ``ranked`` contract (a query traverse) or the
    ``loops`` contract (no query: each frame against the earlier ones)."""
    from placeloc.evaluation import loops
    from placeloc.seqslam.matching import sequence_match

    p: SeqSLAMParams = ctx.params
    ex = ctx.artifact("extract")
    ref = ex["reference/features"][()]
    loop_closure = "query" not in ex
    query = ref if loop_closure else ex["query/features"][()]
    n_ref, n_q = len(ref), len(query)
    # what extract prepared the rows for: an image comparison, or a distance between brought descriptors
    comparison = str(ex.attrs.get("comparison", p.comparison))

    # What evaluate needs is kept here, as the blocks pass, so evaluate never re-runs a kernel:
    # D and D^ (store_difference), subsamples of both for the picture, and (a query
    # traverse) the plain ranking, neighbouring references allowed, for the standard Recall@N.
    d_ds = e_ds = None
    if p.store_difference:
        chunks = (min(n_ref, 512), min(n_q, 256))
        d_ds = ctx.out.create_dataset("difference", shape=(n_ref, n_q), dtype=np.float32, chunks=chunks)
        d_ds.attrs["convention"] = "rows = reference, columns = query, lower = more alike"
        d_ds.attrs["comparison"] = comparison
        e_ds = ctx.out.create_dataset("enhanced", shape=(n_ref, n_q), dtype=np.float32, chunks=chunks)
        e_ds.attrs["convention"] = f"D after contrast enhancement (enhance_window {int(p.enhance_window)}), as D"
    sr, sq = max(1, -(-n_ref // PLOT_SIDE)), max(1, -(-n_q // PLOT_SIDE))
    plot_d = np.zeros((len(range(0, n_ref, sr)), len(range(0, n_q, sq))), np.float32)
    plot_e = np.zeros_like(plot_d)

    def sampled(c0: int, c1: int) -> tuple[slice, np.ndarray]:
        """The picture's columns among queries c0..c1-1: where they go, and where they are in the block."""
        first = -(-c0 // sq)
        cols = np.arange(first * sq, c1, sq)
        return slice(first, first + len(cols)), cols - c0

    def store(c0: int, c1: int, d: np.ndarray) -> None:
        if d_ds is not None:
            d_ds[:, c0:c1] = d
        where, cols = sampled(c0, c1)
        plot_d[:, where] = d[::sr][:, cols]

    def keep_enhanced(c0: int, c1: int, e: np.ndarray) -> None:
        # e: query-major
        if e_ds is not None:
            e_ds[:, c0:c1] = e.T
        where, cols = sampled(c0, c1)
        plot_e[:, where] = e[cols][:, ::sr].T

    m = sequence_match(ref, query, comparison=comparison, enhance_window=int(p.enhance_window), ds=int(p.ds),
                       v_min=p.v_min, v_max=p.v_max, v_step=p.v_step, v_auto=bool(p.v_auto), search=p.search,
                       sequence_shape=p.sequence_shape, edges=p.edges, top_k=int(p.top_k),
                       speed_change_cost=float(p.speed_change_cost), stop_cost=float(p.stop_cost),
                       reverse_cost=float(p.reverse_cost), v_reverse=float(p.v_reverse),
                       collapse_stops=bool(p.collapse_stops), backward_paths=bool(p.backward_paths),
                       backward_v_max=float(p.backward_v_max),
                       exclude_recent=loops.exclusion_for(ctx, n_ref) if loop_closure else None, block_size=int(p.block_size),
                       # Blocks run in this process: the difference kernel, the enhancement and the
                       # search are threaded over every usable core already, and a pool worker would
                       # send each D block back through a pipe (n_ref x block_size float32: 14 MB at
                       # 3576 references) while its threads compete with ours (docs/architecture.md).
                       map_blocks=None, on_difference=store, on_enhanced=keep_enhanced,
                       progress=ctx.progress, plain_k=0 if loop_closure else max(int(p.top_k), PLAIN_RANKING_K))
    pic = ctx.out.create_group("plot")
    pic.attrs["stride"] = (sr, sq)
    pic.attrs["convention"] = "D and D^ at every stride-th reference (rows) and query (columns)"
    pic.create_dataset("difference", data=plot_d)
    pic.create_dataset("enhanced", data=plot_e)
    out = ctx.out
    out.create_dataset("candidates", data=m.candidates)
    out.create_dataset("scores", data=m.scores)
    out.create_dataset("confidence", data=m.confidence)
    out.create_dataset("single_best", data=m.single_best)
    out.create_dataset("single_confidence", data=m.single_confidence)
    out.attrs["loop_closure"] = loop_closure
    out.attrs["velocities"] = m.velocities
    # the confidence compares the best score with the best one window + 1 frames or more from
    # it (search.confidence): 0 where there is none (the first frames a loop may close)
    no_rival = f"no rival {int(p.enhance_window) + 1}+ frames away"
    if loop_closure:
        loops.write(ctx, frames=ex["reference"], match=m.candidates[:, 0], confidence=m.confidence, threshold=None,
                    zero_confidence=no_rival)
        return
    from placeloc.evaluation import ranked

    plain_candidates, plain_scores = m.plain_candidates, m.plain_scores
    assert plain_candidates is not None and plain_scores is not None
    ranked.write(ctx, reference=ex["reference"], query=ex["query"], candidates=m.candidates, scores=m.scores,
                 confidence=m.confidence, higher_is_better=False, separation=int(p.enhance_window) + 1,
                 plain_candidates=plain_candidates,
                 plain_scores=np.where(np.isfinite(plain_scores), plain_scores, np.nan), zero_confidence=no_rival)


# ---------------------------------------------------------------------------------------
# evaluate: the contract scores the matches; this hook adds SeqSLAM's own figures
# ---------------------------------------------------------------------------------------
def comparison_label(p: SeqSLAMParams) -> str:
    """What the frames were compared with: the image comparison, or one's own descriptors
    named after their file (never the image comparison they bypass)."""
    if p.descriptors_reference is not None:
        from pathlib import Path

        return f"descriptors {Path(p.descriptors_reference).name} ({p.descriptor_distance})"
    return str(p.comparison)


def evaluate_extra(ctx: Any, ev: Any) -> None:
    """SeqSLAM's own figures beside the contract's, from what localize wrote (no kernel runs
    again): the paper's dissimilarity ratio before/after enhancement (a pass over the stored
    D and D^), the single-image baseline, and the difference matrices' picture (localize's
    subsamples) with the ground-truth band (conventions in :mod:`placeloc.evaluation.matching`)."""
    from placeloc.evaluation import matching
    from placeloc.evaluation.contracts import LoopEvaluation, RankedEvaluation
    from placeloc.evaluation.pictures import alongside, draw

    p = ctx.params
    ex, lo_art = ctx.artifact("extract"), ctx.artifact("localize")
    loop_closure = bool(lo_art.attrs["loop_closure"])
    ref_index = ex["reference/index"][()]
    q_index = ex["reference" if loop_closure else "query"]["index"][()]
    n_q, n_ref = len(q_index), len(ref_index)
    window, ds, block = int(p.enhance_window), int(p.ds), max(1, int(p.block_size))
    comparison = comparison_label(p)
    ev.label = f"SeqSLAM {comparison} ds={ds}"
    metrics = ev.metrics
    metrics.update({"comparison": comparison, "ds": ds, "search": p.search})

    # the band of true references per query (drawn under the matches), and per reference the
    # smallest difference to a right and to a wrong query, raw and enhanced (the ratio)
    band_lo, band_hi = np.full(n_q, 1, np.int64), np.full(n_q, 0, np.int64)
    stored = "difference" in lo_art and "enhanced" in lo_art
    if isinstance(ev, RankedEvaluation):
        rows, cols = ev.gt.positives(ref_index, q_index)  # sorted by query column
        band_lo, band_hi = band_of(rows, cols, n_q)
        best, best_ok = ev.scores.best, ev.scores.best_correct
    else:
        assert isinstance(ev, LoopEvaluation)
        best, best_ok = ev.match_local, ev.correct
    # the picture first: it is drawn on a thread (placeloc.evaluation.pictures) while the pass
    # over the stored D and D^ below runs
    if ctx.config.get("plots", True) and "plot" in lo_art:
        from placeloc.evaluation import plots  # only with pictures (see ranked.finish)

        head_key = "recall_at_1" if "recall_at_1" in metrics else "recall_at_100_precision"
        head = metrics.get(head_key)
        what = "recall@1" if head_key == "recall_at_1" else "recall at 100% precision"
        pic = lo_art["plot"]
        sr, sq = (int(x) for x in pic.attrs["stride"])
        draw(plots.plot_difference_matrices,
             {"D (raw)": pic["difference"][()], f"D^ (enhanced, R_window={window})": pic["enhanced"][()]},
             ctx.output("difference_matrix.png"), matches=best, correct=best_ok, gt_lo=band_lo, gt_hi=band_hi,
             gt_points=_loop_truth_points(ev, ref_index) if isinstance(ev, LoopEvaluation) else None, stride=(sr, sq),
             title=f"SeqSLAM {comparison}: ds={ds}, v={p.v_min:g}..{p.v_max:g} step {p.v_step:g}, search={p.search}, "
                   f"R_window={window}; {what} {'none' if head is None else f'{head:.3f}'}")
    if isinstance(ev, RankedEvaluation):
        single = lo_art["single_best"][()]
        single_s = matching.score_matches(ev.gt, q_index, ref_index, separated=single[:, None],
                                          confidence=lo_art["single_confidence"][()], ns=(1,))
        metrics.update({"single_image_recall_at_1": single_s.metrics["recall_at_1"],
                        "single_image_auc_pr": single_s.metrics["auc_pr"]})
        metrics["headline"] = [k for k in metrics["headline"] if k != "seconds_per_frame"] + [
            "single_image_recall_at_1", "seconds_per_frame"]
        ev.pr_curves["single image (no sequence)"] = (single_s.pr.recall, single_s.pr.precision)
        if stored:
            # the pass over D and D^ reads 2 x 4 x n_ref x n_q bytes, mostly outside the GIL
            # (h5py's reads, NumPy's minima): on a thread of its own while the stage writes
            # per_query.csv and the charts, which hold it
            step = int((lo_art["difference"].chunks or (0, block))[1])
            alongside(lambda: _dissimilarity_minima(lo_art, rows, cols, n_ref, n_q, step),
                      lambda found: _file_dissimilarity(ev, found))


# the stored matrices the dissimilarity ratio is taken of, and their metrics' suffixes
_RATIO_OF = (("difference", ""), ("enhanced", "_enhanced"))


def _dissimilarity_minima(lo_art: Any, rows: np.ndarray, cols: np.ndarray, n_ref: int, n_q: int,
                          step: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per stored matrix (:data:`_RATIO_OF` in ``lo_art``, reference x query) and reference,
    the smallest difference to a right query (the positive cells ``rows``, ``cols``, sorted
    by column) and to a wrong one: one pass in column slabs ``step`` wide. Slabs one chunk
    wide: h5py copies whole chunks (a 1024-wide slab of 256-wide chunks read at half the speed)."""
    mins = {key: (np.full(n_ref, np.inf), np.full(n_ref, np.inf)) for key, _ in _RATIO_OF}
    # one reused slab: a new array per slab cost 1.5x the read (its pages touched anew)
    slab = np.empty((n_ref, step), np.float32)
    for c0 in range(0, n_q, step):
        c1 = min(n_q, c0 + step)
        a, b = np.searchsorted(cols, (c0, c1))
        for key, (mc, mw) in mins.items():
            part = slab if c1 - c0 == step else np.empty((n_ref, c1 - c0), np.float32)
            lo_art[key].read_direct(part, np.s_[:, c0:c1])
            at_positive, elsewhere = split_row_minima(part, rows[a:b], cols[a:b] - c0)
            np.minimum(mc, at_positive, out=mc)
            np.minimum(mw, elsewhere, out=mw)
    return mins


def _file_dissimilarity(ev: Any, mins: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    """The dissimilarity ratios' figures and arrays into the evaluation, raw then enhanced."""
    for key, suffix in _RATIO_OF:
        ratio = dissimilarity_ratios(*mins[key])
        ev.metrics[f"dissimilarity_mean{suffix}"], ev.metrics[f"dissimilarity_count_ge1{suffix}"] = summarise_ratios(ratio)
        ev.arrays[f"dissimilarity{suffix or '_raw'}"] = ratio


def _loop_truth_points(ev: Any, ref_index: np.ndarray, most: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """Loop closures: the true pairs (frame, earlier frame) that count (at least
    ``exclude_recent`` frames apart) as positions in the frame list, at most ``most`` of them
    (evenly thinned), for the picture: a loop-closure truth holds several revisits per
    frame, no single band."""
    from scipy import sparse

    truth = ev.truth.tocoo()
    scored = truth.row - truth.col >= int(ev.metrics["exclude_recent"])
    truth = sparse.coo_matrix((truth.data[scored], (truth.row[scored], truth.col[scored])), shape=truth.shape)
    pos = np.full(int(ref_index.max(initial=0)) + 1, -1, np.int64)
    pos[ref_index] = np.arange(len(ref_index))
    ok = (truth.row < len(pos)) & (truth.col < len(pos))
    q, r = pos[truth.row[ok]], pos[truth.col[ok]]
    keep = (q >= 0) & (r >= 0)
    q, r = q[keep], r[keep]
    if len(q) > most:
        pick = np.linspace(0, len(q) - 1, most).round().astype(np.int64)
        q, r = q[pick], r[pick]
    return q, r


METHOD = Method(
    resources=seqslam_resources,
    name="seqslam",
    params=SeqSLAMParams,
    stages={
        # images_per_task and block_size change how the work is cut, never the result.
        "extract": Stage(extract, keys=("comparison", "thumbnail", "patch", "normalisation", "gaussian_sigma", "ocm_epsilon",
                                        "descriptors_reference", "descriptors_query", "descriptor_distance")),
        "localize": Stage(localize, keys=("comparison", "enhance_window", "ds", "v_min", "v_max", "v_step", "v_auto",
                                          "search", "sequence_shape", "edges", "top_k", "store_difference",
                                          "speed_change_cost", "stop_cost", "reverse_cost", "v_reverse",
                                          "collapse_stops", "backward_paths", "backward_v_max"),
                          sections=("ground_truth.exclude_recent",)),
    },
    result="ranked",
    result_without_query="loops",
    evaluate_extra=evaluate_extra,
    evaluate_keys=("comparison", "ds", "search", "enhance_window", "descriptors_reference", "descriptor_distance"),
    checker=_check,
    citation="M. Milford and G. Wyeth, \"SeqSLAM: Visual route-based navigation for sunny summer days and stormy winter "
             "nights\", ICRA 2012; with the illumination-robust comparisons (ZNCC, ISC, OCM) studied for it",
)
