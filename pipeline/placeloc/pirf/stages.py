"""PIRF-nav2 as pipeline stages: extract -> build-dictionary -> index -> localize -> evaluate.

Artifacts (one HDF5 file per stage, written into ``ctx.out``):

- extract.h5: per traverse (``reference``, ``query``) the PIRFs of every frame as one
  chunked (n, dim) float32 array with per-frame offsets, the window used, feature counts,
  the kept images' names and folder positions (``index``) and the ``skipped`` ones.
- build-dictionary.h5: the dictionary, node vectors (CSR: ``node_ptr``, ``node_words``),
  the topological graph (temporal and loop-closure edges), every frame's best candidate
  and score, and the loop closures (score >= tau).
- index.h5: the ANN index (bytes) with its parameters and the dictionary hash.
- localize.h5: for each query frame the best node and score, for the configured backend
  and (``compare_bf``) brute force, with m_t of both (CSR) and per-frame times.
- evaluate.h5 + metrics.json, loop_closures.csv, localization.csv and plots.

The numerics live in chain.py (PIRFs), mapping.py (dictionary, similarity, localization),
ann.py (indexes), metrics.py, truth.py (poses per frame), tables.py (CSV) and plots.py.
"""

from __future__ import annotations

import logging
from typing import Any, Callable

import h5py
import numpy as np

from placeloc.core.artifacts import read_strings, write_tree
from placeloc.core.config import ConfigError
from placeloc.core.errors import StageError
from placeloc.core.images import ImageError, ImageSet, list_images, read_gray
from placeloc.core.imagework import ImageResult, ImageStream, ImageWork, extract_images
from placeloc.core.methods import Method, Stage
from placeloc.evaluation.contracts import LoopEvaluation
from placeloc.evaluation.pictures import draw
from placeloc.evaluation.poses import PoseError
from placeloc.pirf import resources as pirf_resources
from placeloc.pirf.ann import AnnIndex
from placeloc.pirf.chain import PirfTracker
from placeloc.pirf.features import blank_frames_note, few_features_note, frame_arrays
from placeloc.pirf.mapping import correct_for_travel_direction, csr_rows, localize_video, loop_closures, map_video
from placeloc.pirf.metrics import (
    accuracy_at_gap,
    loop_closure_correct,
    loop_closure_correct_in_truth,
    nearest_earlier,
    nearest_true_earlier,
    set_agreement,
    tail_count,
    tail_mean,
)
from placeloc.pirf.params import INDEX_KEYS, PirfParams, index_settings
from placeloc.pirf.plots import plot_accuracy_gap, plot_closure_strips, plot_loop_closure_pairs, plot_loop_closures
from placeloc.pirf.tables import write_localization, write_loop_closures
from placeloc.pirf.truth import read_frame_xy
from placeloc.pirf.tuning import SEARCH_GRID, build_tuned, tune_on_queries
from placeloc.pirf.verify import bearings, frames_needed, verify_closures

log = logging.getLogger("placeloc.pirf")


def _check(config: dict) -> None:
    p = config["pirf"]
    # Single-key ranges are declared in PirfParams (and n_pmin <= n_pmax by the generic
    # min/max pair rule); what a range cannot say is checked here.
    if p["ratio"] >= 1:
        raise ConfigError(f"pirf.ratio must lie in (0, 1), got {p['ratio']}; the paper uses 0.7")
    if p["w_size_max"] < p["w_size_default"]:
        raise ConfigError(f"pirf: need w_size_default <= w_size_max, got {p['w_size_default']} and {p['w_size_max']}")
    gt = config["ground_truth"]
    if gt["kind"] not in ("none", "poses", "matrix", "csv"):
        raise ConfigError(f"ground_truth.kind: PIRF-nav2's loop closures are scored against poses (with a radius), a "
                          f"loop-closure matrix or a CSV of pairs, not {gt['kind']!r}; set ground_truth.kind: poses with "
                          "ground_truth.path = the reference poses CSV (and pirf.query_poses for the query's), kind: matrix "
                          "or kind: csv")
    if p["query_poses"] is not None and gt["kind"] != "poses":
        raise ConfigError("pirf.query_poses needs the reference poses too: set ground_truth.kind: poses and ground_truth.path")
    # A PIRF is a feature matched from one frame into the next: one frame gives none.
    for role in ("reference", "query"):
        section = config.get(role) or {}
        if section.get("images"):
            n = len(list_images(section["images"], section.get("on_error", "stop")))
            if n < 2:
                raise ConfigError(f"{role}.images: {section['images']} holds {n} image; PIRF-nav2 matches features from "
                                  "frame to frame and needs a video of at least 2 frames")
    # Every image needs a pose: check the counts now, not after mapping.
    for role, path in (("reference", gt["path"] if gt["kind"] == "poses" else None), ("query", p["query_poses"])):
        section = config.get(role) or {}
        if path is None or not section.get("images"):
            continue
        images = list_images(section["images"])
        what = "ground_truth.path" if role == "reference" else "pirf.query_poses"
        try:
            read_frame_xy(path, images.names, range(len(images)), len(images), what)
        except PoseError as exc:
            raise ConfigError(f"{exc} ({role}.images: {section['images']})") from None


