"""PIRF-nav2 as pipeline stages: extract -> build-dictionary -> index -> localize -> evaluate.

Artifacts (one HDF5 file per stage, written into ``ctx.out``):

- extract.h5: per traverse (``reference``, ``query``) the PIRFs of every frame as one
  chunked (n, dim) float32 array with per-frame offsets, the window used and feature counts.
- build-dictionary.h5: the dictionary, node vectors (CSR: ``node_ptr``, ``node_words``),
  the topological graph (temporal and loop-closure edges), every frame's best candidate
  and score, and the loop closures (score >= tau).
- index.h5: the ANN index (bytes) with its parameters and the dictionary hash.
- localize.h5: for each query frame the best node, score and pose, for the configured
  backend and (``compare_bf``) brute force, with m_t of both (CSR) and per-frame times.
- evaluate.h5 + metrics.json + plots.
"""

from __future__ import annotations

import csv
import time
from pathlib import Path
from typing import Any

import numpy as np
from placeloc.artifacts import write_tree
from placeloc.config import ConfigError
from placeloc.images import ImageError
from placeloc.methods import Method, Stage
from placeloc.pirf.ann import INDEX_DEFAULTS, AnnIndex
from placeloc.pirf.chain import extract_pirfs, ratio_match
from placeloc.pirf.features import check_sizes, extract_frame
from placeloc.pirf.mapping import PirfMapper, localize_frame, node_vector, vectors_to_csr
from placeloc.pirf.params import PirfParams

EXTRACT_KEYS = ("features", "n_features", "blank_frames", "ratio", "w_size_default", "w_size_max", "n_pmin", "n_pmax")
BUILD_KEYS = EXTRACT_KEYS + ("eps", "sigma", "tau", "update")
INDEX_KEYS = BUILD_KEYS + ("index",) + tuple(INDEX_DEFAULTS)
LOCALIZE_KEYS = INDEX_KEYS + ("compare_bf", "reference_poses")


def _check(config: dict) -> None:
    p = config["pirf"]
    if not 0 < p["ratio"] < 1:
        raise ConfigError(f"pirf.ratio must lie in (0, 1), got {p['ratio']}; the paper uses 0.7")
    if not 1 <= p["n_pmin"] <= p["n_pmax"]:
        raise ConfigError(f"pirf: need 1 <= n_pmin <= n_pmax, got {p['n_pmin']} and {p['n_pmax']}")
    if p["w_size_default"] < 1 or p["w_size_max"] < p["w_size_default"]:
        raise ConfigError("pirf: need 1 <= w_size_default <= w_size_max")
    if p["eps"] < 1 or p["sigma"] <= 0:
        raise ConfigError("pirf: eps must be >= 1 and sigma > 0")


# -- extract --------------------------------------------------------------------------
def _pirf_video(ctx: Any, role: str, paths: list[Path]) -> dict[str, Any]:
    p = ctx.params
    items = [(str(q), p["features"], p["n_features"]) for q in paths]
    descs: list[np.ndarray] = []
    resps: list[np.ndarray] = []
    matches: list[np.ndarray] = []
    shapes: list[tuple[int, int]] = []
    out_desc: list[np.ndarray] = []
    windows, n_feat = [], []
    keep = p["w_size_max"] + 1
    for t, (_xy, resp, d, shape) in enumerate(ctx.progress(ctx.executor.map(extract_frame, items), total=len(items), desc=f"extract {role}")):
        shapes.append(shape)
        if shape != shapes[0]:
            check_sizes(shapes, paths[: t + 1])
        if len(d) == 0 and p["blank_frames"] == "stop":
            raise ImageError(f"{paths[t]}: no {p['features']} features found (blank or featureless frame); "
                             "remove it, or set pirf.blank_frames: empty to treat it as a frame without PIRFs")
        matches.append(ratio_match(d, descs[-1], p["ratio"]) if descs else np.full(len(d), -1, np.int64))
        descs.append(d)
        resps.append(resp)
        if len(descs) > keep:  # only the window's history is needed
            descs.pop(0)
            resps.pop(0)
            matches.pop(0)
        pirf, _sel, w = extract_pirfs(descs, resps, matches, p["w_size_default"], p["n_pmin"], p["n_pmax"], p["w_size_max"])
        out_desc.append(pirf)
        windows.append(w)
        n_feat.append(len(d))
    dim = descs[-1].shape[1]
    counts = np.array([len(x) for x in out_desc], np.int64)
    return {"pirfs": np.concatenate(out_desc) if counts.sum() else np.zeros((0, dim), np.float32),
            "offsets": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            "window": np.array(windows, np.int32), "n_features": np.array(n_feat, np.int32),
            "names": [q.name for q in paths], "height": shapes[0][0], "width": shapes[0][1]}


