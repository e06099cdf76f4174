"""Co-embedding solver benchmark: 10,000 steps x 2,000 features at 5 % fill.

Prints the solve time and the peak memory (resident set) of the sparse closed form, then,
in the same run, the literal dense solve of eq. (11) against the sparse one at a size where
the dense (M K) x (M K) system still fits, with the ratio of their times and their largest
difference. Run: ``make bench-coembed`` or ``python bench/bench_coembed.py [--steps M --features N --fill F]``.
Last, the sparse solve on 1, 2, 4, ..., nproc cores (this process pinned with
``sched_setaffinity``; the sparse factorisation and BLAS follow the affinity), best of 2;
``--workers 1,2`` chooses the counts, ``--workers 0`` leaves the table out.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from placeloc.coembed.observations import from_triplets  # noqa: E402
from placeloc.coembed.solver import coembed_map, coembed_map_dense  # noqa: E402


def make_problem(m: int, n: int, fill: float, seed: int = 0, n_landmarks: int = 20):
    """Bearing-like scalar sightings: step t sees feature i at y = a_t . x_i + b_t + noise, on a random 5 % mask."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 100, (n, 2))
    mask = rng.random((m, n)) < fill if m * n <= 5e7 else None
    if mask is None:   # draw the mask row by row to keep the generator itself small
        rows, cols = [], []
        for t in range(m):
            c = np.flatnonzero(rng.random(n) < fill)
            rows.append(np.full(len(c), t))
            cols.append(c)
        t_idx, i_idx = np.concatenate(rows), np.concatenate(cols)
    else:
        t_idx, i_idx = np.nonzero(mask)
    a = rng.standard_normal((m, 2))
    b = rng.standard_normal(m)
    y = np.einsum("nk,nk->n", a[t_idx], x[i_idx]) + b[t_idx] + rng.normal(0, 0.01, len(t_idx))
    obs = from_triplets(t_idx, i_idx, y)
    lm = obs.columns_of(np.arange(n_landmarks))
    return obs, lm, x[obs.feature_ids[lm]]


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0   # Linux reports KiB


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument("--features", type=int, default=2_000)
    ap.add_argument("--fill", type=float, default=0.05)
    ap.add_argument("--dense-steps", type=int, default=2_000)
    ap.add_argument("--dense-features", type=int, default=400)
    ap.add_argument("--workers", default=None, help="core counts of the scaling table (default 1, 2, 4, ..., nproc; 0: none)")
    args = ap.parse_args()
    print(f"cpu cores: {os.cpu_count()}, numpy {np.__version__}")

    obs, lm, xs = make_problem(args.steps, args.features, args.fill)
    rss0 = peak_rss_mb()
    t0 = time.perf_counter()
    res = coembed_map(obs, lm, xs, alpha=1000.0)
    dt = time.perf_counter() - t0
    rss1 = peak_rss_mb()
    print(f"sparse co-embedding: {obs.n_steps} steps x {obs.n_features} features, {obs.nnz} sightings "
          f"({obs.nnz / (obs.n_steps * obs.n_features):.1%} fill): {dt:.2f} s, peak RSS {rss1:.0f} MB "
          f"(problem alone {rss0:.0f} MB); map finite: {bool(np.isfinite(res.X).all())}")
    kk = obs.value_dim + 1
    print(f"  the dense system (11) at this size would be {obs.n_steps * kk} x {obs.n_steps * kk}: "
          f"{(obs.n_steps * kk) ** 2 * 8 / 2**30:.1f} GiB for the matrix alone")
    print(f"  targets: < 30 s {'MET' if dt < 30 else 'MISSED'}, < 2 GB {'MET' if rss1 < 2048 else 'MISSED'}")

    obs2, lm2, xs2 = make_problem(args.dense_steps, args.dense_features, args.fill, seed=1)
    t0 = time.perf_counter()
    fast = coembed_map(obs2, lm2, xs2, alpha=1000.0).X
    t_fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    dense = coembed_map_dense(obs2, lm2, xs2, alpha=1000.0)
    t_dense = time.perf_counter() - t0
    print(f"dense vs sparse at {obs2.n_steps} steps x {obs2.n_features} features ({obs2.n_steps * kk}^2 dense system): "
          f"dense {t_dense:.2f} s, sparse {t_fast:.3f} s, ratio {t_dense / t_fast:.0f}x, "
          f"max |difference| {np.abs(fast - dense).max():.2e} (map extent 100)")
    if args.workers != "0" and hasattr(os, "sched_setaffinity"):
        scaling(obs, lm, xs, args.workers)


def scaling(obs, lm, xs, workers: str | None) -> None:
    """The sparse solve pinned to 1, 2, 4, ... cores: which part of it scales with cores."""
    from scaling import counts_from, markdown, on_first_cores, scaling_table

    def measure(k: int) -> dict[str, float]:
        with on_first_cores(k):
            t0 = time.perf_counter()
            coembed_map(obs, lm, xs, alpha=1000.0)
            return {f"sparse co-embedding, {obs.n_steps} x {obs.n_features}": time.perf_counter() - t0}

    print(markdown(scaling_table(measure, counts_from(workers), repeat=2, warm_up=False), "co-embedding solve", unit="core",
                   note="This process pinned to the first k cores; best of 2."))


if __name__ == "__main__":
    main()
