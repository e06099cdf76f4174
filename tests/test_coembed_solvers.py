"""Known-answer tests for the co-embedding solver, Wiberg, Isomap and the alignment."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.coembed.align import AlignmentError, align_to_landmarks, apply_affine, fit_affine
from placeloc.coembed.isomap import IsomapError, feature_distances, isomap_from_distances, isomap_points
from placeloc.coembed.observations import ObservationError, from_triplets
from placeloc.coembed.solver import CoembedError, coembed_map, coembed_map_dense, estimate_path
from placeloc.coembed.wiberg import WibergError, wiberg


def linear_world(seed: int = 0, n: int = 60, m: int = 40, fill: float = 0.4, k: int = 2):
    """Map X (n x 2); step t sees y = A_t x + b_t (k-D, A_t full rank): exactly invertible by some T_t."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 10, (n, 2))
    st, fe, va = [], [], []
    for t in range(m):
        a = rng.standard_normal((k, 2)) + 2 * np.eye(k, 2)
        b = rng.standard_normal(k)
        seen = np.flatnonzero(rng.random(n) < fill)
        for i in seen:
            st.append(t)
            fe.append(i + 100)  # ids that are not column numbers, to exercise the id mapping
            va.append(a @ x[i] + b)
    obs = from_triplets(np.array(st), np.array(fe), np.array(va))
    return obs, x[obs.feature_ids - 100]


@pytest.mark.parametrize("alpha", [1.0, 10.0, 1000.0])
def test_noise_free_linear_observations_give_the_map_exactly(alpha):
    obs, x = linear_world()
    lm = obs.columns_of([100, 101, 102, 103])
    res = coembed_map(obs, lm, x[lm], alpha=alpha)
    assert np.abs(res.X - x).max() < 1e-8
    # Every single sighting maps onto its feature: T_t z_{t,i} = x_i.
    assert np.abs(res.per_step - x[obs.indices]).max() < 1e-7


def test_fast_solve_matches_the_literal_closed_form_11_on_noisy_data():
    obs, x = linear_world(seed=3, n=40, m=30)
    obs.values += np.random.default_rng(1).normal(0, 0.3, obs.values.shape)
    lm = obs.columns_of([100, 101, 102, 103, 104])
    fast = coembed_map(obs, lm, x[lm], alpha=5.0).X
    dense = coembed_map_dense(obs, lm, x[lm], alpha=5.0)
    assert np.abs(fast - dense).max() < 1e-8
    assert np.abs(fast - x).max() > 1e-3  # noise really moved it: the comparison is not trivial


def test_landmark_weight_pulls_the_map_to_conflicting_landmarks():
    obs, x = linear_world(seed=2)
    lm = obs.columns_of([100, 101, 102, 103])
    target = x[lm].copy()
    target[0] += 5.0  # inconsistent with the others: the larger alpha, the closer x^_0 gets to it
    gaps = [np.linalg.norm(coembed_map(obs, lm, target, alpha=a).X[lm[0]] - target[0]) for a in (0.1, 1.0, 100.0)]
    assert gaps[0] > gaps[1] > gaps[2]


def test_too_few_landmarks_is_a_clear_error():
    obs, x = linear_world()
    lm = obs.columns_of([100, 101])
    with pytest.raises(CoembedError, match="at least 3 landmarks"):
        coembed_map(obs, lm, x[lm], alpha=10.0)


def test_groups_never_observed_together_need_their_own_landmarks():
    obs_a, xa = linear_world(seed=0, n=20, m=10)
    st = np.concatenate([obs_a.rows, obs_a.rows + 10])
    fe = np.concatenate([obs_a.feature_ids[obs_a.indices], obs_a.feature_ids[obs_a.indices] + 1000])
    va = np.vstack([obs_a.values, obs_a.values])
    obs = from_triplets(st, fe, va)
    lm = obs.columns_of([100, 101, 102, 103])
    with pytest.raises(CoembedError, match="never seen together"):
        coembed_map(obs, lm, np.vstack([xa[:4]]), alpha=10.0)


def test_unknown_or_unobserved_landmark_id_is_a_clear_error():
    obs, _ = linear_world()
    with pytest.raises(ObservationError, match=r"landmark id\(s\) \[7\]"):
        obs.columns_of([100, 7], "landmark")


def test_bad_observation_rows_are_rejected():
    with pytest.raises(ObservationError, match="observed twice"):
        from_triplets([0, 0], [1, 1], [0.5, 0.7])
    with pytest.raises(ObservationError, match="not a finite number"):
        from_triplets([0, 1], [1, 1], [0.5, np.nan])
    with pytest.raises(ObservationError, match="empty"):
        from_triplets([], [], np.zeros((0, 1)))


def test_explicit_zero_observations_stay_in_the_mask():
    obs = from_triplets([0, 0, 1], [5, 6, 5], [0.0, 1.0, 0.0])
    assert obs.mask().nnz == 3


def test_path_closed_form_16_recovers_an_affine_function_of_the_transforms():
    rng = np.random.default_rng(0)
    m = 200
    t = rng.standard_normal((m, 2, 2))
    h = rng.standard_normal((5, 2))
    truth = np.hstack([t.reshape(m, -1), np.ones((m, 1))]) @ h
    labels = np.arange(0, m, 20)
    est = estimate_path(t, labels, truth[labels], beta=0.0)
    assert np.abs(est - truth).max() < 1e-9
    smooth = estimate_path(t, labels, truth[labels], beta=10.0)  # smoothing trades label fit for smoothness
    assert np.sum(np.diff(smooth, axis=0) ** 2) < np.sum(np.diff(est, axis=0) ** 2)
    with pytest.raises(CoembedError, match="known poses"):
        estimate_path(t, [], np.zeros((0, 2)), beta=1.0)