def stage_extract(ctx: Any) -> None:
    ctx.out.attrs["features"] = ctx.params["features"]
    for role in ("reference", "query"):
        images = ctx.images.get(role)
        if images is None:
            continue
        res = _pirf_video(ctx, role, images.paths)
        g = ctx.out.create_group(role)
        g.attrs["height"], g.attrs["width"] = res.pop("height"), res.pop("width")
        g.attrs["dim"] = res["pirfs"].shape[1]
        g.attrs["source"] = images.source
        pirfs = res.pop("pirfs")
        g.create_dataset("pirfs", data=pirfs, chunks=(min(max(len(pirfs), 1), 16384), pirfs.shape[1]), maxshape=(None, pirfs.shape[1]))
        write_tree(g, res)


def read_pirfs(f: Any, role: str) -> tuple[np.ndarray, np.ndarray]:
    g = f[role]
    return g["pirfs"][()], g["offsets"][()]


# -- build-dictionary -----------------------------------------------------------------
def stage_build(ctx: Any) -> None:
    p = ctx.params
    ex = ctx.artifact("extract")
    pirfs, off = read_pirfs(ex, "reference")
    mapper = PirfMapper(pirfs.shape[1], p["ratio"], p["n_pmax"], p["eps"], p["sigma"], p["tau"], p["update"])
    secs = np.zeros(len(off) - 1)
    for t in ctx.progress(range(len(off) - 1), total=len(off) - 1, desc=f"map ({p['update']})"):
        t0 = time.perf_counter()
        mapper.step(pirfs[off[t]:off[t + 1]])
        secs[t] = time.perf_counter() - t0
    best = np.array([b[0] for b in mapper.best], np.int64)
    score = np.array([b[1] for b in mapper.best], np.float64)
    lc = np.flatnonzero((best >= 0) & (score >= p["tau"]))
    n_nodes = len(best)
    temporal = np.column_stack([np.arange(n_nodes - 1), np.arange(1, n_nodes)]) if n_nodes > 1 else np.zeros((0, 2), np.int64)
    d = mapper.dictionary
    ctx.out.attrs["update"] = p["update"]
    ctx.out.attrs["features"] = ex.attrs["features"]
    ctx.out.attrs["dictionary_size"] = len(d)
    ctx.out.create_dataset("dictionary", data=d, chunks=(min(max(len(d), 1), 16384), d.shape[1]))
    ptr = np.concatenate([[0], np.cumsum([len(v) for v in mapper.node_words])]).astype(np.int64)
    write_tree(ctx.out, {
        "dict_size_after": np.array(mapper.dict_size_after, np.int64),
        "node_ptr": ptr, "node_words": np.concatenate(mapper.node_words).astype(np.int64) if n_nodes else np.zeros(0, np.int64),
        "best_node": best, "best_score": score, "map_seconds": secs,
        "loop_closures": {"frame": lc, "node": best[lc], "score": score[lc]},
        "graph": {"temporal": temporal, "loop": np.column_stack([lc, best[lc]]).astype(np.int64)},
    })