# -- extract --------------------------------------------------------------------------
def stage_extract(ctx: Any) -> None:
    """Every frame's features through the engine (:mod:`placeloc.core.imagework`; frames of
    one size), chained frame by frame into PIRFs by one :class:`PirfTracker` per traverse."""
    p = ctx.params
    ctx.out.attrs["features"] = p.features
    work = ImageWork(fn=frame_arrays, settings={"kind": p.features, "n_features": p.n_features},
                     ragged=("xy", "response", "descriptors"), same_size=True)

    def chain(role: str) -> Callable[[ImageResult], dict[str, np.ndarray]]:
        tracker = PirfTracker(ratio=p.ratio, w_size_default=p.w_size_default, w_size_max=p.w_size_max,
                              n_pmin=p.n_pmin, n_pmax=p.n_pmax)

        def step(frame: ImageResult) -> dict[str, np.ndarray]:
            d = frame.arrays["descriptors"]
            if len(d) == 0 and p.blank_frames == "stop":
                raise ImageError(f"{frame.path}: no {p.features} features found (blank or featureless frame); "
                                 "remove it, or set pirf.blank_frames: empty to treat it as a frame without PIRFs")
            pirf, w = tracker.push(d, frame.arrays["response"])
            return {"pirfs": pirf, "window": np.int32(w), "n_features": np.int32(len(d))}
        return step

    for role, table in extract_images(ctx, work, fold=chain, ragged=("pirfs",)).items():
        g = ctx.out[role]
        g.attrs["height"], g.attrs["width"] = table.first_shape
        g.attrs["dim"] = g["pirfs"].shape[1]
        blank = blank_frames_note(role, list(table.names), g["n_features"][()], p.features)
        if blank:
            log.warning("%s", blank)
        g.attrs["blank_frames_note"] = blank or ""


def _pirfs(f: h5py.File, role: str) -> tuple[np.ndarray, np.ndarray]:
    return f[f"{role}/pirfs"][()], f[f"{role}/offsets"][()]


def _frames(f: h5py.File, role: str) -> tuple[list[str], np.ndarray, int]:
    g = f[role]
    return read_strings(g["names"]), g["index"][()], int(g.attrs["n_listed"])


# -- build-dictionary -----------------------------------------------------------------
def stage_build(ctx: Any) -> None:
    p = ctx.params
    ex = ctx.artifact("extract")
    pirfs, off = _pirfs(ex, "reference")
    g = ex["reference"]
    few = few_features_note("reference", g["n_features"][()], np.diff(off), g["window"][()],
                            shape=(int(g.attrs["height"]), int(g.attrs["width"])), kind=str(ex.attrs["features"]),
                            n_pmin=p.n_pmin, tau=p.tau)
    if few:
        log.warning("%s", few)
    ctx.out.attrs["few_features_note"] = few or ""
    bar = lambda it: ctx.progress(it, total=len(off) - 1, desc=f"map ({p.update})")  # noqa: E731
    res = map_video(pirfs, off, ratio=p.ratio, n_pmax=p.n_pmax, eps=p.eps, sigma=p.sigma, update=p.update, search=p.map_search,
                    hnsw_m=p.map_hnsw_m, hnsw_ef_construction=p.map_ef_construction, ef_search=p.map_ef_search, progress=bar)
    best, score = res["best_node"], res["best_score"]
    lc = loop_closures(best, score, p.tau)
    lc_node = best[lc]
    if p.direction_correction:
        lc_node = correct_for_travel_direction(lc, lc_node, ex["reference/window"][()], span=p.eps)
    n_nodes = len(best)
    check = _verify(ctx, ex, lc, lc_node, n_nodes)
    keep = check["keep"]
    temporal = np.column_stack([np.arange(n_nodes - 1), np.arange(1, n_nodes)]) if n_nodes > 1 else np.zeros((0, 2), np.int64)
    d = res.pop("dictionary")
    ctx.out.attrs["update"] = p.update
    ctx.out.attrs["map_search"] = p.map_search
    ctx.out.attrs["features"] = ex.attrs["features"]
    ctx.out.attrs["dictionary_size"] = len(d)
    ctx.out.create_dataset("dictionary", data=d, chunks=(min(max(len(d), 1), 16384), d.shape[1]), maxshape=(None, d.shape[1]))
    ctx.out.attrs["verify_frames"] = p.verify_frames
    cand = {"frame": lc, "node": lc_node, "matched_node": best[lc], "score": score[lc]}
    write_tree(ctx.out, {**res, "loop_closures": {k: v[keep] for k, v in cand.items()},
                         "closure_candidates": {**cand, **check},
                         "graph": {"temporal": temporal, "loop": np.column_stack([lc[keep], lc_node[keep]]).astype(np.int64)}})


