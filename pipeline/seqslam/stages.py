"""SeqSLAM on the staged pipeline: extract -> (no dictionary, no index) -> localize -> evaluate.

Artifacts:

- ``extract.h5``: per traverse (``reference/``, ``query/``) the ``features`` the chosen
  comparison works on (one row per image), the ``thumbnails``, image ``names``, their
  original positions ``index`` and the ``skipped`` files.
- ``localize.h5``: ``difference`` D[r, q] (rows = reference, columns = query, lower = more
  alike; chunked, written block by block), ``candidates``/``scores`` (n_query, K) ranked
  sequence matches, ``confidence`` of the best, and the single-image baseline
  ``single_best``/``single_confidence``. Indices are positions in the extracted lists.
- ``evaluate.h5`` + ``metrics.json``, ``pr_curve.png``, ``difference_matrix.png``.
"""

from __future__ import annotations

import csv
import logging
from typing import Any

import h5py
import numpy as np
from placeloc.artifacts import atomic_open, read_strings
from placeloc.evaluation import write_metrics
from placeloc.evaluation.ground_truth import GroundTruth
from placeloc.evaluation.metrics import dissimilarity_ratios, summarise_ratios
from placeloc.images import ImageError, read_gray
from placeloc.methods import Method, Stage
from placeloc.seqslam.comparisons import difference_block, feature_dtype, prepare, thumbnail
from placeloc.seqslam.params import SeqSLAMParams
from placeloc.seqslam.search import confidence, enhance_t, query_offsets, sequence_search, velocities

log = logging.getLogger("placeloc")


def _check(config: dict) -> None:
    from placeloc.config import ConfigError

    p = config["seqslam"]
    if min(p["thumbnail"]) < 4:
        raise ConfigError("seqslam.thumbnail: width and height must be >= 4 pixels, e.g. [64, 32]")
    if p["patch"] < 1:
        raise ConfigError("seqslam.patch must be >= 1")
    if p["v_min"] <= 0 or p["v_max"] < p["v_min"] or p["v_step"] <= 0:
        raise ConfigError("seqslam velocities: need 0 < v_min <= v_max and v_step > 0, e.g. 0.8, 1.2, 0.1")
    if p["ds"] < 1 or p["enhance_window"] < 1 or p["top_k"] < 2 or p["block_size"] < 1:
        raise ConfigError("seqslam: ds, enhance_window and block_size must be >= 1, top_k >= 2")


# ---------------------------------------------------------------------------------------
# extract
# ---------------------------------------------------------------------------------------
def extract_chunk(job: tuple[list[str], dict[str, Any], str]) -> tuple[np.ndarray, np.ndarray, list[int], list[str]]:
    """Read and prepare a chunk of images (runs in a worker). Returns features, thumbnails,
    the positions that succeeded and the errors of those that did not (on_error: skip)."""
    paths, params, on_error = job
    size = params["thumbnail"]
    dtype = feature_dtype(params["comparison"], params)
    feats, thumbs, ok, errors = [], [], [], []
    for i, path in enumerate(paths):
        try:
            thumb = thumbnail(read_gray(path), size)
        except ImageError as exc:
            if on_error != "skip":
                raise
            errors.append(str(exc))
            continue
        thumbs.append(thumb)
        feats.append(prepare(thumb, params["comparison"], params).astype(dtype, copy=False))
        ok.append(i)
    w, h = size
    f = np.stack(feats) if feats else np.zeros((0, 0), dtype)
    t = np.stack(thumbs) if thumbs else np.zeros((0, h, w), np.uint8)
    return f, t, ok, errors


def extract(ctx: Any) -> None:
    """Features of every image, appended chunk by chunk to resizable datasets, so the
    writing process holds one chunk at a time however long the traverse is."""
    params = ctx.params
    chunk = int(params["images_per_task"])
    w, h = params["thumbnail"]
    for role, images in ctx.images.items():
        paths = [str(p) for p in images.paths]
        jobs = [(paths[i:i + chunk], params, images.on_error) for i in range(0, len(paths), chunk)]
        g = ctx.out.create_group(role)
        thumbs = g.create_dataset("thumbnails", shape=(0, h, w), maxshape=(None, h, w), dtype=np.uint8,
                                  chunks=(min(1024, max(1, len(paths))), h, w), compression="gzip", compression_opts=1)
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
            for ds, arr in ((features, f), (thumbs, t)):
                ds.resize(len(index), axis=0)
                ds[n0:] = arr
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


