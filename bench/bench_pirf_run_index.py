"""The PIRF index on a real run's dictionary: m_t agreement with brute force and time per
query frame, for HNSW graphs given as ``M,efConstruction``, at the tuned efSearch and a
sweep. Needs a finished run directory (extract.h5 with a query run, build-dictionary.h5).

    python bench/bench_pirf_run_index.py RUN_DIR 32,40 16,200

Brute force and every setting are timed in the same process on the same query frames
(``--frames`` of them, spread over the query run), so the ratio holds on a shared machine
better than either time.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from placeloc.pirf.ann import AnnIndex
from placeloc.pirf.knn import bf_knn2, sq_norms
from placeloc.pirf.params import PirfParams, index_settings
from placeloc.pirf.results import read_dictionary, read_pirfs
from placeloc.pirf.tuning import agreement, build_tuned


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("graphs", nargs="*", default=["16,200"], help="HNSW M,efConstruction pairs")
    ap.add_argument("--frames", type=int, default=100, help="query frames timed and compared")
    ap.add_argument("--ef", default="16,24,32,48,64,96", help="efSearch values of the sweep")
    args = ap.parse_args()
    p = PirfParams()
    words = read_dictionary(args.run_dir)
    pirfs, offsets = read_pirfs(args.run_dir, "query")
    n_frames = len(offsets) - 1
    frames = range(0, n_frames, max(1, n_frames // args.frames))
    batches = [pirfs[offsets[t]:offsets[t + 1]] for t in frames]
    norms = sq_norms(words)
    t0 = time.perf_counter()
    exact = [bf_knn2(b, words, b_norms=norms) for b in batches]
    bf = (time.perf_counter() - t0) / len(batches)
    exact_pooled = (np.concatenate([e[0] for e in exact]), np.concatenate([e[1] for e in exact]))
    print(f"dictionary {words.shape}, {len(batches)} query frames, {len(exact_pooled[0])} PIRFs; "
          f"brute force {1e3 * bf:.1f} ms/frame")
    for graph in args.graphs:
        m, efc = (int(x) for x in graph.split(","))
        index = AnnIndex("faiss-hnsw", words, {**index_settings(p), "hnsw_m": m, "hnsw_ef_construction": efc}, seed=0)
        t0 = time.perf_counter()
        tuned = build_tuned(index, target=p.index_recall, jaccard=p.index_jaccard, sample=p.index_tune_sample,
                            ratio=p.ratio, seed=0)
        print(f"M {m}, efConstruction {efc}: build and tuning {time.perf_counter() - t0:.0f} s (exact search of the "
              f"sample {tuned['exact_seconds']:.0f} s), sample {tuned['sample']} with {tuned['mt_matched']} ratio-test "
              f"matches, rule {tuned['rule']}: efSearch {tuned['value']} (sample m_t recall {tuned['mt_recall']:.3f}, "
              f"Jaccard {tuned['mt_jaccard']:.3f})")
        for ef in sorted({tuned["value"], *(int(x) for x in args.ef.split(","))}):
            index.set_search("ef_search", ef)
            t0 = time.perf_counter()
            approx = [index.knn2(b) for b in batches]
            ann = (time.perf_counter() - t0) / len(batches)
            ag = agreement(exact_pooled, (np.concatenate([a[0] for a in approx]), np.concatenate([a[1] for a in approx])),
                           p.ratio)
            mark = "  <- tuned" if ef == tuned["value"] else ""
            print(f"  efSearch {ef:4d}: query run m_t recall {ag['mt_recall']:.3f}, Jaccard {ag['mt_jaccard']:.3f}, "
                  f"precision {ag['mt_precision']:.3f}; {1e3 * ann:.2f} ms/frame, {bf / ann:.1f}x brute force{mark}")


if __name__ == "__main__":
    main()