# -- index ----------------------------------------------------------------------------
def stage_index(ctx: Any) -> None:
    p = ctx.params
    d = ctx.artifact("build-dictionary")["dictionary"][()]
    idx = AnnIndex(p["index"], d, {k: p[k] for k in INDEX_DEFAULTS}, int(ctx.config["seed"])).build()
    idx.to_h5(ctx.out.create_group("index"))
    ctx.out.attrs["backend"] = p["index"]


# -- localize -------------------------------------------------------------------------
def read_poses(path: str | Path) -> np.ndarray:
    """poses.csv (frame, x, y, heading) -> (n, 3) array ordered by frame."""
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        arr = np.array([[float(r["frame"]), float(r["x"]), float(r["y"]), float(r.get("heading") or 0)] for r in rows])
    except (OSError, KeyError, ValueError) as exc:
        raise ImageError(f"{path}: not a poses file with columns frame,x,y,heading ({exc}); give the generator's poses.csv") from exc
    arr = arr[np.argsort(arr[:, 0])]
    return arr[:, 1:]


def _poses_for(ctx: Any, role: str, key: str) -> np.ndarray | None:
    path = ctx.params.get(key)
    if path is None:
        section = ctx.config.get(role) or {}
        cand = Path(section.get("images") or "") / "poses.csv"
        path = cand if cand.is_file() else None
    return read_poses(path) if path is not None else None


def check_feature_type(ex: Any, build: Any, where: Path) -> None:
    fe, fb = str(ex.attrs["features"]), str(build.attrs["features"])
    if fe != fb:
        raise ImageError(f"{where}: the query was extracted with {fe} features but the dictionary was built from {fb}; "
                         f"set pirf.features: {fb} (or rebuild the map with {fe})")


def localize_all(pirfs: np.ndarray, off: np.ndarray, index: AnnIndex, nodes: Any, p: dict[str, Any]) -> dict[str, Any]:
    """Best node per query frame via ``index``; m_t as CSR and seconds per frame for m_t."""
    n = len(off) - 1
    best = np.full(n, -1, np.int64)
    score = np.zeros(n)
    secs = np.zeros(n)
    vecs = []
    for t in range(n):
        t0 = time.perf_counter()
        d2, ix = index.knn2(pirfs[off[t]:off[t + 1]])
        m = node_vector(d2, ix, p["ratio"])
        secs[t] = time.perf_counter() - t0
        vecs.append(m)
        best[t], score[t] = localize_frame(m, nodes, p["n_pmax"], p["sigma"])
    ptr = np.concatenate([[0], np.cumsum([len(v) for v in vecs])]).astype(np.int64)
    return {"best_node": best, "score": score, "mt_seconds": secs, "m_ptr": ptr,
            "m_words": np.concatenate(vecs).astype(np.int64) if vecs else np.zeros(0, np.int64)}


def stage_localize(ctx: Any) -> None:
    p = ctx.params
    ex = ctx.artifact("extract")
    if "query" not in ex:
        ctx.out.attrs["note"] = "no query traverse configured: nothing to localize"
        return
    build = ctx.artifact("build-dictionary")
    check_feature_type(ex, build, ctx.run_dir / "extract.h5")
    d = build["dictionary"][()]
    ptr, words = build["node_ptr"][()], build["node_words"][()]
    nodes = vectors_to_csr([words[ptr[i]:ptr[i + 1]] for i in range(len(ptr) - 1)], len(d))
    index = AnnIndex.from_h5(ctx.artifact("index")["index"], d, where=str(ctx.run_dir / "index.h5"))
    pirfs, off = read_pirfs(ex, "query")
    if pirfs.shape[1] != d.shape[1]:
        raise ImageError(f"{ctx.run_dir / 'extract.h5'}: query descriptors have {pirfs.shape[1]} dimensions, the dictionary {d.shape[1]}; "
                         "extract the query with the map's feature type")
    ref_poses = _poses_for(ctx, "reference", "reference_poses")
    runs = {index.backend: index}
    if p["compare_bf"] and index.backend != "bruteforce":
        runs["bruteforce"] = AnnIndex("bruteforce", d, {}).build()
    ctx.out.attrs["backend"] = index.backend
    for name, ix in runs.items():
        res = localize_all(pirfs, off, ix, nodes, p)
        if ref_poses is not None:
            res["pose"] = np.where(res["best_node"][:, None] >= 0, ref_poses[np.maximum(res["best_node"], 0)], np.nan)
        write_tree(ctx.out.create_group(name), res)


