"""SeqSLAM's memory and disk needs per stage (the contract with :mod:`placeloc.core.limits`)."""

from __future__ import annotations

from typing import Any, Sequence

from placeloc.core.limits import Need, count_images, decode_need
from placeloc.core.limits import workers as n_workers

BASE_MEMORY: dict[str, int] = {
    "extract": 32 << 20,
    "build-dictionary": 64 << 20,
    "index": 64 << 20,
    # localize: measured 141 MB of growth on tests/test_resource_estimates.py's 1500-frame
    # route in one virtualenv and 196-204 MB in a fresh one of the same packages (the same code
    # from two revisions; the libraries' pages the stage touches differ): with the route's own
    # terms added to this base, the estimate holds the larger
    "localize": 160 << 20,
    # evaluate: Pillow, its canvases and the report (36 MB measured for configs/demo.yaml with
    # pictures, rows below included; matplotlib, no longer imported, took about 100 MB)
    "evaluate": 16 << 20,
}


def needs(config: dict[str, Any], images: dict[str, Any], stages: Sequence[str]) -> list[Need]:
    from placeloc.seqslam.comparisons import feature_dtype

    p = config["seqslam"]
    w, h = p["thumbnail"]
    pixels = int(w) * int(h)
    fbytes = feature_dtype(p["comparison"], p.get("normalisation", "")).itemsize
    n = count_images(images)
    per_task = min(int(p["images_per_task"]), max(1, n))
    workers = n_workers(config)
    needs = []
    # extract: a worker holds its chunk's decoded frames, uint8 thumbnails and features;
    # extract.h5 stores thumbnails and features uncompressed, in chunks of up to 1024
    # rows that HDF5 allocates whole (so a traverse rounds up to the next chunk).
    rows = 0
    for s in images.values():
        chunk = min(1024, max(1, len(s)))
        rows += -(-len(s) // chunk) * chunk
    needs.append(Need(f"SeqSLAM thumbnails {w}x{h} x {per_task} images per task x {workers} worker(s)",
                      "seqslam.thumbnail (or seqslam.images_per_task)", stage="extract",
                      memory=(1 + fbytes) * pixels * (n + per_task * workers),
                      disk=(1 + fbytes) * pixels * rows + 64 * n + (1 << 18)))  # + names, index, HDF5's own
    if "reference" in images:
        n_ref = len(images["reference"])
        n_query = len(images["query"]) if "query" in images else n_ref
        block = min(int(p.get("block_size", 1024)), n_query)
        d_block = 4 * n_ref * block
        # D and its enhanced copy D^ (evaluate reads both for the dissimilarity ratio, never recomputing D^)
        d_full = 2 * 4 * n_ref * n_query if p.get("store_difference") else 0
        top_k = int(p.get("top_k", 10))
        # what localize keeps for evaluate beside D: the plain ranking (int64 + float32, twice: the
        # method's own arrays and the contract's copy) and the picture's two subsamples (at most 800 x 800)
        plain = 2 * 12 * max(top_k, 20) * n_query if "query" in images else 0
        picture = 2 * 4 * min(n_ref, 800) * min(n_query, 800)
        # localize: both traverses' features and about 8 float32 blocks of D at once (D,
        # its enhanced copy, the sequence search's scores and their temporaries), one more
        # with collapse_stops (the differences its second search reads, kept as the blocks pass);
        # localize.h5 keeps D and D^ (chunked: 5% over) when store_difference, matches.csv a row
        # per query, and the ranked result contract a second copy of the candidates (int64)
        # and scores (float32) with both traverses' names and indices.
        # Measured: 138, 214, 299 MB at 1500, 3000, 6000 frames a traverse.
        needs.append(Need(f"the {n_ref} x {n_query} difference matrix, {block} query columns at a time",
                          "seqslam.block_size (memory) or seqslam.store_difference: false (disk)", stage="localize",
                          memory=fbytes * pixels * (n_ref + n_query) + (9 if p.get("collapse_stops") else 8) * d_block
                          + 64 * top_k * n_query + plain + picture,
                          disk=d_full * 21 // 20 + (600 + 12 * top_k + 64) * n_query + 64 * n_ref + plain + picture
                          + (1 << 18)))  # + HDF5's own
        # evaluate: D and D^ read back one chunk-wide column slab at a time (localize writes D in
        # chunks of at most 256 queries) with the slab's row minima, the ground truth's positive
        # pairs (a few per query), the result's rankings and per-query scores; per_query.csv and
        # evaluate.h5 about 800 bytes a query; the PNGs and report.html a few MB (measured 13 MB
        # with plots: false at 1500 frames a traverse, against 164 MB when the pass built a
        # boolean block of the ground truth per 1024 queries).
        # The PNGs (the difference-matrix picture subsamples D to at most 800 x 800, two
        # panels) and report.html, which embeds them again in base64: about 2.5 times their
        # sum (the strips of samples and of failures about 160 kB each; measured 2.6 MiB in
        # all for configs/demo.yaml, 81 queries, estimated 3.5 MiB).
        plotting = bool(config.get("plots", True))
        pictures = (600_000 + 2 * min(n_ref, 800) * min(n_query, 800)) * 5 // 2 if plotting else 0
        slab = 4 * n_ref * min(256, n_query)
        needs.append(Need(f"scoring {n_query} queries against {n_ref} references, {min(256, n_query)} at a time",
                          "seqslam.store_difference: false (no dissimilarity ratio)", stage="evaluate",
                          memory=(4 * slab if d_full else 0) + 64 * max(top_k, 20) * n_query + (8 << 20)
                          + (24 << 20 if plotting else 0),
                          disk=800 * n_query + pictures))
    return [n for n in needs if n.stage in stages] + decode_need(config, images, 8, "decoding", stages)




def config_rules(config: dict[str, Any]) -> list[str]:
    p = config["seqslam"]
    w, h = p["thumbnail"]
    problems = []
    if p["patch"] > min(w, h):
        problems.append(f"seqslam.patch ({p['patch']}) is larger than the thumbnail ({w}x{h}); "
                        f"it must be <= {min(w, h)} (the smaller thumbnail side)")
    return problems


def input_rules(config: dict[str, Any], images: dict[str, Any]) -> list[str]:
    """A sequence of ds + 1 frames must fit in each traverse (else every query is
    unmatched and Recall@1 is 0 with no word)."""
    ds = int(config["seqslam"]["ds"])
    problems = []
    for role in ("query", "reference"):
        if role in images and ds + 1 > len(images[role]):
            n = len(images[role])
            problems.append(f"seqslam.ds={ds} needs sequences of ds + 1 = {ds + 1} frames, but the {role} traverse "
                            f"({images[role].source}) has {n} image(s); set seqslam.ds to at most {max(1, n - 1)} "
                            f"(e.g. --set seqslam.ds={max(1, min(10, n - 1))})")
            break
    return problems
