"""PIRF-nav2 index benchmark (``make bench-pirf``): m_t for 200-PIRF frames against a
500,000-entry dictionary of SIFT descriptors, brute force (BLAS) vs every ANN backend.

The dictionary is real SIFT from frames of the synthetic omnidirectional building
(``placeloc.synth.omni``), rendered along the loop; the query frames are rendered at
poses 0.15 m to the side under other lighting, 200 strongest SIFT each: twice
``--queries`` of them, every other one timed and compared, the ones between them the
sample the default index re-tunes on (as localize re-tunes on the query run,
``pirf.index_tune_queries``). Descriptors are cached as .npy under ``--cache``. Prints
one table with ratios against brute force, then the default index's m_t on 1, 2, 4, ...,
nproc faiss threads (``--workers``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from placeloc.pirf.ann import BACKENDS, AnnIndex
from placeloc.pirf.knn import sq_norms
from placeloc.pirf.mapping import PirfMapper, node_vector
from placeloc.pirf.metrics import set_agreement
from placeloc.pirf.params import PirfParams, index_settings
from placeloc.pirf.tuning import build_tuned, tune_on_queries
from placeloc.synth.omni import OmniWorld, loop_path


def sift_set(n_target: int, n_queries: int, cache: Path) -> tuple[np.ndarray, list[np.ndarray]]:
    dpath, qpath = cache / f"dict_{n_target}.npy", cache / f"queries_{n_queries}.npy"
    if dpath.is_file() and qpath.is_file():
        q = np.load(qpath)
        return np.load(dpath), list(q.reshape(n_queries, 200, 128))
    cache.mkdir(parents=True, exist_ok=True)
    world = OmniWorld("building", 0)
    sift = cv2.SIFT_create(nfeatures=700)
    light = {"gain": 1.0, "gamma": 1.0, "field": 0.15, "phase": 0.0, "noise": 2.0}
    rng = np.random.default_rng(0)
    chunks, total, t = [], 0, 0
    poses = loop_path(world.loop, 4000, 0.25)
    while total < n_target:
        img = world.render(*poses[t], 480, light, world.movers_at(t, 0), rng)
        _, d = sift.detectAndCompute(img, None)
        if d is not None:
            chunks.append(d)
            total += len(d)
        t += 1
    dic = np.concatenate(chunks)[:n_target].astype(np.float32)
    qlight = {"gain": 0.85, "gamma": 1.15, "field": 0.25, "phase": 1.3, "noise": 3.0}
    qposes = loop_path(world.loop, n_queries, 0.25 * t / n_queries, offset=0.15, start=0.01)
    queries = []
    for k in range(n_queries):
        img = world.render(*qposes[k], 480, qlight, world.movers_at(k, 1), rng)
        kps, d = sift.detectAndCompute(img, None)
        order = np.argsort([-kp.response for kp in kps])[:200]
        queries.append(d[order].astype(np.float32))
    np.save(dpath, dic)
    np.save(qpath, np.stack(queries))
    return dic, queries


def time_mt(ix: AnnIndex, queries: list[np.ndarray], reps: int) -> tuple[float, list[np.ndarray]]:
    best = np.inf
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        out = [node_vector(*ix.knn2(q), 0.7) for q in queries]
        best = min(best, (time.perf_counter() - t0) / len(queries))
    return best, out


def preload(mapper: PirfMapper, dic: np.ndarray, per_node: int) -> float:
    """Give ``mapper`` a map of ``dic`` (nodes of ``per_node`` consecutive words, as if mapped
    frame by frame); returns the seconds spent growing its HNSW graph (0 for brute force)."""
    n = len(dic)
    mapper._grow(n)
    mapper.words[:n] = dic
    mapper.norms[:n] = sq_norms(dic)
    t0 = time.perf_counter()
    if mapper.search != "bruteforce":
        for s in range(0, n, 10_000):  # as mapping would: the graph grows with the dictionary
            mapper._hnsw_add(dic[s:s + 10_000])
    secs = time.perf_counter() - t0
    mapper.n = n
    for j, s in enumerate(range(0, n, per_node)):
        words = np.arange(s, min(s + per_node, n))
        mapper.node_words.append(words)
        mapper._add_pairs(j, words)
        mapper.pairs_after.append(mapper._npairs)
        mapper.dict_size_after.append(min(s + per_node, n))
        mapper.best.append((-1, 0.0))
    return secs


def bench_mapping(dic: np.ndarray, queries: list[np.ndarray], ef: int) -> None:
    """Seconds per mapping step (m_t over Q_{t-eps}, scoring, improved update) at a map of
    len(dic) words, brute force against the incremental HNSW graph."""
    p = PirfParams()
    rows = []
    for search in ("bruteforce", "faiss-hnsw"):
        mp = PirfMapper(dic.shape[1], ratio=p.ratio, n_pmax=p.n_pmax, eps=p.eps, sigma=p.sigma, update=p.update, search=search,
                        hnsw_m=p.map_hnsw_m, hnsw_ef_construction=p.map_ef_construction, ef_search=ef)
        build = preload(mp, dic, 125)
        c0, t0 = time.process_time(), time.perf_counter()
        for q in queries:
            mp.step(q)
        rows.append((search, build, (time.perf_counter() - t0) / len(queries), (time.process_time() - c0) / len(queries)))
    print(f"\nmapping step at {len(dic)} words ({len(queries)} frames of 200 PIRF-sized SIFT; improved update):")
    print(f"{'search':<12}{'graph s':>9}{'ms/frame':>10}{'CPU ms':>9}{'frames/s':>10}{'speedup':>9}")
    for r in rows:
        print(f"{r[0]:<12}{r[1]:>9.1f}{1000 * r[2]:>10.1f}{1000 * r[3]:>9.1f}{1 / r[2]:>10.1f}{rows[0][2] / r[2]:>8.1f}x")


def thread_scaling(dic: np.ndarray, queries: list[np.ndarray], reps: int, workers: str | None) -> None:
    """m_t with the default index (HNSW, tuned) on 1, 2, 4, ... faiss threads
    (``faiss.omp_set_num_threads``: one frame's ~200 queries are one faiss search)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from scaling import counts_from, markdown, scaling_table

    from placeloc.core.faiss_loader import import_faiss

    faiss = import_faiss()
    p = PirfParams()
    ix = AnnIndex("faiss-hnsw", dic, index_settings(p), seed=0)
    build_tuned(ix, target=p.index_recall, jaccard=p.index_jaccard, sample=p.index_tune_sample, ratio=p.ratio, seed=0)
    counts = counts_from(workers)
    before = faiss.omp_get_max_threads()

    def measure(k: int) -> dict[str, float]:
        faiss.omp_set_num_threads(k)
        try:
            # seconds per 100 frames, so the table's two decimals show it
            return {f"m_t of 100 frames of 200 PIRFs, HNSW tuned, {len(dic)} words": 100 * time_mt(ix, queries, reps)[0]}
        finally:
            faiss.omp_set_num_threads(before)

    print()
    print(markdown(scaling_table(measure, counts), "PIRF-nav2 m_t", unit="thread",
                   note=f"faiss threads set with omp_set_num_threads; best of {reps} a frame."))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=500_000)
    ap.add_argument("--queries", type=int, default=10, help="200-PIRF query frames")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--backends", default="bruteforce,faiss-hnsw-tuned,faiss-hnsw,faiss-ivf-tuned,faiss-ivf,flann-kdtree,flann-kmeans",
                    help=f"comma list of {', '.join(BACKENDS)}, faiss-hnsw-tuned, faiss-ivf-tuned "
                         "(flann-autotune takes many minutes at 500k: add it explicitly)")
    ap.add_argument("--cache", type=Path, default=Path("runs/bench-pirf"))
    ap.add_argument("--mapping", action="store_true", help="also time a mapping step at this dictionary size (BF vs HNSW)")
    ap.add_argument("--map-ef", type=int, default=PirfParams().map_ef_search, help="HNSW efSearch while mapping")
    ap.add_argument("--workers", default=None,
                    help="faiss thread counts of the scaling table (default 1, 2, 4, ..., nproc; 0: no table)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    dic, frames = sift_set(args.size, 2 * args.queries, args.cache)
    queries, tuning_frames = frames[0::2], frames[1::2]
    print(f"dictionary {dic.shape[0]} x {dic.shape[1]} SIFT, {len(queries)} query frames x 200 timed, {len(tuning_frames)} between "
          f"them to tune on ({time.perf_counter() - t0:.1f} s to make)")
    bf = AnnIndex("bruteforce", dic, {}).build()
    bf_s, bf_m = time_mt(bf, queries, args.reps)
    ptr_b = np.concatenate([[0], np.cumsum([len(m) for m in bf_m])])
    rows = [{"backend": "bruteforce", "build_s": bf.build_seconds, "mt_s": bf_s, "speedup": 1.0, "jaccard": 1.0, "precision": 1.0, "recall": 1.0}]
    for b in [x for x in args.backends.split(",") if x and x != "bruteforce"]:
        if b.endswith("-tuned"):  # the default: the search setting tuned to pirf.index_recall
            p = PirfParams()
            ix = AnnIndex(b[: -len("-tuned")], dic, index_settings(p), seed=0)
            tuned = build_tuned(ix, target=p.index_recall, jaccard=p.index_jaccard, sample=p.index_tune_sample, ratio=p.ratio, seed=0)
            print(f"{b}: on the dictionary's entries {tuned['key']} {tuned['value']} (sample recall {tuned['nn_recall']:.3f}, "
                  f"m_t recall {tuned['mt_recall']:.3f}, {tuned['mt_matched']} matches)")
            again = tune_on_queries(ix, np.concatenate(tuning_frames), target=p.index_recall, jaccard=p.index_jaccard,
                                    sample=p.index_tune_sample, ratio=p.ratio, seed=0)
            print(f"{' ' * len(b)}  re-tuned on {again['sample']} query PIRFs: {again['key']} {again['value']} (rule {again['rule']}, "
                  f"m_t recall {again['mt_recall']:.3f}, Jaccard {again['mt_jaccard']:.3f}, {again['mt_matched']} matches, "
                  f"{again['seconds']:.1f} s)")
        else:
            ix = AnnIndex(b, dic, index_settings(PirfParams()), seed=0).build()
        s, ms = time_mt(ix, queries, args.reps)
        ptr = np.concatenate([[0], np.cumsum([len(m) for m in ms])])
        ag = set_agreement(ptr, np.concatenate(ms), ptr_b, np.concatenate(bf_m))
        rows.append({"backend": b, "build_s": ix.build_seconds, "mt_s": s, "speedup": bf_s / s, **ag})
    print(f"\nm_t for a 200-PIRF frame, dictionary {len(dic)}:  (ratios vs brute force)")
    print(f"{'backend':<14}{'build s':>9}{'m_t ms':>10}{'speedup':>9}{'Jaccard':>9}{'precision':>10}{'recall':>8}")
    for r in rows:
        print(f"{r['backend']:<14}{r['build_s']:>9.1f}{1000 * r['mt_s']:>10.2f}{r['speedup']:>8.1f}x"
              f"{r['jaccard']:>9.3f}{r['precision']:>10.3f}{r['recall']:>8.3f}")
    (args.cache / "bench.json").write_text(json.dumps(rows, indent=2))
    if args.workers != "0":
        thread_scaling(dic, queries, args.reps, args.workers)
    if args.mapping:
        bench_mapping(dic, queries, args.map_ef)
    print(f"\nwritten {args.cache / 'bench.json'}; m_t words per frame (BF): {np.mean([len(m) for m in bf_m]):.1f}")


if __name__ == "__main__":
    main()
