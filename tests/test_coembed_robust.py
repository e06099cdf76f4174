"""Co-embedding does not depend on the image origin or units, chooses its settings from the landmarks, and handles perspective."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.coembed.camera import Intrinsics, normalised_coordinates, read_intrinsics
from placeloc.coembed.landmarks import farthest_point_landmarks, landmark_warnings
from placeloc.coembed.observations import ObservationError, Observations, from_triplets
from placeloc.coembed.perspective import perspective_coembed
from placeloc.coembed.solver import coembed_map, coembed_operator, estimate_path, solve_landmarks
from placeloc.coembed.tuning import loo_alpha, loo_isomap_neighbors


def pinhole_world(seed=0, n=40, m=60, noise=0.5):
    """A camera sliding sideways past points 4-30 m away, seen in pixels (f 800, centre 640, 360)."""
    rng = np.random.default_rng(seed)
    x = np.column_stack([rng.uniform(-6, 6, n), rng.uniform(-2, 2, n), rng.uniform(4, 30, n)])
    st, fe, va = [], [], []
    for t in range(m):
        c = np.array([-3 + 6 * t / m, 0.1 * np.sin(t / 7), 0.5 * t / m])
        yaw = np.deg2rad(8) * (t / m - 0.5)
        r = np.array([[np.cos(yaw), 0, -np.sin(yaw)], [0, 1, 0], [np.sin(yaw), 0, np.cos(yaw)]])
        pc = (x - c) @ r.T
        uv = 800 * pc[:, :2] / pc[:, 2:] + [640, 360] + rng.normal(0, noise, (n, 2))
        seen = rng.random(n) < 0.6
        st += [t] * int(seen.sum())
        fe += list(np.flatnonzero(seen))
        va.append(uv[seen])
    return from_triplets(np.array(st), np.array(fe), np.vstack(va)), x


def test_map_and_path_do_not_change_when_image_coordinates_are_shifted_or_scaled():
    obs, x = pinhole_world()
    lm = np.arange(8)
    base = coembed_map(obs, lm, x[lm], alpha=100.0)
    for shift, scale in ((10_000.0, 1.0), (0.0, 3.0), (-5_000.0, 0.01)):
        moved = Observations(obs.indptr, obs.indices, obs.values * scale + shift, obs.step_ids, obs.feature_ids)
        res = coembed_map(moved, lm, x[lm], alpha=100.0)
        assert np.abs(res.X - base.X).max() < 1e-7 * np.abs(base.X).max()
        # The path read-out (16) is affine in vec(T_t): with T_t in globally standardised coordinates it is unchanged too.
        targets = np.random.default_rng(1).standard_normal((obs.n_steps, 2))
        labels = np.arange(0, obs.n_steps, 5)
        a = estimate_path(base.T, labels, targets[labels], beta=1.0)
        b = estimate_path(res.T, labels, targets[labels], beta=1.0)
        assert np.abs(a - b).max() < 1e-6


def test_a_step_with_one_sighting_is_rank_deficient_not_fatal_at_any_offset():
    obs, x = pinhole_world(n=20, m=15)
    # Step 15 sees one feature only: its D_t has rank 1 whatever the offset (the old pseudo-inverse with a
    # fixed rcond lost a direction in every step once 10,000 px were added).
    st = np.concatenate([obs.rows, [15]])
    fe = np.concatenate([obs.feature_ids[obs.indices], [3]])
    va = np.vstack([obs.values, obs.values[:1]])
    one = from_triplets(st, fe, va)
    lm = np.arange(8)
    a = coembed_map(one, lm, x[lm], alpha=10.0).X
    shifted = Observations(one.indptr, one.indices, one.values + 10_000.0, one.step_ids, one.feature_ids)
    b = coembed_map(shifted, lm, x[lm], alpha=10.0).X
    assert np.all(np.isfinite(a)) and np.abs(a - b).max() < 1e-6


def test_leave_one_out_picks_a_large_alpha_for_exact_data_and_never_reads_the_unknowns():
    obs, x = pinhole_world(noise=0.0)
    lm = np.arange(10)
    choice = loo_alpha(obs, lm, x[lm], candidates=(0.01, 1.0, 100.0))
    assert set(choice.scores) == {0.01, 1.0, 100.0} and choice.value == min(choice.scores, key=choice.scores.get)
    scrambled = Observations(obs.indptr, obs.indices, obs.values.copy(), obs.step_ids, obs.feature_ids)
    # The truth of the unknown points is not an input: the choice depends only on observations and landmarks.
    assert loo_alpha(scrambled, lm, x[lm], candidates=(0.01, 1.0, 100.0)).scores == choice.scores
    # The rank-one shortcut gives the same errors as solving each hold-out problem from scratch.
    g = coembed_operator(obs).g
    for alpha in (0.01, 100.0):
        err = []
        for j in range(len(lm)):
            keep = np.arange(len(lm)) != j
            _, xm = solve_landmarks(g, lm[keep], x[lm][keep], alpha=alpha)
            err.append(np.sum((xm[lm[j]] - x[lm[j]]) ** 2))
        assert choice.scores[alpha] == pytest.approx(np.sqrt(np.mean(err)), rel=1e-6)
    k = loo_isomap_neighbors(obs, lm, x[lm], dim=3, min_common=1, candidates=(4, 8, 100))
    assert 100 not in k.scores and k.value in (4, 8)


def test_depth_scaled_directions_make_the_linear_model_exact_for_a_pinhole_camera():
    obs, x = pinhole_world(noise=0.0)
    cam = Intrinsics(800.0, 640.0, 360.0, (0.0, 0.0, 0.0, 0.0, 0.0))
    norm = Observations(obs.indptr, obs.indices, normalised_coordinates(obs.values, cam), obs.step_ids, obs.feature_ids)
    directions = np.hstack([norm.values, np.ones((norm.nnz, 1))])
    lm = farthest_point_landmarks(np.arange(len(x)), x, np.bincount(obs.indices), 10)
    ev = ~np.isin(np.arange(len(x)), lm)

    def rmse(est):
        return np.sqrt(np.mean(np.sum((est[ev] - x[ev]) ** 2, axis=1)))

    # The true depth of every sighting (the camera's z of the point), as pinhole_world moves the camera.
    depth = np.empty(obs.nnz)
    for t in range(obs.n_steps):
        c = np.array([-3 + 6 * t / obs.n_steps, 0.1 * np.sin(t / 7), 0.5 * t / obs.n_steps])
        yaw = np.deg2rad(8) * (t / obs.n_steps - 0.5)
        s = slice(obs.indptr[t], obs.indptr[t + 1])
        depth[s] = (x[obs.indices[s]] - c) @ np.array([np.sin(yaw), 0, np.cos(yaw)])
    lifted = Observations(obs.indptr, obs.indices, directions * depth[:, None], obs.step_ids, obs.feature_ids)
    assert rmse(coembed_map(lifted, lm, x[lm], alpha=100.0).X) < 1e-8          # exact with the right depths
    paper = rmse(coembed_map(norm, lm, x[lm], alpha=100.0).X)
    assert paper > 1.0                                                          # the paper's form is not
    res, est_depth, alphas = perspective_coembed(norm, directions, lm, x[lm], alpha_for=lambda o: 100.0, iterations=5)
    assert rmse(res.X) < paper and np.all(est_depth > 0) and alphas == [100.0] * 6


def test_normalised_coordinates_and_intrinsics_file(tmp_path):
    (tmp_path / "k.csv").write_text("problem,f,cx,cy,k1,k2,k3,p1,p2\n1,1000,500,250,0,0,0,0,0\n")
    cam = read_intrinsics(tmp_path / "k.csv")
    assert np.allclose(normalised_coordinates(np.array([[1500.0, 250.0]]), cam), [[1.0, 0.0]])
    # With radial distortion, a distorted pixel maps back to where the pinhole would have put it.
    dist = Intrinsics(1000.0, 500.0, 250.0, (0.1, 0.0, 0.0, 0.0, 0.0))
    xn = np.array([0.3, 0.2])
    r2 = np.sum(xn ** 2)
    pix = 1000 * xn * (1 + 0.1 * r2) + [500, 250]
    assert np.allclose(normalised_coordinates(pix[None], dist), xn[None], atol=1e-6)
    (tmp_path / "bad.csv").write_text("f,cx\n1,2\n")
    with pytest.raises(ObservationError, match="cy"):
        read_intrinsics(tmp_path / "bad.csv")


def test_farthest_point_rule_and_warnings():
    ids = np.array([5, 6, 7, 8, 9])
    xyz = np.array([[0, 0, 0], [1, 0, 0], [10, 0, 0], [0, 10, 0], [5, 5, 0.0]])
    counts = np.array([3, 9, 1, 1, 1])
    assert farthest_point_landmarks(ids, xyz, counts, 3).tolist() == [6, 8, 7]   # most-seen first, then farthest
    flat = landmark_warnings(xyz, 3)
    assert any("only 5 landmarks" in w for w in flat) and any("clustered" in w for w in flat)
    spread = np.random.default_rng(0).uniform(0, 10, (8, 3))
    assert landmark_warnings(spread, 3) == []