def _verify(ctx: Any, ex: h5py.File, frames: np.ndarray, nodes: np.ndarray, n_frames: int, chunk: int = 256) -> dict[str, np.ndarray]:
    """The geometric check of :mod:`placeloc.pirf.verify` on the mapping frames' images
    (every candidate kept when ``verify_frames`` is 0). Features are detected a chunk of
    closures at a time, in parallel, so memory stays bounded on long videos."""
    p = ctx.params
    n = len(frames)
    if p.verify_frames == 0 or n == 0:
        return {"keep": np.ones(n, bool), "residual": np.full(n, np.nan), "reference": np.full(n, np.nan)}
    images = ctx.images.get("reference")
    if images is None:
        raise ConfigError("pirf.verify_frames reads the mapping images again: set reference.images, or pirf.verify_frames: 0")
    folder_pos = ex["reference/index"][()]
    width = int(ex["reference"].attrs["width"])
    # the same per-image work as extract, through the engine: the frames were read once
    # already, so any that fails now (changed on disk) stops the stage, naming the file
    work = ImageWork(fn=frame_arrays, settings={"kind": p.features, "n_features": p.n_features},
                     ragged=("xy", "response", "descriptors"))
    parts: list[dict[str, np.ndarray]] = []
    for s in range(0, n, chunk):
        f, c = frames[s:s + chunk], nodes[s:s + chunk]
        need = frames_needed(f, c, p.verify_frames, n_frames)
        subset = ImageSet(images.source, [images.paths[folder_pos[j]] for j in need], on_error="stop")
        stream = ImageStream(ctx, subset, work, desc=f"verify loop closures {s + 1}-{s + len(f)} of {n}")
        feats = {int(need[r.local]): (bearings(r.arrays["xy"][:, 0], width), r.arrays["descriptors"]) for r in stream}
        parts.append(verify_closures(f, c, feats.__getitem__, k=p.verify_frames, n_frames=n_frames, ratio=p.ratio,
                                     min_matches=p.verify_min_matches))
    return {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}


# -- index ----------------------------------------------------------------------------
def stage_index(ctx: Any) -> None:
    p = ctx.params
    if "query" not in ctx.artifact("extract"):
        # Loop closure alone: the map finds its own closures while it grows; the index of
        # the finished dictionary serves only a query traverse's m_t.
        ctx.out.attrs["backend"] = "none"
        ctx.out.attrs["note"] = "no query traverse configured: no index built (loop closure needs none)"
        return
    d = ctx.artifact("build-dictionary")["dictionary"][()]
    if len(d) < 2:
        ex = ctx.artifact("extract")["reference"]
        raise StageError(f"{ex.attrs['source']}: the map holds {len(d)} dictionary entries, too few to localize a query "
                         f"against ({int((ex['n_features'][()] == 0).sum())} of {len(ex['n_features'])} frames have no "
                         f"features); map a longer or more textured video")
    seed = int(ctx.config["seed"])
    idx = AnnIndex(p.index, d, index_settings(p), seed)
    tuned = None
    if p.index_recall is not None and p.index in SEARCH_GRID:
        tuned = build_tuned(idx, target=p.index_recall, jaccard=p.index_jaccard, sample=p.index_tune_sample, ratio=p.ratio,
                            seed=seed)
        _warn_if_unmet(tuned, p, "index", "the dictionary sample")
    else:
        idx.build()
    g = ctx.out.create_group("index")
    idx.to_h5(g)
    if tuned is not None:
        _write_tuning(g, tuned)
    ctx.out.attrs["backend"] = p.index


