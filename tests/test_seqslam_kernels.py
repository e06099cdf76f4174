"""The compiled enhancement and straight search against their NumPy references, bit for
bit, and against values worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.seqslam import row_kernels
from placeloc.seqslam.comparisons import difference_block
from placeloc.seqslam.matching import difference_block_t
from placeloc.seqslam.search import (
    enhance_rows_numpy,
    query_offsets,
    trajectory_offsets,
    trajectory_scores_numpy,
    velocities,
)


@pytest.mark.parametrize(("n", "nr", "window"), [(5, 100, 10), (3, 7, 10), (4, 21, 10), (7, 22, 10), (2, 5, 0),
                                                  (1, 1, 3), (33, 300, 4)])
def test_enhancement_is_the_numpy_reference_bit_for_bit(n, nr, window):
    rng = np.random.default_rng(n * 1000 + nr)
    dt = (rng.random((n, nr), dtype=np.float32) * 40).astype(np.float32)
    dt[0, : min(nr, 2 * window + 3)] = 7.0  # a flat stretch: z-score 0 there
    if n > 2:
        dt[2] = np.round(dt[2])  # repeated values: ties in the window sums
    want, got = np.empty_like(dt), np.empty_like(dt)
    enhance_rows_numpy(dt, window, 2.5, want)
    row_kernels.enhance_rows(dt, window, 2.5, got)
    np.testing.assert_array_equal(got, want)


def test_enhancement_by_hand():
    # one row 0, 1, 2, 3 with window 1: windows [0,1], [0,1,2], [1,2,3], [2,3]
    dt = np.array([[0.0, 1.0, 2.0, 3.0], [5.0, 5.0, 5.0, 5.0]], np.float32)
    out = np.empty_like(dt)
    row_kernels.enhance_rows(dt, 1, 10.0, out)
    z_end = (0.0 - 0.5) / 0.5  # mean 0.5, sd 0.5
    z_mid = 0.0  # the centre of a symmetric window
    np.testing.assert_allclose(out[0], [10 + z_end, 10 + z_mid, 10 + z_mid, 10 - z_end], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(out[1], np.float32(10.0))  # flat: z-score 0, the shift alone


@pytest.mark.parametrize("search", ["causal", "centred"])
def test_straight_search_is_the_numpy_reference_bit_for_bit(search):
    rng = np.random.default_rng(3)
    et = rng.random((120, 257), dtype=np.float32) * 5
    t_off = query_offsets(12, search)
    traj = trajectory_offsets(velocities(0.5, 2.0, 0.25), t_off)
    a, b = -int(t_off.min()), 120 - int(t_off.max())
    want = trajectory_scores_numpy(et, (a, b), t_off, traj)
    got = row_kernels.trajectory_scores(et, (a, b), t_off, traj)
    np.testing.assert_array_equal(got, want)
    edge = 0 if search == "causal" else -1  # where a speed of 2 leaves the matrix: not scored
    assert np.isinf(got[:, edge]).all() and np.isfinite(got[:, 128]).all()


def test_straight_search_by_hand():
    # et[q, r] = 10 q + r: a trajectory of speed 1 over offsets -1, 0, 1 at anchor (T, r)
    # sums 10 (T-1) + (r-1) + 10 T + r + 10 (T+1) + (r+1) = 30 T + 3 r
    et = (10 * np.arange(5)[:, None] + np.arange(6)[None, :]).astype(np.float32)
    t_off = np.array([-1, 0, 1])
    s = row_kernels.trajectory_scores(et, (1, 4), t_off, trajectory_offsets(np.array([1.0]), t_off))
    want = np.full((3, 6), np.inf, np.float32)
    for T in (1, 2, 3):
        want[T - 1, 1:5] = 30 * T + 3 * np.arange(1, 5)
    np.testing.assert_array_equal(s, want)


def test_straight_search_refuses_rows_whose_window_leaves_the_matrix():
    et = np.zeros((10, 4), np.float32)
    t_off = np.array([-2, 0, 2])
    with pytest.raises(ValueError, match="leave"):
        row_kernels.trajectory_scores(et, (1, 5), t_off, trajectory_offsets(np.array([1.0]), t_off))


@pytest.mark.parametrize("comparison", ["sad", "histeq", "zncc"])
def test_query_major_difference_block_is_the_transpose(comparison):
    rng = np.random.default_rng(8)
    if comparison == "zncc":
        ref, query = rng.standard_normal((40, 16)).astype(np.float32), rng.standard_normal((23, 16)).astype(np.float32)
    else:
        ref, query = rng.integers(0, 256, (40, 64), np.uint8), rng.integers(0, 256, (23, 64), np.uint8)
    got = difference_block_t(ref, query, comparison)
    assert got.flags.c_contiguous and got.shape == (23, 40)
    np.testing.assert_array_equal(got, difference_block(ref, query, comparison).T)


def test_flat_variance_is_the_threshold_the_numpy_reference_uses():
    # one bump of height h in a window of 7: variance h^2 (1/7 - 1/49) = 0.122 h^2, so
    # h = 3e-6 lies above FLAT_VARIANCE (scored) and h = 2e-6 below it (flat, z-score 0)
    assert row_kernels.FLAT_VARIANCE == 1e-12
    for h, scored in ((3e-6, True), (2e-6, False)):
        dt = np.array([[0.0, 0.0, 0.0, h, 0.0, 0.0, 0.0]], np.float32)
        out, ref = np.empty_like(dt), np.empty_like(dt)
        row_kernels.enhance_rows(dt, 3, 0.0, out)
        enhance_rows_numpy(dt, 3, 0.0, ref)
        np.testing.assert_array_equal(out, ref)
        assert bool(out[0, 3] > 2.0) is scored  # the bump's own z-score: (h - h/7) / sd = sqrt(6)


@pytest.mark.parametrize("seed", range(4))
def test_ranking_is_the_numpy_reference_bit_for_bit(seed):
    from placeloc.seqslam.search import top_k_numpy

    rng = np.random.default_rng(seed)
    for _ in range(40):
        n, nr = int(rng.integers(1, 6)), int(rng.integers(1, 300))
        window, k = int(rng.integers(0, 30)), int(rng.integers(1, 12))
        s = rng.integers(0, 20, (n, nr)).astype(np.float32)  # many ties: the first reference wins
        s[rng.random((n, nr)) < 0.2] = np.inf  # left out: never picked
        want = top_k_numpy(s.copy(), window, k)
        got = row_kernels.top_k(s.copy(), window, k)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])


def test_ranking_by_hand():
    s = np.array([[5, 1, 4, 1, 9, 0, 7, np.inf, 3, 2]], np.float32)
    # window 1: 0 (at 5), then 1 at 1 (3 is free too but 1 comes first), then 1 at 3, then 2 at 9
    best, scores = row_kernels.top_k(s.copy(), 1, 5)
    np.testing.assert_array_equal(best, [[5, 1, 3, 9, -1]])
    np.testing.assert_array_equal(scores, [[0, 1, 1, 2, np.inf]])
    # window 0, the plain ranking: every reference in order of score, ties by position
    best, _ = row_kernels.top_k(s.copy(), 0, 9)
    np.testing.assert_array_equal(best, [[5, 1, 3, 9, 8, 2, 0, 6, 4]])
