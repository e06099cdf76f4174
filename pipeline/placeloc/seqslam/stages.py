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

from placeloc.core.artifacts import read_strings
from placeloc.core.images import ImageError
from placeloc.core.methods import Method, Stage
from placeloc.evaluation.metrics import dissimilarity_ratios, summarise_ratios
from placeloc.seqslam import resources as seqslam_resources
from placeloc.seqslam.features import extract_chunk
from placeloc.seqslam.params import SeqSLAMParams

log = logging.getLogger("placeloc")


def _check(config: dict) -> None:
    from placeloc.core.config import ConfigError

    p = config["seqslam"]
    if p["v_max"] < p["v_min"]:
        raise ConfigError("seqslam velocities: need v_min <= v_max, e.g. v_min 0.8, v_max 1.2")
    has_query = config.get("query") is not None
    if p["descriptors_query"] is not None and p["descriptors_reference"] is None:
        raise ConfigError("seqslam.descriptors_query is set but seqslam.descriptors_reference is not; give both")
    if p["descriptors_reference"] is not None and has_query and p["descriptors_query"] is None:
        raise ConfigError("seqslam.descriptors_reference is set but seqslam.descriptors_query is not: the query "
                          "images need descriptors too")


# ---------------------------------------------------------------------------------------
# extract
# ---------------------------------------------------------------------------------------
def extract(ctx: Any) -> None:
    """Features of every image, appended chunk by chunk to resizable datasets, so the
    writing process holds one chunk at a time however long the traverse is."""
    p: SeqSLAMParams = ctx.params
    if p.descriptors_reference is not None:
        _extract_descriptors(ctx)
        return
    ctx.out.attrs["comparison"] = p.comparison
    chunk = int(p.images_per_task)
    w, h = p.thumbnail
    settings = {"thumbnail_size": (int(w), int(h)), "comparison": p.comparison, "patch": int(p.patch),
                "normalisation": p.normalisation, "gaussian_sigma": float(p.gaussian_sigma),
                "ocm_epsilon": float(p.ocm_epsilon)}
    for role, images in ctx.images.items():
        paths = [str(x) for x in images.paths]
        jobs = [(paths[i:i + chunk], settings, images.on_error) for i in range(0, len(paths), chunk)]
        g = ctx.out.create_group(role)
        # Uncompressed: small grey thumbnails of real images shrink little under gzip, and
        # compressing them was a tenth of extract's time.
        thumbs = g.create_dataset("thumbnails", shape=(0, h, w), maxshape=(None, h, w), dtype=np.uint8,
                                  chunks=(min(1024, max(1, len(paths))), h, w))
        features = None
        index: list[int] = []
        skipped: list[str] = []
        bar = ctx.progress(ctx.executor.map(extract_chunk, jobs), total=len(jobs), desc=f"extract {role}")
        for c, (f, t, ok, errors) in enumerate(bar):
            skipped.extend(errors)
            if not ok:
                continue
            if features is None:
                features = g.create_dataset("features", shape=(0, f.shape[1]), maxshape=(None, f.shape[1]), dtype=f.dtype,
                                            chunks=(min(1024, max(1, len(paths))), f.shape[1]))
            n0 = len(index)
            index.extend(c * chunk + i for i in ok)
            for dset, arr in ((features, f), (thumbs, t)):
                dset.resize(len(index), axis=0)
                dset[n0:] = arr
        if not index:
            raise ImageError(f"{images.source}: no image could be read; check the folder")
        g.create_dataset("names", data=np.array([images.paths[i].name for i in index], dtype=object),
                         dtype=h5py.string_dtype())
        g.create_dataset("index", data=np.asarray(index, np.int64))
        g.attrs["source"] = images.source
        g.attrs["n_listed"] = len(paths)
        g.create_dataset("skipped", data=np.array(skipped, dtype=object), dtype=h5py.string_dtype())
        for msg in skipped:
            log.warning("skipped: %s", msg)


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
    from placeloc.seqslam.matching import sequence_match

    p: SeqSLAMParams = ctx.params
    ex = ctx.artifact("extract")
    ref = ex["reference/features"][()]
    loop_closure = "query" not in ex
    query = ref if loop_closure else ex["query/features"][()]
    n_ref, n_q = len(ref), len(query)
    # what extract prepared the rows for: an image comparison, or a distance between brought descriptors
    comparison = str(ex.attrs.get("comparison", p.comparison))

    d_ds = None
    if p.store_difference:
        d_ds = ctx.out.create_dataset("difference", shape=(n_ref, n_q), dtype=np.float32,
                                      chunks=(min(n_ref, 512), min(n_q, 256)))
        d_ds.attrs["convention"] = "rows = reference, columns = query, lower = more alike"
        d_ds.attrs["comparison"] = comparison

    def store(c0: int, c1: int, d: np.ndarray) -> None:
        d_ds[:, c0:c1] = d

    m = sequence_match(ref, query, comparison=comparison, enhance_window=int(p.enhance_window), ds=int(p.ds),
                       v_min=p.v_min, v_max=p.v_max, v_step=p.v_step, v_auto=bool(p.v_auto), search=p.search,
                       sequence_shape=p.sequence_shape, edges=p.edges, top_k=int(p.top_k),
                       speed_change_cost=float(p.speed_change_cost), stop_cost=float(p.stop_cost),
                       reverse_cost=float(p.reverse_cost), v_reverse=float(p.v_reverse),
                       exclude_recent=int(p.exclude_recent) if loop_closure else None, block_size=int(p.block_size),
                       map_blocks=ctx.executor.map, on_difference=store if d_ds is not None else None,
                       progress=ctx.progress)
    out = ctx.out
    out.create_dataset("candidates", data=m.candidates)
    out.create_dataset("scores", data=m.scores)
    out.create_dataset("confidence", data=m.confidence)
    out.create_dataset("single_best", data=m.single_best)
    out.create_dataset("single_confidence", data=m.single_confidence)
    out.attrs["loop_closure"] = loop_closure
    out.attrs["velocities"] = m.velocities
    ref_index = ex["reference/index"][()]
    q_group = ex["reference" if loop_closure else "query"]
    original = np.where(m.candidates >= 0, ref_index[np.clip(m.candidates, 0, None)], -1)
    if loop_closure:
        from placeloc.evaluation import loops

        loops.write(ctx, frame_index=ref_index, frame_names=read_strings(ex["reference/names"]), match=original[:, 0],
                    confidence=m.confidence, threshold=None)
        return
    from placeloc.evaluation import ranked

    ranked.write(ctx, query_index=q_group["index"][()], query_names=read_strings(q_group["names"]), reference_index=ref_index,
                 reference_names=read_strings(ex["reference/names"]), candidates=original, scores=m.scores,
                 confidence=m.confidence, higher_is_better=False, separation=int(p.enhance_window) + 1)


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
    """SeqSLAM's own figures beside the contract's: the standard (unseparated) sequence
    ranking for Recall@N, the paper's dissimilarity ratio before/after enhancement, the
    single-image baseline, and the difference matrices (conventions in
    :mod:`placeloc.evaluation.matching`)."""
    from placeloc.evaluation import matching, plots
    from placeloc.seqslam.search import enhance, enhance_t, query_offsets, sequence_search

    p = ctx.params
    ex, lo_art = ctx.artifact("extract"), ctx.artifact("localize")
    loop_closure = bool(lo_art.attrs["loop_closure"])
    ref_index = ex["reference/index"][()]
    q_group = ex["reference" if loop_closure else "query"]
    q_index = q_group["index"][()]
    gt = ev.extra.get("gt")  # image-matching ground truth (ranked); loop closures have their own
    n_q, n_ref = len(q_index), len(ref_index)
    ns = ev.extra.get("ns", (1,))
    window, ds, block = int(p.enhance_window), int(p.ds), max(1, int(p.block_size))
    comparison = comparison_label(p)

    # One streaming pass over D (when stored): the plain (unseparated) sequence ranking for
    # the standard Recall@N, the paper's dissimilarity ratio before/after enhancement, the
    # ground-truth band and subsampled copies of D and D^ for the plot.
    ranked = ranked_scores = None
    mins = {"raw": [np.full(n_ref, np.inf) for _ in range(2)], "enh": [np.full(n_ref, np.inf) for _ in range(2)]}
    band = (np.full(n_q, 1, np.int64), np.full(n_q, 0, np.int64))
    sr, sq = max(1, n_ref // 800), max(1, n_q // 800)
    plot_raw: list[np.ndarray] = []
    plot_enh: list[np.ndarray] = []
    if "difference" in lo_art:
        d_ds = lo_art["difference"]
        t_off = query_offsets(ds, p.search)
        before, after = int(-t_off.min()), int(t_off.max())
        k_plain = max(ns)
        ranked = np.full((n_q, k_plain), -1, np.int64)
        ranked_scores = np.full((n_q, k_plain), np.inf, np.float32)
        for c0 in ctx.progress(range(0, n_q, block), total=(n_q + block - 1) // block, desc="evaluate blocks"):
            c1 = min(n_q, c0 + block)
            lo, hi = max(0, c0 - before), min(n_q, c1 + after)
            d = d_ds[:, lo:hi]
            if not loop_closure:
                et = enhance_t(np.ascontiguousarray(d.T), window)
                ranked[c0:c1], ranked_scores[c0:c1] = sequence_search(
                    et, c0 - lo, c1 - lo, ds, lo_art.attrs["velocities"], p.search, 0, k_plain,
                    None, lo, shape=p.sequence_shape, edges=p.edges)
            d = d[:, c0 - lo:c1 - lo]
            e = enhance(d, window)
            if gt is not None:
                g = gt.block_idx(ref_index, q_index[c0:c1])
                band[0][c0:c1], band[1][c0:c1] = gt.band(ref_index, q_index[c0:c1])
                for key, mat in (("raw", d), ("enh", e)):
                    mc, mw = mins[key]
                    np.minimum(mc, np.where(g, mat, np.inf).min(axis=1), out=mc)
                    np.minimum(mw, np.where(g, np.inf, mat).min(axis=1), out=mw)
            sel = np.arange(c0, c1)
            sel = sel[sel % sq == 0] - c0
            plot_raw.append(d[::sr][:, sel])
            plot_enh.append(e[::sr][:, sel])
    label = f"SeqSLAM {comparison} ds={ds}"
    ev.label = label
    metrics = ev.metrics
    if ev.kind == "ranked":
        if ranked is not None:
            ev.rescore(plain=np.where(ranked >= 0, ref_index[np.clip(ranked, 0, None)], -1),
                       plain_scores=np.where(np.isfinite(ranked_scores), ranked_scores, np.nan))
            metrics = ev.metrics
        single = lo_art["single_best"][()]
        single_s = matching.score_matches(gt, q_index, ref_index, separated=single[:, None],
                                          confidence=lo_art["single_confidence"][()], ns=(1,))
        metrics.update({"single_image_recall_at_1": single_s.metrics["recall_at_1"],
                        "single_image_auc_pr": single_s.metrics["auc_pr"]})
        metrics["headline"] = list(metrics["headline"]) + ["single_image_recall_at_1"]
        ev.pr_curves["single image (no sequence)"] = (single_s.pr.recall, single_s.pr.precision)
        best, best_ok = ev.scores.best, ev.scores.best_correct
    else:
        best, best_ok = ev.extra["match_local"], ev.extra["correct"]
    metrics.update({"dissimilarity_mean": None, "dissimilarity_count_ge1": None,
                    "dissimilarity_mean_enhanced": None, "dissimilarity_count_ge1_enhanced": None,
                    "comparison": comparison, "ds": ds, "search": p.search})
    if plot_raw and not loop_closure:
        for key, suffix in (("raw", ""), ("enh", "_enhanced")):
            ratio = dissimilarity_ratios(*mins[key])
            metrics[f"dissimilarity_mean{suffix}"], metrics[f"dissimilarity_count_ge1{suffix}"] = summarise_ratios(ratio)
            ev.arrays[f"dissimilarity{suffix or '_raw'}"] = ratio
    if ctx.config.get("plots", True) and plot_raw:
        head = metrics.get("recall_at_1", metrics.get("recall_at_100_precision"))
        what = "recall@1" if "recall_at_1" in metrics else "recall at 100% precision"
        head_text = "n/a" if head is None else f"{head:.3f}"
        plots.plot_difference_matrices(
            {"D (raw)": np.concatenate(plot_raw, axis=1), f"D^ (enhanced, R_window={window})": np.concatenate(plot_enh, axis=1)},
            ctx.output("difference_matrix.png"), matches=best, correct=best_ok, gt_lo=band[0], gt_hi=band[1],
            stride=(sr, sq), title=f"SeqSLAM {comparison}: ds={ds}, v={p.v_min:g}..{p.v_max:g} step {p.v_step:g}, "
                                   f"search={p.search}, R_window={window}; {what} {head_text}")


METHOD = Method(
    resources=seqslam_resources,
    name="seqslam",
    params=SeqSLAMParams,
    stages={
        # images_per_task and block_size change how the work is cut, never the result.
        "extract": Stage(extract, keys=("comparison", "thumbnail", "patch", "normalisation", "gaussian_sigma", "ocm_epsilon",
                                        "descriptors_reference", "descriptors_query", "descriptor_distance")),
        "localize": Stage(localize, keys=("comparison", "enhance_window", "ds", "v_min", "v_max", "v_step", "v_auto",
                                          "search", "sequence_shape", "edges", "exclude_recent", "top_k", "store_difference",
                                          "speed_change_cost", "stop_cost", "reverse_cost", "v_reverse")),
    },
    result="ranked",
    result_without_query="loops",
    evaluate_extra=evaluate_extra,
    evaluate_keys=("comparison", "ds", "search", "enhance_window", "sequence_shape", "edges", "descriptors_reference",
                   "descriptor_distance"),
    checker=_check,
    citation="M. Milford and G. Wyeth, \"SeqSLAM: Visual route-based navigation for sunny summer days and stormy winter "
             "nights\", ICRA 2012; with the illumination-robust comparisons (ZNCC, ISC, OCM) studied for it",
)