def _warn_if_unmet(tuned: dict[str, Any], p: PirfParams, stage: str, sample: str) -> None:
    if not tuned["target_met"]:
        # The targets must hold with 95 % confidence (placeloc.pirf.tuning.meets): a small
        # sample can agree perfectly and still not show it.
        log.warning("%s: no %s setting up to %s shows m_t recall %s / Jaccard %s with 95 %% confidence on %s (it "
                    "gives %.3f / %.3f on %d ratio-test matches, nearest-neighbour recall %.3f on %d neighbours); "
                    "using it anyway", stage, p.index, tuned["value"], p.index_recall, p.index_jaccard, sample,
                    tuned["mt_recall"], tuned["mt_jaccard"], tuned["mt_matched"], tuned["nn_recall"], tuned["nn_count"])


def _write_tuning(g: Any, tuned: dict[str, Any]) -> None:
    """A tuning result as attributes ``tuned_*`` of ``g`` and the table of every setting tried as ``g/tuning``."""
    tried = tuned["tried"]
    for k, v in tuned.items():
        if k != "tried":
            g.attrs[f"tuned_{k}"] = v
    write_tree(g, {"tuning": {k: np.array([r[k] for r in tried]) for k in tried[0]}})


# -- localize -------------------------------------------------------------------------
def check_feature_type(ex: Any, build: Any, where: Any) -> None:
    fe, fb = str(ex.attrs["features"]), str(build.attrs["features"])
    if fe != fb:
        raise ImageError(f"{where}: the query was extracted with {fe} features but the dictionary was built from {fb}; "
                         f"set pirf.features: {fb} (or rebuild the map with {fe})")


def _write_loops(ctx: Any, ex: h5py.File, build: h5py.File) -> None:
    """The ``loops`` contract from the map: per mapping frame its best earlier node (moved
    for the track lag where pirf.direction_correction applies) with its score; a candidate
    the geometric check rejected closes no loop; tau is the acceptance threshold; the
    mapping time per frame against the dictionary's size."""
    best = build["best_node"][()].copy()
    if "closure_candidates/frame" in build:
        c_f, c_n = build["closure_candidates/frame"][()], build["closure_candidates/node"][()]
        best[c_f] = c_n  # the nodes in use (direction-corrected when configured)
        if "closure_candidates/keep" in build:
            best[c_f[~build["closure_candidates/keep"][()].astype(bool)]] = -1
    from placeloc.evaluation import loops

    loops.write(ctx, frames=ex["reference"], match=best, confidence=build["best_score"][()],
                threshold=float(ctx.params.tau), seconds=build["map_seconds"][()], map_size=build["dict_size_after"][()])


def stage_localize(ctx: Any) -> None:
    p = ctx.params
    ex = ctx.artifact("extract")
    build = ctx.artifact("build-dictionary")
    _write_loops(ctx, ex, build)
    if "query" not in ex:
        ctx.out.attrs["note"] = "no query traverse configured: the loop closures only"
        return
    check_feature_type(ex, build, ctx.run_dir / "extract.h5")
    d = build["dictionary"][()]
    nodes = csr_rows(build["node_ptr"][()], build["node_words"][()], len(d))
    index = AnnIndex.from_h5(ctx.artifact("index")["index"], d, where=str(ctx.run_dir / "index.h5"))
    pirfs, off = _pirfs(ex, "query")
    if pirfs.shape[1] != d.shape[1]:
        raise ImageError(f"{ctx.run_dir / 'extract.h5'}: query descriptors have {pirfs.shape[1]} dimensions, the dictionary {d.shape[1]}; "
                         "extract the query with the map's feature type")
    if p.index_tune_queries and p.index_recall is not None and index.backend in SEARCH_GRID and len(pirfs):
        tuned = tune_on_queries(index, pirfs, target=p.index_recall, jaccard=p.index_jaccard, sample=p.index_tune_sample,
                                ratio=p.ratio, seed=int(ctx.config["seed"]))
        _warn_if_unmet(tuned, p, "localize", "the query sample")
        _write_tuning(ctx.out.create_group("query_tuning"), tuned)
    runs = {index.backend: index}
    if p.compare_bf and index.backend != "bruteforce":
        runs["bruteforce"] = AnnIndex("bruteforce", d, {}).build()
    ctx.out.attrs["backend"] = index.backend
    for name, ix in runs.items():
        res = localize_video(pirfs, off, ix.knn2, nodes, ratio=p.ratio, n_pmax=p.n_pmax, sigma=p.sigma)
        write_tree(ctx.out.create_group(name), res)