def test_wiberg_recovers_a_low_rank_matrix_with_missing_entries():
    rng = np.random.default_rng(1)
    m, n, r = 60, 80, 3
    full = rng.standard_normal((m, r)) @ rng.standard_normal((r, n))
    mask = rng.random((m, n)) < 0.45
    i, j = np.nonzero(mask)
    res = wiberg(i, j, full[i, j], (m, n), r, max_iter=200, tol=1e-12, seed=0)
    assert res.converged
    assert np.abs(res.U @ res.V.T - full).max() < 1e-6   # including the 55 % never observed
    assert np.allclose(res.U.T @ res.U, np.eye(r), atol=1e-10)


def test_wiberg_from_a_poor_start_still_converges():
    rng = np.random.default_rng(4)
    m, n, r = 30, 40, 2
    full = rng.standard_normal((m, r)) @ rng.standard_normal((r, n))
    i, j = np.nonzero(rng.random((m, n)) < 0.6)
    res = wiberg(i, j, full[i, j], (m, n), r, max_iter=200, tol=1e-12, seed=0, init=rng.standard_normal((m, r)))
    assert np.abs(res.U @ res.V.T - full).max() < 1e-6


def test_wiberg_rejects_too_few_observations():
    with pytest.raises(WibergError, match="degrees of freedom"):
        wiberg(np.arange(5), np.arange(5), np.ones(5), (10, 10), 2, max_iter=200, tol=1e-12, seed=0)


def test_isomap_unrolls_a_swiss_roll():
    rng = np.random.default_rng(0)
    n = 500
    s = rng.uniform(1.5 * np.pi, 4.5 * np.pi, n)   # angle along the roll
    h = rng.uniform(0, 15, n)
    pts = np.column_stack([s * np.cos(s), h, s * np.sin(s)])
    arc = 0.5 * (s * np.sqrt(1 + s ** 2) + np.arcsinh(s))   # arc length: the intrinsic coordinate
    truth = np.column_stack([arc, h])
    emb = isomap_points(pts, n_neighbors=10, dim=2)
    aligned = apply_affine(emb, fit_affine(emb, truth))
    rmse = np.sqrt(np.mean(np.sum((aligned - truth) ** 2, axis=1)))
    assert rmse < 0.03 * np.ptp(arc)
    # Plain MDS (a complete graph = Euclidean distances) cannot unroll it: the geodesics matter.
    flat = isomap_points(pts, n_neighbors=n - 1, dim=2)
    flat_rmse = np.sqrt(np.mean(np.sum((apply_affine(flat, fit_affine(flat, truth)) - truth) ** 2, axis=1)))
    assert flat_rmse > 3 * rmse


def test_isomap_distances_with_missing_entries_match_brute_force():
    rng = np.random.default_rng(2)
    m, n = 12, 6
    y = rng.standard_normal((m, n))
    mask = rng.random((m, n)) < 0.7
    t, i = np.nonzero(mask)
    obs = from_triplets(t, i, y[t, i])
    d = feature_distances(obs, min_common=1)
    for a in range(n):
        for b in range(n):
            common = mask[:, a] & mask[:, b]
            want = np.sqrt(np.mean((y[common, a] - y[common, b]) ** 2) * m) if common.any() else np.inf
            assert d[a, b] == pytest.approx(want) if a != b else d[a, b] == 0


def test_isomap_refuses_disconnected_data():
    d = np.full((6, 6), np.inf)
    d[:3, :3] = 1.0
    d[3:, 3:] = 1.0
    np.fill_diagonal(d, 0)
    with pytest.raises(IsomapError, match="2 groups"):
        isomap_from_distances(d, 2, 2)


def test_affine_alignment_recovers_a_known_transform():
    rng = np.random.default_rng(5)
    src = rng.standard_normal((30, 3))
    a = rng.standard_normal((3, 2))
    dst = src @ a + [4.0, -2.0]
    coef = fit_affine(src[:6], dst[:6])
    assert np.allclose(apply_affine(src, coef), dst)
    assert np.allclose(align_to_landmarks(src, np.arange(5), dst[:5]), dst)


def test_alignment_errors_are_clear():
    with pytest.raises(AlignmentError, match="at least 3 landmarks"):
        fit_affine(np.zeros((2, 2)), np.zeros((2, 2)))
    line = np.column_stack([np.arange(5.0), 2 * np.arange(5.0)])
    with pytest.raises(AlignmentError, match="degenerate"):
        fit_affine(line, line)


def test_poses_are_read_by_the_one_pose_reader_sorted_by_step(tmp_path):
    from placeloc.coembed.observations import poses_by_step
    from placeloc.evaluation.poses import PoseError

    (tmp_path / "p.csv").write_text("t,x,y,heading\n2,1,1,0\n0,0,0,0.5\n1,0.5,0.5,0.2\n")
    steps, xy, heading = poses_by_step(tmp_path / "p.csv")
    assert steps.tolist() == [0, 1, 2] and xy[:, 0].tolist() == [0, 0.5, 1] and heading.tolist() == [0.5, 0.2, 0]
    (tmp_path / "d.csv").write_text("t,x,y\n1,0,0\n1,1,1\n")
    with pytest.raises(PoseError, match="twice"):
        poses_by_step(tmp_path / "d.csv")
    (tmp_path / "n.csv").write_text("image,x,y\na.png,0,0\n")
    with pytest.raises(PoseError, match="integer time steps"):
        poses_by_step(tmp_path / "n.csv")