# ---------------------------------------------------------------------------------------
# localize
# ---------------------------------------------------------------------------------------
def localize(ctx: Any) -> None:
    p = ctx.params
    ex = ctx.artifact("extract")
    ref = ex["reference/features"][()]
    loop_closure = "query" not in ex
    query = ref if loop_closure else ex["query/features"][()]
    n_ref, n_q = len(ref), len(query)
    window, ds, k = int(p["enhance_window"]), int(p["ds"]), int(p["top_k"])
    vels = velocities(p["v_min"], p["v_max"], p["v_step"])
    t_off = query_offsets(ds, p["search"])
    before, after = int(-t_off.min()), int(t_off.max())
    exclude = int(p["exclude_recent"]) if loop_closure else None
    block = int(p["block_size"])

    out = ctx.out
    d_ds = None
    if p["store_difference"]:
        d_ds = out.create_dataset("difference", shape=(n_ref, n_q), dtype=np.float32,
                                  chunks=(min(n_ref, 512), min(n_q, 256)))
        d_ds.attrs["convention"] = "rows = reference, columns = query, lower = more alike"
        d_ds.attrs["comparison"] = p["comparison"]
    candidates = np.full((n_q, k), -1, np.int64)
    scores = np.full((n_q, k), np.inf, np.float32)
    single_best = np.full(n_q, -1, np.int64)
    single_conf = np.zeros(n_q, np.float64)

    spans = [(c0, min(n_q, c0 + block), max(0, c0 - before), min(n_q, c0 + block + after)) for c0 in range(0, n_q, block)]
    # D blocks run on the executor (ref shipped once as shared; query slices made lazily, views inline);
    # enhancement, search and writing stay here, in order.
    jobs = ((span, query[span[2]:span[3]], p["comparison"]) for span in spans)
    blocks = ctx.executor.map(difference_job, jobs, shared=ref,
                              describe=lambda job: f"difference block, query columns {job[0][2]}:{job[0][3]}")
    # blocks first in zip: its exhaustion runs the executor's clean-up (release the shared input).
    for d, (c0, c1, lo, _hi) in ctx.progress(zip(blocks, spans), total=len(spans), desc="localize blocks"):
        if d_ds is not None:
            d_ds[:, c0:c1] = d[:, c0 - lo:c1 - lo]
        dt = np.ascontiguousarray(d.T)
        # single-image baseline on the raw differences
        sb, ss = _single_image(dt[c0 - lo:c1 - lo], window, exclude, c0)
        single_best[c0:c1], single_conf[c0:c1] = sb, ss
        et = enhance_t(dt, window)
        del dt, d
        b, s = sequence_search(et, c0 - lo, c1 - lo, ds, vels, p["search"], window, k=k,
                               exclude_recent=exclude, query_index0=lo)
        candidates[c0:c1], scores[c0:c1] = b, s

    conf = confidence(scores)
    out.create_dataset("candidates", data=candidates)
    out.create_dataset("scores", data=scores)
    out.create_dataset("confidence", data=conf)
    out.create_dataset("single_best", data=single_best)
    out.create_dataset("single_confidence", data=single_conf)
    out.attrs["loop_closure"] = loop_closure
    out.attrs["velocities"] = vels
    _write_matches_csv(ctx, ex, candidates[:, 0], conf, loop_closure)


def difference_job(job: tuple[tuple[int, int, int, int], np.ndarray, str], ref: np.ndarray) -> np.ndarray:
    """One difference-matrix block (runs in a worker), (n_ref, hi - lo); ``ref`` is shared."""
    _, query_block, comparison = job
    return difference_block(ref, query_block, comparison)