# -- evaluate -------------------------------------------------------------------------
def set_agreement(ptr_a: np.ndarray, wa: np.ndarray, ptr_b: np.ndarray, wb: np.ndarray) -> dict[str, float]:
    """Jaccard, precision, recall of vectors a (approximate) against b (exact), pooled over frames."""
    inter = union = na = nb = 0
    for t in range(len(ptr_a) - 1):
        a = wa[ptr_a[t]:ptr_a[t + 1]]
        b = wb[ptr_b[t]:ptr_b[t + 1]]
        k = len(np.intersect1d(a, b, assume_unique=True))
        inter += k
        union += len(a) + len(b) - k
        na += len(a)
        nb += len(b)
    return {"jaccard": inter / union if union else float("nan"), "precision": inter / na if na else float("nan"),
            "recall": inter / nb if nb else float("nan")}


def accuracy_at_gap(best: np.ndarray, q_poses: np.ndarray, r_poses: np.ndarray, radius: float, gap: int) -> float:
    """Fraction of query frames whose matched node lies within ``gap`` nodes of a reference
    node that is within ``radius`` metres of the query's true position. Frames with no match count as wrong."""
    ok = 0
    for t, c in enumerate(best):
        if c < 0:
            continue
        near = np.linalg.norm(r_poses[:, :2] - q_poses[t, :2], axis=1) <= radius
        lo, hi = max(0, c - gap), min(len(r_poses), c + gap + 1)
        ok += bool(near[lo:hi].any())
    return ok / len(best) if len(best) else float("nan")


def stage_evaluate(ctx: Any) -> None:
    from placeloc.evaluation import write_metrics

    p = ctx.params
    gt = ctx.config["ground_truth"]
    build = ctx.artifact("build-dictionary")
    loc = ctx.artifact("localize")
    radius = float(gt["radius"])
    r_poses = read_poses(gt["path"]) if gt["kind"] == "poses" else _poses_for(ctx, "reference", "reference_poses")
    q_poses = _poses_for(ctx, "query", "query_poses")
    lc_f, lc_n = build["loop_closures/frame"][()], build["loop_closures/node"][()]
    m: dict[str, Any] = {"dictionary_size": int(build.attrs["dictionary_size"]), "update": str(build.attrs["update"]),
                         "frames": int(len(build["best_node"])), "loop_closures": int(len(lc_f))}
    m["map_seconds_per_frame"] = float(np.mean(build["map_seconds"][()])) if len(build["map_seconds"]) else float("nan")
    if r_poses is not None:
        correct = np.linalg.norm(r_poses[lc_f, :2] - r_poses[lc_n, :2], axis=1) <= radius if len(lc_f) else np.zeros(0, bool)
        m["loop_closures_correct"] = int(correct.sum())
        m["loop_closure_precision"] = float(correct.mean()) if len(correct) else float("nan")
    else:
        m["loop_closures_correct"] = m["loop_closure_precision"] = None
    backend = str(loc.attrs.get("backend", p["index"]))
    m["index"] = backend
    for k in ("accuracy_gap0", "accuracy_gap1", "accuracy_gap2", "jaccard_ann_bf", "precision_ann_bf", "recall_ann_bf",
              "mt_seconds_bf", "mt_seconds_ann"):
        m[k] = None
    if backend in loc:
        a = loc[backend]
        m["mt_seconds_ann"] = float(np.mean(a["mt_seconds"][()]))
        m["localize_fps"] = float(1.0 / max(m["mt_seconds_ann"], 1e-12))
        if "bruteforce" in loc:
            b = loc["bruteforce"]
            m["mt_seconds_bf"] = float(np.mean(b["mt_seconds"][()]))
            ag = set_agreement(a["m_ptr"][()], a["m_words"][()], b["m_ptr"][()], b["m_words"][()])
            m["jaccard_ann_bf"], m["precision_ann_bf"], m["recall_ann_bf"] = ag["jaccard"], ag["precision"], ag["recall"]
        if q_poses is not None and r_poses is not None:
            for name, suffix in ((backend, ""), ("bruteforce", "_bf")):
                if name not in loc:
                    continue
                best = loc[name]["best_node"][()]
                for gap in (0, 1, 2):
                    m[f"accuracy_gap{gap}{suffix}"] = accuracy_at_gap(best, q_poses, r_poses, radius, gap)
    metrics = write_metrics(ctx.run_dir, m, ctx.out)
    if ctx.config.get("plots", True) and r_poses is not None:
        _plots(ctx.run_dir, r_poses, lc_f, lc_n, metrics, radius)


