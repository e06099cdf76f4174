"""Single-image retrieval on the staged pipeline: extract (thumbnails or one's own
descriptors) -> localize (each query's nearest reference images) -> the ``ranked``
contract's evaluate. The standard baseline of visual place recognition (e.g. Berton et
al., "Deep visual geo-localization benchmark", CVPR 2022, score retrieval by Recall@N)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np

from placeloc.core.images import ImageError, read_gray
from placeloc.core.methods import Method, Stage
from placeloc.evaluation.contracts import RankedEvaluation
from placeloc.retrieval.params import RetrievalParams


def _check(config: dict) -> None:
    from placeloc.core.errors import ConfigError

    p = config["retrieval"]
    if (p["descriptors_reference"] is None) != (p["descriptors_query"] is None):
        raise ConfigError("retrieval: give both descriptors_reference and descriptors_query, or neither (thumbnails)")


def extract(ctx: Any) -> None:
    """One row per image: a thumbnail, or the brought descriptor."""
    from placeloc.core.descriptors import load_descriptors
    from placeloc.retrieval.neighbours import thumbnail_row

    p: RetrievalParams = ctx.params
    descriptors = {"reference": p.descriptors_reference, "query": p.descriptors_query}
    for role, images in ctx.images.items():
        index: list[int] = []
        if descriptors[role] is not None:
            path = descriptors[role]
            rows = load_descriptors(path, len(images.paths), role, key="retrieval.descriptors")
            index = list(range(len(rows)))
            source = f"descriptors {Path(path).name}"
        else:
            kept = []
            for i, path in enumerate(ctx.progress(images.paths, total=len(images.paths), desc=f"thumbnails {role}")):
                try:
                    kept.append(thumbnail_row(read_gray(path), p.thumbnail))
                    index.append(i)
                except ImageError:
                    if images.on_error != "skip":
                        raise
            if not kept:
                raise ImageError(f"{images.source}: no image could be read; check the folder")
            rows, source = np.stack(kept), f"thumbnails {p.thumbnail[0]}x{p.thumbnail[1]}"
        g = ctx.out.create_group(role)
        g.create_dataset("features", data=np.asarray(rows, np.float32))
        g.create_dataset("index", data=np.asarray(index, np.int64))
        g.create_dataset("names", data=np.array([images.paths[i].name for i in index], dtype=object),
                         dtype=h5py.string_dtype())
        g.attrs["source"] = source
        if role == "reference":  # what the rows are, named after their source in every figure
            ctx.out.attrs["features"] = source


def localize(ctx: Any) -> None:
    from placeloc.core.artifacts import read_strings
    from placeloc.evaluation import ranked
    from placeloc.retrieval.neighbours import nearest

    p: RetrievalParams = ctx.params
    ex = ctx.artifact("extract")
    ref, query = ex["reference/features"][()], ex["query/features"][()]
    use_faiss = p.search == "faiss" or (p.search == "auto" and len(ref) >= p.faiss_from)
    idx, score = nearest(ref, query, k=p.top_k, distance=p.distance, use_faiss=use_faiss, block_size=p.block_size)
    ref_index = ex["reference/index"][()]
    cand = np.where(idx >= 0, ref_index[np.clip(idx, 0, None)], -1)
    higher = p.distance == "cosine"
    ctx.out.attrs["search"] = "faiss" if use_faiss else "exact"
    ranked.write(ctx, query_index=ex["query/index"][()], query_names=read_strings(ex["query/names"]),
                 reference_index=ref_index, reference_names=read_strings(ex["reference/names"]), candidates=cand,
                 scores=score, confidence=score[:, 0] if higher else -score[:, 0], higher_is_better=higher)


def evaluate_extra(ctx: Any, ev: RankedEvaluation) -> None:
    """Name the curve after what was compared (thumbnails or the descriptors' file)."""
    ev.label = f"retrieval, {ctx.artifact('extract').attrs['features']} ({ctx.params.distance})"
    ev.metrics["features"] = ev.label


METHOD = Method(
    name="retrieval",
    params=RetrievalParams,
    stages={"extract": Stage(extract, keys=("thumbnail", "descriptors_reference", "descriptors_query")),
            "localize": Stage(localize, keys=("distance", "top_k", "search", "faiss_from"))},
    result="ranked",
    evaluate_extra=evaluate_extra,
    evaluate_keys=("distance",),
    required_images=("reference", "query"),
    checker=_check,
    citation="single-image nearest-neighbour retrieval, the baseline of visual place recognition (as benchmarked by "
             "G. Berton et al., \"Deep Visual Geo-localization Benchmark\", CVPR 2022)",
)