# -- evaluate -------------------------------------------------------------------------
def _xy(f: h5py.File, role: str, path: str | None, what: str) -> np.ndarray | None:
    if path is None or role not in f:
        return None
    try:
        return read_frame_xy(path, *_frames(f, role), what=what)
    except PoseError as exc:
        raise ConfigError(str(exc)) from None


def evaluate_extra(ctx: Any, ev: LoopEvaluation) -> None:
    """PIRF-nav2's own figures beside the loops contract's: loop-closure precision of its own
    closures (as matched, direction-corrected, after the geometric check), judged within the
    radius with positions or by the contract's loop-closure matrix or CSV, the mapping
    cost, the ANN index against brute force, and the query traverse's localization
    accuracy at node gaps 0-2 (the paper's Figs. 6-7)."""
    p = ctx.params
    gt = ctx.config["ground_truth"]
    ex, build, loc = ctx.artifact("extract"), ctx.artifact("build-dictionary"), ctx.artifact("localize")
    radius = float(gt["radius"])
    r_xy = _xy(ex, "reference", gt["path"] if gt["kind"] == "poses" else None, "ground_truth.path")
    r_names, r_index, _ = _frames(ex, "reference")
    m_contract = ev.metrics
    q_xy = _xy(ex, "query", p.query_poses, "pirf.query_poses") if r_xy is not None else None
    lc_f, lc_n, lc_s = (build[f"loop_closures/{k}"][()] for k in ("frame", "node", "score"))
    m: dict[str, Any] = {"dictionary_size": int(build.attrs["dictionary_size"]), "update": str(build.attrs["update"]),
                         "frames_without_features": int((ex["reference/n_features"][()] == 0).sum())}
    # PIRF's own closures (its eps rule) are the contract's accepted ones unless ground_truth.exclude_recent
    # drops some: then both counts are kept, each named for what it counts
    if int(len(lc_f)) != m_contract.get("n_accepted"):
        m["loop_closures"] = int(len(lc_f))
    m.update(_mapping_cost(build))

    def judge(frames: np.ndarray, nodes: np.ndarray) -> np.ndarray | None:
        """Per closure (positions in the frame list): right within the radius (positions) or by the truth matrix."""
        if r_xy is not None:
            return loop_closure_correct(r_xy, frames, nodes, radius)
        if ev.truth is not None:
            return loop_closure_correct_in_truth(ev.truth, r_index[frames], r_index[nodes], ev.tolerance)
        return None

    correct = judge(lc_f, lc_n)
    if correct is not None:
        m["loop_closures_correct"] = int(correct.sum())
        m["loop_closure_precision"] = float(correct.mean()) if len(correct) else float("nan")
        # The candidates (score >= tau) before the geometric check, read both ways whichever is in
        # use: as the similarity matched them, and moved for the PIRF track lag on opposite-direction
        # revisits (pirf.direction_correction); then the check's effect on the nodes in use.
        group = "closure_candidates" if "closure_candidates" in build else "loop_closures"
        c_f, matched, c_n = (build[f"{group}/{k}"][()] for k in ("frame", "matched_node", "node"))
        fixed = correct_for_travel_direction(c_f, matched, ex["reference/window"][()], span=p.eps)
        checks = {name: judge(c_f, nodes)
                  for name, nodes in (("as_matched", matched), ("direction_corrected", fixed), ("candidates", c_n))}
        for name, ok in checks.items():
            assert ok is not None
            m[f"loop_closure_precision_{name}"] = float(ok.mean()) if len(ok) else float("nan")
        m["loop_closure_candidates"] = int(len(c_f))
        m["loop_closure_candidates_correct"] = int(np.sum(checks["candidates"]))
    else:
        m["loop_closures_correct"] = m["loop_closure_precision"] = None
    backend = str(loc.attrs.get("backend", "none"))
    m["index"] = backend
    for k in ("accuracy_gap0", "accuracy_gap1", "accuracy_gap2", "jaccard_ann_bf", "precision_ann_bf", "recall_ann_bf",
              "mt_seconds_bf", "mt_seconds_ann", "mt_total_seconds_bf", "mt_total_seconds_ann"):
        m[k] = None
    index_h5 = ctx.artifact("index")
    tunings = {"index_tuned": index_h5["index"].attrs} if "index" in index_h5 else {}
    if "query_tuning" in loc:
        tunings["index_query_tuned"] = loc["query_tuning"].attrs
    for prefix, tuned in tunings.items():
        for k in ("key", "value", "target", "target_jaccard", "target_met", "rule", "sample", "nn_recall", "mt_recall",
                  "mt_jaccard", "mt_matched", "exact_seconds", "seconds"):
            if f"tuned_{k}" in tuned:
                v = tuned[f"tuned_{k}"]
                m[f"{prefix}_{k}"] = v.item() if hasattr(v, "item") else v
    write_loop_closures(ctx.output("loop_closures.csv"), lc_f, lc_n, lc_s, r_names, r_xy, radius, correct)
    if backend in loc:
        a = loc[backend]
        m["mt_seconds_ann"] = float(np.mean(a["mt_seconds"][()]))
        m["localize_fps"] = float(1.0 / max(m["mt_seconds_ann"], 1e-12))
        # the whole query run's m_t, with the re-tuning on its sample (a fixed cost) counted in
        m["mt_total_seconds_ann"] = float(np.sum(a["mt_seconds"][()])) + float(m.get("index_query_tuned_seconds", 0.0))
        if "bruteforce" in loc:
            b = loc["bruteforce"]
            m["mt_seconds_bf"] = float(np.mean(b["mt_seconds"][()]))
            m["mt_total_seconds_bf"] = float(np.sum(b["mt_seconds"][()]))
            ag = set_agreement(a["m_ptr"][()], a["m_words"][()], b["m_ptr"][()], b["m_words"][()])
            m["jaccard_ann_bf"], m["precision_ann_bf"], m["recall_ann_bf"] = ag["jaccard"], ag["precision"], ag["recall"]
        results = {name: (loc[name]["best_node"][()], loc[name]["score"][()]) for name in dict.fromkeys((backend, "bruteforce"))
                   if name in loc}
        if q_xy is not None:
            for name, suffix in ((backend, ""), ("bruteforce", "_bf")):
                if name in results:
                    for gap in (0, 1, 2):
                        m[f"accuracy_gap{gap}{suffix}"] = accuracy_at_gap(results[name][0], q_xy, r_xy, radius, gap)
        write_localization(ctx.output("localization.csv"), results, _frames(ex, "query")[0], r_names, q_xy, r_xy, radius)
    m_contract.update(m)
    metrics = m_contract
    ev.label = f"PIRF-nav2 ({p.update})"
    if ctx.config.get("plots", True) and correct is not None:
        if r_xy is not None:
            draw(plot_loop_closures, ctx.output("loop_closures.png"), r_xy, lc_f, lc_n, correct, radius)
        else:
            truth = ev.truth.tocoo()
            draw(plot_loop_closure_pairs, ctx.output("loop_closures.png"), lc_f, lc_n, correct, truth.row, truth.col,
                 len(r_names), ev.tolerance, _local(r_index))
        _wrong_strips(ctx, r_xy, lc_f[~correct], lc_n[~correct], radius, ev)
        if metrics.get("accuracy_gap0") is not None:
            bf = [metrics[f"accuracy_gap{g}_bf"] for g in range(3)] if metrics.get("accuracy_gap0_bf") is not None else None
            draw(plot_accuracy_gap, ctx.output("accuracy_gap.png"), [metrics[f"accuracy_gap{g}"] for g in range(3)], bf,
                 backend, radius)


