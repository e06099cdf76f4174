"""Queries of the whole-panorama search on threads of their own (``panorama_threads``): the
same answers to the bit as one after another, a render cache that threads share, and no
threads where numba's threading layer cannot take them."""

from __future__ import annotations

import threading
from dataclasses import replace

import numba
import numpy as np
import pytest
from test_umap_oriented import _oriented
from test_umap_panorama import PLAN, H

import placeloc.umap.panorama as panorama
from placeloc.geometry.floorplan import floor_plan_model, plan_grid
from placeloc.umap.panorama import RenderCache, chamfer_spectra, panorama_threads, row_weights, search_panoramas
from placeloc.umap.params import PanoramaParams


def _answers(threads, monkeypatch, batch):
    """Every field of search_panoramas' answers for seven cameras of the L-shaped room (the
    oriented score, 4 bins), the queries searched on ``threads`` threads, ``batch`` a batch."""
    monkeypatch.setattr(panorama, "PANORAMA_THREADS", threads)
    monkeypatch.setattr(panorama, "PANORAMA_BATCH", batch)
    m = floor_plan_model(PLAN)
    truth = np.array([[5.653, 1.374, 1.4, 117.5], [0.347, 5.516, 1.4, 250.0], [3.207, 0.404, 1.4, 30.0],
                      [1.803, 6.617, 1.4, 200.0], [1.234, 2.871, 1.4, 75.0], [4.71, 3.13, 1.4, 300.0],
                      [2.5, 2.5, 1.4, 10.0]])
    q = _oriented(m, truth, 4)
    q[..., ::3, ::4] = 0                                      # a few line pixels lost
    pp = replace(PanoramaParams(), orientation_bins=4)
    wts = row_weights(H, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
    poses, _ = plan_grid(m, x=[0.2, 6.0, 0.3], y=[0.2, 7.0, 0.3], z=1.4, headings=[0.0])
    db = {"spectra": chamfer_spectra(_oriented(m, poses, 4), tau_px=pp.chamfer_tau_px, weights=wts,
                                     spread=pp.orientation_spread)}
    done = []
    answers = search_panoramas(q, poses, m.segments, m.faces, db, pp, tolerance_px=2, wall_margin_m=0.1, hidden=True,
                               progress=lambda it: (done.append(k) or k for k in it))
    return answers, sorted(done), truth


def test_threads_give_the_same_answers_to_the_bit(monkeypatch):
    if not _layer_known() or numba.threading_layer() not in ("omp", "tbb"):
        pytest.skip("numba's threading layer here is workqueue: the search runs its queries one after another")
    one, done_one, truth = _answers(1, monkeypatch, batch=32)
    for threads, batch in ((3, 32), (3, 2), (8, 4)):
        many, done_many, _ = _answers(threads, monkeypatch, batch=batch)
        for name, a, b in zip(one._fields, one, many):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=f"{name}, {threads} threads")
        assert done_many == done_one == list(range(len(truth)))   # each query reported once as it ended
    # and they are right: every camera within 0.05 m (the off-grid search's own test)
    assert np.hypot(*(one.xy - truth[:, :2]).T).max() <= 0.05


def _layer_known():
    panorama.panorama_threads(2)                              # runs a parallel kernel: numba picks its layer
    try:
        numba.threading_layer()
    except ValueError:
        return False
    return True


def test_panorama_threads_follows_the_threading_layer_and_the_setting(monkeypatch):
    monkeypatch.setattr(panorama, "PANORAMA_THREADS", 6)
    monkeypatch.setattr(numba, "threading_layer", lambda: "omp")
    assert panorama_threads(4) == 4                           # never more than the queries
    assert panorama_threads(10) == 6
    assert panorama_threads(1) == 1
    monkeypatch.setattr(numba, "threading_layer", lambda: "tbb")
    assert panorama_threads(10) == 6
    # workqueue aborts the process when two threads call its kernels at once
    monkeypatch.setattr(numba, "threading_layer", lambda: "workqueue")
    assert panorama_threads(10) == 1
    monkeypatch.setattr(panorama, "PANORAMA_THREADS", None)
    monkeypatch.setattr(panorama, "usable_cores", lambda: 3)
    monkeypatch.setattr(numba, "threading_layer", lambda: "omp")
    assert panorama_threads(10) == 3                          # the usable cores by default


def test_render_cache_shared_by_threads_returns_each_point_s_own_render():
    # a render that is a function of the point alone (its coordinates' digits), slowed so that
    # threads overlap: every thread gets each of its points' own render, kept ones included,
    # and the cache never holds more than its bytes
    def render(pts):
        threading.Event().wait(0.001)
        return np.round(pts * 1000).astype(np.int64)

    cache = RenderCache(render, max_bytes=40 * 16)
    rng = np.random.default_rng(0)
    points = np.round(rng.uniform(0, 1, (60, 2)), 3)
    errors = []

    def worker(seed):
        r = np.random.default_rng(seed)
        for _ in range(40):
            pts = points[r.integers(0, len(points), 7)]
            got = cache(pts)
            if not np.array_equal(got, np.round(pts * 1000).astype(np.int64)):
                errors.append(seed)

    threads = [threading.Thread(target=worker, args=(s,)) for s in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert cache.bytes <= 40 * 16 and cache.bytes == sum(v.nbytes for v in cache.kept.values())
    assert cache.rendered + cache.reused == 6 * 40 * 7 and cache.reused > 0