def _plots(run_dir: Path, r_poses: np.ndarray, lc_f: np.ndarray, lc_n: np.ndarray, m: dict[str, Any], radius: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(r_poses[:, 0], r_poses[:, 1], "-", color="0.7", lw=1, label="mapping path")
    if len(lc_f):
        good = np.linalg.norm(r_poses[lc_f, :2] - r_poses[lc_n, :2], axis=1) <= radius
        ax.plot(r_poses[lc_f[good], 0], r_poses[lc_f[good], 1], ".", color="tab:green", ms=4, label="correct loop closure")
        ax.plot(r_poses[lc_f[~good], 0], r_poses[lc_f[~good], 1], "x", color="tab:red", ms=5, label="wrong loop closure")
    ax.set_aspect("equal")
    ax.set_title(f"loop closures: {m['loop_closures']} (precision {m.get('loop_closure_precision')})")
    ax.legend(loc="best", fontsize=8)
    fig.savefig(run_dir / "loop_closures.png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    if m.get("accuracy_gap0") is not None:
        fig, ax = plt.subplots(figsize=(5, 3.5))
        gaps = np.arange(3)
        ax.bar(gaps - 0.2, [m[f"accuracy_gap{g}"] for g in gaps], 0.4, label=f"ANN ({m['index']})")
        if m.get("accuracy_gap0_bf") is not None:
            ax.bar(gaps + 0.2, [m[f"accuracy_gap{g}_bf"] for g in gaps], 0.4, label="brute force")
        ax.set_xticks(gaps)
        ax.set_xlabel("gap tolerance (nodes)")
        ax.set_ylabel("localization accuracy")
        ax.set_ylim(0, 1)
        ax.legend(fontsize=8)
        fig.savefig(run_dir / "accuracy_gap.png", dpi=100, bbox_inches="tight")
        plt.close(fig)


METHOD = Method(
    name="pirf",
    params=PirfParams,
    stages={
        "extract": Stage(stage_extract, keys=EXTRACT_KEYS),
        "build-dictionary": Stage(stage_build, keys=BUILD_KEYS),
        "index": Stage(stage_index, keys=INDEX_KEYS),
        "localize": Stage(stage_localize, keys=LOCALIZE_KEYS),
        "evaluate": Stage(stage_evaluate, keys=tuple(PirfParams.__dataclass_fields__), sections=("ground_truth", "plots")),
    },
    checker=_check,
    citation="H. Sasaki and T. Hamagami, \"Construction of feature space for speeding up self-localization using time "
             "series omnidirectional images\" (PIRF-nav2: A. Kawewong, N. Tongprasit and O. Hasegawa)",
)
