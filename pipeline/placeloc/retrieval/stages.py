"""Single-image retrieval on the staged pipeline: extract (thumbnails or one's own
descriptors) -> localize (each query's nearest reference images; without a query, each
frame's nearest earlier frame: loop closure) -> the ``ranked`` (or ``loops``) contract's
evaluate. The standard baseline of visual place recognition (e.g. Berton et
al., "Deep visual geo-localization benchmark", CVPR 2022, score retrieval by Recall@N)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np

from placeloc.core.imagework import ImageStream, ImageWork, write_images
from placeloc.core.methods import Method, Stage
from placeloc.evaluation.contracts import LoopEvaluation, RankedEvaluation
from placeloc.retrieval.params import RetrievalParams


def _check(config: dict) -> None:
    from placeloc.core.descriptors import check_descriptor_pair
    from placeloc.core.errors import ConfigError

    p = config["retrieval"]
    if not (config.get("query") or {}).get("images"):  # loop mode: the reference against itself
        if p["descriptors_query"] is not None:
            raise ConfigError("retrieval.descriptors_query is set but no query.images: without a query, retrieval "
                              "closes loops within the reference (give descriptors_reference only), or set query.images")
        return
    if (p["descriptors_reference"] is None) != (p["descriptors_query"] is None):
        raise ConfigError("retrieval: give both descriptors_reference and descriptors_query, or neither (thumbnails)")
    check_descriptor_pair(p["descriptors_reference"], p["descriptors_query"], "retrieval.descriptors")


def extract(ctx: Any) -> None:
    """One row per image: a thumbnail (through the engine, :mod:`placeloc.core.imagework`),
    or the brought descriptor."""
    from placeloc.core.descriptors import load_descriptors
    from placeloc.retrieval.neighbours import thumbnail_arrays

    p: RetrievalParams = ctx.params
    descriptors = {"reference": p.descriptors_reference, "query": p.descriptors_query}
    work = ImageWork(fn=thumbnail_arrays, settings={"size": (int(p.thumbnail[0]), int(p.thumbnail[1]))})
    for role, images in ctx.images.items():
        g = ctx.out.create_group(role)
        if descriptors[role] is not None:
            path = descriptors[role]
            rows = load_descriptors(path, len(images.paths), role, key="retrieval.descriptors")
            g.create_dataset("features", data=np.asarray(rows, np.float32))
            g.create_dataset("index", data=np.arange(len(rows), dtype=np.int64))
            g.create_dataset("names", data=np.array(images.names, dtype=object), dtype=h5py.string_dtype())
            source = f"descriptors {Path(path).name}"
        else:
            write_images(g, ImageStream(ctx, images, work, desc=f"thumbnails {role}"))
            source = f"thumbnails {p.thumbnail[0]}x{p.thumbnail[1]}"
        g.attrs["source"] = source
        if role == "reference":  # what the rows are, named after their source in every figure
            ctx.out.attrs["features"] = source


def localize(ctx: Any) -> None:
    from placeloc.evaluation import ranked
    from placeloc.retrieval.neighbours import nearest

    p: RetrievalParams = ctx.params
    ex = ctx.artifact("extract")
    if "query" not in ex:
        _localize_loops(ctx, ex)
        return
    ref, query = ex["reference/features"][()], ex["query/features"][()]
    use_faiss = p.search == "faiss" or (p.search == "auto" and len(ref) >= p.faiss_from)
    idx, score = nearest(ref, query, k=p.top_k, distance=p.distance, use_faiss=use_faiss, block_size=p.block_size)
    higher = p.distance == "cosine"
    ctx.out.attrs["search"] = "faiss" if use_faiss else "exact"
    ranked.write(ctx, reference=ex["reference"], query=ex["query"], candidates=idx, scores=score,
                 confidence=score[:, 0] if higher else -score[:, 0], higher_is_better=higher)


def _localize_loops(ctx: Any, ex: Any) -> None:
    """Loop mode (no query traverse): every frame against the frames at least
    ``ground_truth.exclude_recent`` before it (the exclusion the loops contract scores
    with); its nearest one is the loop closure, its similarity the confidence. Retrieval has
    no acceptance rule of its own, so no threshold: the PR curve sweeps the confidence."""
    import time

    from placeloc.evaluation import loops
    from placeloc.retrieval.neighbours import nearest_earlier

    p: RetrievalParams = ctx.params
    rows = ex["reference/features"][()]
    exclude = loops.exclusion_for(ctx, len(rows))
    t0 = time.perf_counter()
    best, score = nearest_earlier(rows, exclude_recent=exclude, distance=p.distance, block_size=p.block_size)
    seconds = (time.perf_counter() - t0) / max(len(rows), 1)
    ctx.out.attrs["search"] = "exact"
    ctx.out.attrs["exclude_recent"] = exclude
    found = best >= 0
    confidence = np.asarray(score if p.distance == "cosine" else -score, np.float32)
    # frames with nothing far enough back close no loop (match -1); their confidence is
    # only a finite placeholder below every real one
    confidence[~found] = float(confidence[found].min()) - 1.0 if found.any() else 0.0
    loops.write(ctx, frames=ex["reference"], match=np.where(found, best, -1), confidence=confidence, threshold=None,
                seconds=np.full(len(rows), seconds))


def evaluate_extra(ctx: Any, ev: RankedEvaluation | LoopEvaluation) -> None:
    """Name the curve after what was compared (thumbnails or the descriptors' file)."""
    ev.label = f"retrieval, {ctx.artifact('extract').attrs['features']} ({ctx.params.distance})"
    ev.metrics["features"] = ev.label


METHOD = Method(
    name="retrieval",
    params=RetrievalParams,
    stages={"extract": Stage(extract, keys=("thumbnail", "descriptors_reference", "descriptors_query")),
            "localize": Stage(localize, keys=("distance", "top_k", "search", "faiss_from"),
                              sections=("ground_truth.exclude_recent",))},
    result="ranked",
    result_without_query="loops",
    evaluate_extra=evaluate_extra,
    evaluate_keys=("distance",),
    checker=_check,
    citation="single-image nearest-neighbour retrieval, the baseline of visual place recognition (as benchmarked by "
             "G. Berton et al., \"Deep Visual Geo-localization Benchmark\", CVPR 2022)",
)
