"""Known answers for the sequence shapes (trajectory, cone, hybrid) and automatic velocities."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.seqslam.matching import auto_velocity_scale, sequence_match
from placeloc.seqslam.search import query_offsets, sequence_search, trajectory_offsets, velocities


def _brute_scores(d: np.ndarray, T: int, ds: int, vels: np.ndarray, shape: str) -> np.ndarray:
    """Scores of every reference for query column T of D[r, q], written out loop by loop."""
    t_off = query_offsets(ds, "centred")
    traj = trajectory_offsets(vels, t_off)
    nr = d.shape[0]
    s = np.full(nr, np.inf)
    for r in range(nr):
        if shape == "trajectory":
            for o in traj:
                if r + o.min() >= 0 and r + o.max() < nr:
                    s[r] = min(s[r], sum(d[r + o[j], T + t] for j, t in enumerate(t_off)))
        else:
            lo, hi = traj.min(axis=0), traj.max(axis=0)
            if r + lo.min() >= 0 and r + hi.max() < nr:
                s[r] = sum(d[r + lo[j]:r + hi[j] + 1, T + t].min() for j, t in enumerate(t_off))
    return s


def _nms(s: np.ndarray, window: int, k: int) -> list[int]:
    s = s.copy()
    out = []
    for _ in range(k):
        if not np.isfinite(s.min()):
            break
        b = int(np.argmin(s))
        out.append(b)
        s[max(0, b - window):b + window + 1] = np.inf
    return out


@pytest.mark.parametrize("shape", ["trajectory", "cone", "hybrid"])
def test_shapes_match_a_loop_by_loop_reference(shape):
    rng = np.random.default_rng(3)
    d = rng.random((60, 20)).astype(np.float32)
    ds, window, k = 6, 3, 4
    vels = velocities(0.5, 1.5, 0.25)
    best, scores = sequence_search(np.ascontiguousarray(d.T), 0, 20, ds, vels, "centred", window, k, None, 0, shape=shape, edges="skip")
    for T in range(ds // 2, 20 - (ds - ds // 2)):
        if shape == "hybrid":
            cone = _brute_scores(d, T, ds, vels, "cone")
            traj = _brute_scores(d, T, ds, vels, "trajectory")
            s = np.full_like(traj, np.inf)
            for c in _nms(cone, window, k):
                s[max(0, c - window):c + window + 1] = traj[max(0, c - window):c + window + 1]
        else:
            s = _brute_scores(d, T, ds, vels, shape)
        expect = _nms(s, window, k)
        assert list(best[T, :len(expect)]) == expect, (shape, T)
        np.testing.assert_allclose(scores[T, :len(expect)], s[expect], rtol=1e-5)
    # queries whose window leaves the matrix get no match
    assert (best[0] == -1).all() and (best[-1] == -1).all()


def test_cone_follows_a_speed_change_that_no_straight_line_fits():
    # planted path: 1 reference per query frame, then 2 per frame (the vehicle speeds up)
    rng = np.random.default_rng(0)
    n_q, n_r = 80, 200
    d = rng.uniform(0.6, 1.0, (n_r, n_q)).astype(np.float32)
    path = np.array([20 + q if q < 40 else 60 + 2 * (q - 40) for q in range(n_q)])
    d[path, np.arange(n_q)] = 0.0
    ds, window = 10, 5
    vels = velocities(1.0, 2.0, 0.5)
    et = np.ascontiguousarray(d.T)
    cone, cone_scores = sequence_search(et, 0, n_q, ds, vels, "centred", window, 2, None, 0, shape="cone", edges="skip")
    _, traj_scores = sequence_search(et, 0, n_q, ds, vels, "centred", window, 2, None, 0, shape="trajectory", edges="skip")
    valid = np.arange(ds // 2, n_q - ds // 2)
    # the cone lands exactly on the planted reference for every query, around the bend too
    np.testing.assert_array_equal(cone[valid, 0], path[valid])
    # the cone's sequence is all planted cells, also at the bend; no straight line through
    # the bend is, so its best score there is well above 0
    bend = 40
    assert (cone_scores[valid, 0] == 0).all()
    assert traj_scores[bend, 0] > 1.0 and traj_scores[20, 0] == 0


def test_auto_velocity_recovers_a_query_recorded_at_half_the_frame_rate():
    rng = np.random.default_rng(1)
    n_ref = 300
    ref = rng.integers(0, 256, (n_ref, 64), dtype=np.uint8)
    # the query sees every second reference place, with noise
    q_places = np.arange(0, n_ref, 2)
    query = np.clip(ref[q_places].astype(int) + rng.integers(-60, 61, (len(q_places), 64)), 0, 255).astype(np.uint8)
    assert auto_velocity_scale(n_ref, len(q_places)) == 2.0
    common = dict(comparison="sad", enhance_window=5, ds=10, v_min=0.8, v_max=1.2, v_step=0.1, search="centred",
                  sequence_shape="trajectory", edges="skip", top_k=3, exclude_recent=None, block_size=64)
    auto = sequence_match(ref, query, v_auto=True, **common)
    np.testing.assert_allclose(auto.velocities, [1.6, 1.8, 2.0, 2.2, 2.4])
    valid = np.arange(5, len(q_places) - 5)
    np.testing.assert_array_equal(auto.candidates[valid, 0], q_places[valid])
    fixed = sequence_match(ref, query, v_auto=False, **common)
    np.testing.assert_allclose(fixed.velocities, [0.8, 0.9, 1.0, 1.1, 1.2])
    assert (fixed.candidates[valid, 0] == q_places[valid]).mean() < 0.9


def test_shifted_edges_match_the_first_and_last_queries_on_a_one_sided_window():
    rng = np.random.default_rng(2)
    n = 50
    d = rng.uniform(0.6, 1.0, (n + 20, n)).astype(np.float32)
    path = 10 + np.arange(n)
    d[path, np.arange(n)] = 0.0
    et = np.ascontiguousarray(d.T)
    args = (et, 0, n, 8, velocities(1.0, 1.0, 0.1), "centred", 3, 2, None, 0)
    skip, _ = sequence_search(*args, shape="trajectory", edges="skip")
    shift, shift_scores = sequence_search(*args, shape="trajectory", edges="shift")
    assert (skip[:4, 0] == -1).all() and (skip[-4:, 0] == -1).all()
    np.testing.assert_array_equal(skip[4:-4], shift[4:-4])  # inside, nothing changes
    np.testing.assert_array_equal(shift[:, 0], path)  # every query, the ends included
    assert (shift_scores[:, 0] == 0).all()