def _single_image(dt: np.ndarray, window: int, exclude: int | None, q0: int) -> tuple[np.ndarray, np.ndarray]:
    """Best reference per query on raw differences (``dt[q, r]``), confidence as for
    sequences: ``1 - best / best outside +-window`` (differences are >= 0 for every
    comparison)."""
    n, nr = dt.shape
    rows = np.arange(n)[:, None]
    x = dt
    if exclude is not None:
        x = dt.copy()
        limit = np.clip(q0 + np.arange(n) - exclude + 1, 0, nr)
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


def _write_matches_csv(ctx: Any, ex: Any, best: np.ndarray, conf: np.ndarray, loop_closure: bool) -> None:
    ref_names = read_strings(ex["reference/names"])
    ref_index = ex["reference/index"][()]
    qg = ex["reference" if loop_closure else "query"]
    q_names, q_index = read_strings(qg["names"]), qg["index"][()]
    with atomic_open(ctx.run_dir / "matches.csv", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "reference", "confidence", "query_image", "reference_image"])
        for q, (r, c) in enumerate(zip(best, conf)):
            if r < 0:
                w.writerow([int(q_index[q]), "", "", q_names[q], ""])
            else:
                w.writerow([int(q_index[q]), int(ref_index[r]), f"{c:.6f}", q_names[q], ref_names[r]])


