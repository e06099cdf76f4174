"""UMap benchmark: render a 36,032-view database of the synthetic corridor building (the
paper's grid size), pack and dilate it, and score one query against every view with the
bit-packed AND + popcount kernel versus the naive per-view NumPy loop, in one run.

    PYTHONPATH=. python bench/bench_umap.py [--views 36032]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import cv2
import numba
import numpy as np
from placeloc.geometry import Camera, pose_grid
from placeloc.geometry.floorplan import floor_plan_model
from placeloc.synth.corridor import building
from placeloc.umap.bits import iou_naive, iou_scores, pack, popcount_rows, unpack
from placeloc.umap.render import render_packed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--views", type=int, default=36032)
    ap.add_argument("--tolerance", type=int, default=2)
    args = ap.parse_args()
    model = floor_plan_model(building())
    cam = Camera(160, 120, 60.0)
    grid = pose_grid([0.0, 90.0, 0.1], [-1.5, 4.0, 0.2], 1.14, [45.0, 135.0, 225.0, 315.0])
    grid = grid[model.inside(grid[:, :2])]
    # the paper's count: an evenly spread subset of the inside poses of the paper's grid
    poses = grid[np.linspace(0, len(grid) - 1, min(args.views, len(grid))).round().astype(int)]
    print(f"cores: {os.cpu_count()}, numba threads: {numba.get_num_threads()}, model: {len(model.segments)} segments, "
          f"{len(model.faces)} faces; grid inside the plan: {len(grid)} views, benchmarked: {len(poses)}")
    render_packed(model.segments, model.faces, poses[:64], cam)  # JIT warm-up (cached after the first run)
    t0 = time.perf_counter()
    db = render_packed(model.segments, model.faces, poses, cam)
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * args.tolerance + 1,) * 2)
    for s in range(0, len(db), 2048):
        db[s:s + 2048] = pack(np.stack([cv2.dilate(im, kernel) for im in unpack(db[s:s + 2048], cam.height, cam.width)]))
    counts = popcount_rows(db)
    t_index = time.perf_counter() - t0
    mem = db.nbytes + counts.nbytes + poses.nbytes
    print(f"render database: {t_render:.2f} s ({len(poses) / t_render:,.0f} views/s; target < 60 s)")
    print(f"pack + dilate {args.tolerance} px + counts: {t_index:.2f} s")
    print(f"database memory: {mem / 2**20:.1f} MiB ({db.shape[1]} words/view; target < 200 MB)")

    # a query: a database view with a third of its lines lost and clutter added
    rng = np.random.default_rng(0)
    q = unpack(db[len(db) // 3], cam.height, cam.width)
    q = (q & (rng.random(q.shape) < 0.66)) | (rng.random(q.shape) < 0.01)
    qw = pack(q)
    iou_scores(db, counts, qw)
    times = []
    for _ in range(30):
        t0 = time.perf_counter()
        fast = iou_scores(db, counts, qw)
        times.append(time.perf_counter() - t0)
    t_fast = statistics.median(times)
    imgs = unpack(db, cam.height, cam.width)
    t0 = time.perf_counter()
    naive = iou_naive(imgs, q)
    t_naive = time.perf_counter() - t0
    t0 = time.perf_counter()
    packed_loop = np.array([np.bitwise_count(db[i] & qw).sum() for i in range(len(db))])
    t_packed_loop = time.perf_counter() - t0
    assert np.allclose(fast, naive), "fast and naive scores differ"
    assert int(np.argmax(fast)) == int(np.argmax(naive))
    assert packed_loop.sum() >= 0
    print(f"score one query vs {len(db)} views: {t_fast * 1e3:.2f} ms (median of 30; target < 20 ms)")
    print(f"naive per-view NumPy AND/count loop (unpacked images): {t_naive * 1e3:.0f} ms -> speed-up {t_naive / t_fast:.0f}x (target >= 20x)")
    print(f"per-view loop on packed words (np.bitwise_count): {t_packed_loop * 1e3:.0f} ms -> speed-up {t_packed_loop / t_fast:.0f}x")


if __name__ == "__main__":
    main()
