"""Sequence search and contrast enhancement against planted answers and naive code."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.seqslam.search import (
    confidence,
    enhance,
    enhancement_shift,
    query_offsets,
    sequence_search,
    trajectory_offsets,
    velocities,
)


def test_velocities_and_offsets():
    np.testing.assert_allclose(velocities(0.8, 1.2, 0.1), [0.8, 0.9, 1.0, 1.1, 1.2])
    np.testing.assert_array_equal(query_offsets(4, "causal"), [-4, -3, -2, -1, 0])
    np.testing.assert_array_equal(query_offsets(4, "centred"), [-2, -1, 0, 1, 2])
    np.testing.assert_array_equal(trajectory_offsets(np.array([1.5]), np.array([-2, -1, 0, 1, 2]))[0], [-3, -2, 0, 2, 3])


def test_enhance_matches_naive_per_column_zscore():
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 5, (30, 7)).astype(np.float32)
    R = 4
    e = enhance(d, R)
    for q in range(7):
        for r in range(30):
            w = d[max(0, r - R):r + R + 1, q].astype(np.float64)
            expect = (d[r, q] - w.mean()) / w.std() + enhancement_shift(R)
            assert e[r, q] == pytest.approx(expect, rel=1e-4, abs=1e-4)
    assert (e >= -1e-5).all()


@pytest.mark.parametrize("search", ["causal", "centred"])
@pytest.mark.parametrize("v_true", [0.8, 1.0, 1.2])
def test_search_finds_planted_diagonal_at_known_velocity(search, v_true):
    rng = np.random.default_rng(3)
    n_ref, n_q, ds = 200, 120, 10
    d = rng.uniform(0.6, 1.0, (n_ref, n_q)).astype(np.float32)
    r0 = 30
    truth = np.rint(r0 + v_true * np.arange(n_q)).astype(int)
    d[truth, np.arange(n_q)] = rng.uniform(0.0, 0.3, n_q)  # the planted route
    # distractor: single-frame lows that no trajectory connects
    d[rng.integers(0, n_ref, 200), rng.integers(0, n_q, 200)] = 0.0
    et = np.ascontiguousarray(enhance(d, 10).T)
    best, scores = sequence_search(et, 0, n_q, ds, velocities(0.8, 1.2, 0.1), search, 10, 3, None, 0, shape="trajectory", edges="skip")
    t = query_offsets(ds, search)
    valid = np.arange(n_q)[(np.arange(n_q) + t.min() >= 0) & (np.arange(n_q) + t.max() < n_q)]
    assert (best[: valid[0], 0] == -1).all()  # no full window: no match
    err = np.abs(best[valid, 0] - truth[valid])
    assert (err <= 1).mean() > 0.97
    assert (scores[valid, 0] <= scores[valid, 1]).all()
    # the second candidate lies outside the window around the first
    assert (np.abs(best[valid, 1] - best[valid, 0]) > 10).all()


def test_loop_closure_excludes_recent_frames():
    rng = np.random.default_rng(4)
    n = 150
    d = rng.uniform(0.5, 1.0, (n, n)).astype(np.float32)
    np.fill_diagonal(d, 0.0)  # a traverse is identical to itself
    d[np.arange(20, 40), np.arange(100, 120)] = 0.05  # revisit: frames 100..119 see 20..39 again
    et = np.ascontiguousarray(enhance(d, 5).T)
    best, _ = sequence_search(et, 0, n, 5, velocities(1.0, 1.0, 0.1), "causal", 5, 2, 30, 0, shape="trajectory", edges="skip")
    for q in range(n):
        if best[q, 0] >= 0:
            assert best[q, 0] <= q - 30
    np.testing.assert_array_equal(best[110:120, 0], np.arange(30, 40))


def test_confidence_from_best_and_second():
    s = np.array([[1.0, 2.0], [2.0, 2.0], [np.inf, np.inf]], np.float32)
    np.testing.assert_allclose(confidence(s), [0.5, 0.0, 0.0])


@pytest.mark.parametrize("shape", ["trajectory", "cone", "hybrid", "flexible"])
@pytest.mark.parametrize("edges", ["skip", "shift"])
def test_plain_ranking_from_the_same_pass_equals_a_search_without_separation(shape, edges):
    """``plain`` is filled from the scores the separated ranking uses: it must equal a search
    of its own with no separation (window 0), row for row, edge queries included."""
    rng = np.random.default_rng(3)
    et = rng.random((70, 90)).astype(np.float32) * 3
    vels = velocities(0.8, 1.2, 0.1)
    p_k = 6
    plain = (np.full((70, p_k), -1, np.int64), np.full((70, p_k), np.inf, np.float32))
    best, scores = sequence_search(et, 0, 70, 8, vels, "centred", 5, 3, None, 0, shape=shape, edges=edges, plain=plain)
    alone_best, alone_scores = sequence_search(et, 0, 70, 8, vels, "centred", 0, p_k, None, 0, shape=shape, edges=edges)
    np.testing.assert_array_equal(plain[0], alone_best)
    np.testing.assert_array_equal(plain[1], alone_scores)
    # and the separated ranking is the one a search without ``plain`` gives
    sep_best, sep_scores = sequence_search(et, 0, 70, 8, vels, "centred", 5, 3, None, 0, shape=shape, edges=edges)
    np.testing.assert_array_equal(best, sep_best)
    np.testing.assert_array_equal(scores, sep_scores)