# ---------------------------------------------------------------------------------------
# evaluate
# ---------------------------------------------------------------------------------------
def evaluate(ctx: Any) -> None:
    """Score the matches: standard, separated and PR metrics (conventions in
    :mod:`placeloc.evaluation.matching`), the per-query CSV, plots and report.html."""
    from placeloc.evaluation import matching, plots, report, show
    from placeloc.seqslam.search import enhance, enhance_t, query_offsets, sequence_search

    p = ctx.params
    ex, lo_art = ctx.artifact("extract"), ctx.artifact("localize")
    loop_closure = bool(lo_art.attrs["loop_closure"])
    ref_index = ex["reference/index"][()]
    q_group = ex["reference" if loop_closure else "query"]
    q_index = q_group["index"][()]
    if ctx.config["ground_truth"]["kind"] == "none":
        from placeloc.runner import StageError

        raise StageError("ground_truth.kind is none: evaluate needs ground truth (synchronous, csv, hdf5 or poses); "
                         "`placeloc show RUN_DIR` draws the matches without it")
    ref_names = ctx.images["reference"].names
    q_names = ref_names if loop_closure else ctx.images["query"].names
    gt = GroundTruth.from_config(ctx.config["ground_truth"], len(ref_names), len(q_names), ref_names=ref_names,
                                 query_names=None if loop_closure else q_names)
    candidates, conf = lo_art["candidates"][()], lo_art["confidence"][()]
    n_q, n_ref = len(candidates), len(ref_index)
    ns = matching.DEFAULT_RECALL_N
    window, ds, block = int(p.enhance_window), int(p.ds), max(1, int(p.block_size))

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
        ranked = np.full((n_q, max(ns)), -1, np.int64)
        ranked_scores = np.full((n_q, max(ns)), np.inf, np.float32)
        for c0 in ctx.progress(range(0, n_q, block), total=(n_q + block - 1) // block, desc="evaluate blocks"):
            c1 = min(n_q, c0 + block)
            lo, hi = max(0, c0 - before), min(n_q, c1 + after)
            d = d_ds[:, lo:hi]
            et = enhance_t(np.ascontiguousarray(d.T), window)
            ranked[c0:c1], ranked_scores[c0:c1] = sequence_search(
                et, c0 - lo, c1 - lo, ds, lo_art.attrs["velocities"], p.search, 0, k=max(ns),
                exclude_recent=int(p.exclude_recent) if loop_closure else None, query_index0=lo)
            d = d[:, c0 - lo:c1 - lo]
            e = enhance(d, window)
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

    s = matching.score_matches(gt, q_index, ref_index, separated=candidates, confidence=conf, ranked=ranked,
                               ranked_scores=None if ranked_scores is None else np.where(np.isfinite(ranked_scores),
                                                                                          ranked_scores, np.nan),
                               ns=ns)
    single = lo_art["single_best"][()]
    single_s = matching.score_matches(gt, q_index, ref_index, separated=single[:, None],
                                      confidence=lo_art["single_confidence"][()], ns=(1,))
    metrics: dict[str, Any] = dict(s.metrics)
    metrics.update({
        "dissimilarity_mean": None, "dissimilarity_count_ge1": None,
        "dissimilarity_mean_enhanced": None, "dissimilarity_count_ge1_enhanced": None,
        "n_reference": int(n_ref),
        "single_image_recall_at_1": single_s.metrics["recall_at_1"],
        "single_image_auc_pr": single_s.metrics["auc_pr"],
        "comparison": p.comparison, "ds": ds, "search": p.search,
        "localize_seconds": float(lo_art.attrs.get("seconds", float("nan"))),
    })
    if plot_raw and not loop_closure:
        for key, suffix in (("raw", ""), ("enh", "_enhanced")):
            ratio = dissimilarity_ratios(*mins[key])
            metrics[f"dissimilarity_mean{suffix}"], metrics[f"dissimilarity_count_ge1{suffix}"] = summarise_ratios(ratio)
            ctx.out.create_dataset(f"dissimilarity{suffix or '_raw'}", data=ratio)

    pr_group = ctx.out.create_group("pr")
    for name, arr in (("threshold", s.pr.thresholds), ("precision", s.pr.precision), ("recall", s.pr.recall)):
        pr_group.create_dataset(name, data=arr)
    ctx.out.create_dataset("correct", data=s.best_correct)
    write_metrics(ctx.run_dir, metrics, ctx.out)
    matching.write_per_query_csv(ctx.run_dir / "per_query.csv", s, q_names, ref_names)

    if ctx.config.get("plots", True):
        label = f"SeqSLAM {p.comparison} ds={ds}"
        plots.plot_pr_curves({label: (s.pr.recall, s.pr.precision),
                              "single image": (single_s.pr.recall, single_s.pr.precision)},
                             ctx.run_dir / "pr_curve.png", title=f"Precision-recall, {p.comparison}, {n_q} queries")
        plots.plot_recall_at_n({f"{label}, standard": (ns, [metrics[f"standard_recall_at_{n}"] for n in ns]),
                                f"{label}, separated by > {window} frames": (ns, [metrics[f"separated_recall_at_{n}"]
                                                                                  for n in ns])},
                               ctx.run_dir / "recall_at_n.png", title=f"Recall@N over all {n_q} queries")
        if plot_raw:
            plots.plot_difference_matrices(
                {"D (raw)": np.concatenate(plot_raw, axis=1), f"D^ (enhanced, R_window={window})": np.concatenate(plot_enh, axis=1)},
                ctx.run_dir / "difference_matrix.png", matches=s.best, correct=s.best_correct, gt_lo=band[0], gt_hi=band[1],
                stride=(sr, sq), title=f"SeqSLAM {p.comparison}: ds={ds}, v={p.v_min:g}..{p.v_max:g} step {p.v_step:g}, "
                                       f"search={p.search}, R_window={window}; recall@1 {metrics['recall_at_1']:.3f}")
        show.draw_strips(ctx.run_dir)
        report.write_report(ctx.run_dir, config=ctx.config)


METHOD = Method(
    name="seqslam",
    params=SeqSLAMParams,
    stages={
        "extract": Stage(extract, keys=("comparison", "thumbnail", "patch", "normalisation", "gaussian_sigma", "ocm_epsilon")),
        "localize": Stage(localize, keys=("comparison", "enhance_window", "ds", "v_min", "v_max", "v_step", "search",
                                          "exclude_recent", "top_k", "store_difference")),
        "evaluate": Stage(evaluate, keys=("comparison", "ds", "search", "enhance_window"),
                          sections=("ground_truth", "plots")),
    },
    checker=_check,
    citation="M. Milford and G. Wyeth, \"SeqSLAM: Visual route-based navigation for sunny summer days and stormy winter "
             "nights\", ICRA 2012; with the illumination-robust comparisons (ZNCC, ISC, OCM) studied for it",
)