def _local(index: np.ndarray) -> np.ndarray:
    """Original index -> position in the frame list (-1: not kept)."""
    pos = np.full(int(index.max(initial=-1)) + 1, -1, np.int64)
    pos[index] = np.arange(len(index))
    return pos


def _mapping_cost(build: h5py.File, tail: float = 0.1) -> dict[str, float]:
    """Mapping CPU seconds per frame over the run and over its last ``tail`` (where the
    dictionary is largest), with the dictionary size where that tail starts."""
    # the wall time per frame is the contract's loop_seconds_per_frame(_end) (the same record): not repeated here
    out: dict[str, float] = {}
    if "map_cpu_seconds" in build:  # older maps recorded wall time only
        cpu = build["map_cpu_seconds"][()]
        out["map_cpu_seconds_per_frame"] = float(np.mean(cpu)) if len(cpu) else float("nan")
        out["map_cpu_seconds_per_frame_end"] = tail_mean(cpu, tail)
    sizes = build["dict_size_after"][()]
    out["map_end_dictionary_from"] = int(sizes[-tail_count(len(sizes), tail)]) if len(sizes) else 0
    return out


def _wrong_strips(ctx: Any, r_xy: np.ndarray | None, frames: np.ndarray, nodes: np.ndarray, radius: float,
                  ev: LoopEvaluation, most: int = 12) -> None:
    """wrong_loop_closures.png: a picture of each wrong loop closure (up to ``most``), beside
    the earlier frame that truly stands nearest (positions) or the true earlier frame
    nearest the match (a loop-closure matrix or CSV)."""
    path = ctx.output("wrong_loop_closures.png")
    images = ctx.images.get("reference")
    if not len(frames) or images is None:
        path.unlink(missing_ok=True)
        return
    pick = np.linspace(0, len(frames) - 1, min(most, len(frames))).round().astype(int)
    ex = ctx.artifact("extract")
    names, index, _ = _frames(ex, "reference")
    if r_xy is not None:
        near = nearest_earlier(r_xy, frames[pick], ctx.params.eps)
    else:
        pos = _local(index)
        true = nearest_true_earlier(ev.truth, index[frames[pick]], index[nodes[pick]])
        near = np.where(true >= 0, pos[np.clip(true, 0, len(pos) - 1)], -1)
    by_name = {q.name: q for q in images.paths}
    imgs, titles = [], []
    for t, c, k in zip(frames[pick], nodes[pick], near):
        blank = np.full_like(read_gray(by_name[names[t]]), 235)
        imgs.append(tuple(read_gray(by_name[names[j]]) if j >= 0 else blank for j in (t, c, k)))
        if r_xy is not None:
            d_c, d_k = (float(np.linalg.norm(r_xy[t] - r_xy[j])) for j in (c, k))
            titles.append((f"frame {t} (closed the loop)", f"matched node {c}: {d_c:.2f} m away",
                           f"nearest earlier frame {k}: {d_k:.2f} m"))
        else:
            titles.append((f"frame {t} (closed the loop)", f"matched node {c}: no loop in the truth",
                           f"true earlier frame {k}" if k >= 0 else "(the truth has no earlier frame)"))
    rule = f"within {radius:g} m" if r_xy is not None else f"the truth matrix, tolerance {ev.tolerance} frames"
    draw(plot_closure_strips, path, imgs, titles, f"wrong loop closures ({len(pick)} of {len(frames)} shown; correct = {rule})")


METHOD = Method(
    resources=pirf_resources,
    name="pirf",
    params=PirfParams,
    stages={
        "extract": Stage(stage_extract, keys=("features", "n_features", "blank_frames", "ratio", "w_size_default", "w_size_max",
                                              "n_pmin", "n_pmax")),
        # ratio and n_pmax reach build/localize through the extract stamp
        "build-dictionary": Stage(stage_build, keys=("eps", "sigma", "tau", "update", "direction_correction", "verify_frames",
                                                    "verify_min_matches", "map_search", "map_ef_search", "map_hnsw_m",
                                                    "map_ef_construction")),
        "index": Stage(stage_index, keys=INDEX_KEYS),
        "localize": Stage(stage_localize, keys=("compare_bf", "index_tune_queries", "index_recall", "index_jaccard",
                                                "index_tune_sample")),
    },
    result="loops",
    evaluate_extra=evaluate_extra,
    evaluate_keys=("query_poses", "update", "eps"),
    checker=_check,
    citation="H. Sasaki and T. Hamagami, \"Construction of feature space for speeding up self-localization using time "
             "series omnidirectional images\" (PIRF-nav2: A. Kawewong, N. Tongprasit and O. Hasegawa)",
)
