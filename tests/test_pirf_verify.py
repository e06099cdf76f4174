"""Known-answer tests for the geometric check of loop closures (bearing parallax against the
map's own yardstick) and the mapping-cost summary."""

from __future__ import annotations

import math

import numpy as np

from placeloc.pirf.metrics import tail_mean
from placeloc.pirf.verify import bearing_residual, bearings, frames_needed, verify_closures

WIDTH = 480


def _room(seed: int = 0, n: int = 150) -> tuple[np.ndarray, np.ndarray]:
    """Points on the walls of a 10 x 8 m room and one distinct descriptor per point."""
    rng = np.random.default_rng(seed)
    side = rng.integers(0, 4, n)
    u = rng.random(n)
    xy = np.where(side[:, None] == 0, np.c_[u * 10, np.zeros(n)],
                  np.where(side[:, None] == 1, np.c_[u * 10, np.full(n, 8.0)],
                           np.where(side[:, None] == 2, np.c_[np.zeros(n), u * 8], np.c_[np.full(n, 10.0), u * 8])))
    return xy, rng.random((n, 128)).astype(np.float32) * 100


def _view(points: np.ndarray, desc: np.ndarray, x: float, y: float, heading: float) -> tuple[np.ndarray, np.ndarray]:
    """An omnidirectional camera's features: the equirectangular column of each point -> bearing."""
    ang = np.mod(np.arctan2(points[:, 1] - y, points[:, 0] - x) - heading, 2 * math.pi)
    return bearings(ang / (2 * math.pi) * WIDTH, WIDTH), desc


def test_bearings_span_the_full_circle() -> None:
    assert np.allclose(bearings(np.array([0, 120, 240, 480]), WIDTH), [0, math.pi / 2, math.pi, 2 * math.pi])


def test_bearing_residual_zero_for_a_pure_rotation_and_growing_with_the_offset() -> None:
    pts, desc = _room()
    here = _view(pts, desc, 5, 4, 0.0)
    assert bearing_residual(here, _view(pts, desc, 5, 4, 2.0), ratio=0.7, min_matches=8) < 1e-9
    near, far = (bearing_residual(here, _view(pts, desc, 5 + d, 4, 1.0), ratio=0.7, min_matches=8) for d in (0.3, 1.5))
    assert 0 < near < far
    other = (_view(pts, desc, 5, 4, 0.0)[0], np.random.default_rng(9).random((150, 128)).astype(np.float32) * 100)
    assert math.isnan(bearing_residual(here, other, ratio=0.7, min_matches=8))  # nothing shared: no measurement


def test_verify_keeps_a_closure_nearer_than_the_yardstick_and_drops_one_beside_the_path() -> None:
    """Map frames walk along y = 4 at 0.2 m per frame, so k = 5 frames is 1 m. A revisit 0.3 m
    from node 10 is kept, one 1.5 m beside it is dropped, one sharing no features is dropped."""
    pts, desc = _room()
    views = {i: _view(pts, desc, 2.0 + 0.2 * i, 4.0, 0.0) for i in range(21)}
    c_x = 2.0 + 0.2 * 10
    views[100] = _view(pts, desc, c_x + 0.1, 4.3, 2.5)
    views[101] = _view(pts, desc, c_x, 5.5, -1.0)
    views[102] = (views[100][0], np.random.default_rng(5).random((150, 128)).astype(np.float32) * 100)
    frames, nodes = np.array([100, 101, 102]), np.array([10, 10, 10])
    out = verify_closures(frames, nodes, views.__getitem__, k=5, n_frames=21, ratio=0.7, min_matches=8)
    assert out["keep"].tolist() == [True, False, False]
    assert out["residual"][0] < out["reference"][0] < out["residual"][1]
    # the reference is the mean residual of node 10 against frames 5 and 15
    ref = np.mean([bearing_residual(views[10], views[j], ratio=0.7, min_matches=8) for j in (5, 15)])
    assert math.isclose(out["reference"][0], ref)
    # with no reference frame inside the video (k too large) the closure is kept: no yardstick
    assert verify_closures(frames[1:2], nodes[1:2], views.__getitem__, k=50, n_frames=21, ratio=0.7, min_matches=8)["keep"].tolist() == [True]
    assert frames_needed(frames, nodes, 5, 21).tolist() == [5, 10, 15, 100, 101, 102]


def test_tail_mean_is_the_mean_of_the_last_fraction() -> None:
    assert tail_mean(np.arange(10.0), 0.2) == 8.5
    assert tail_mean(np.arange(10.0), 0.01) == 9.0  # at least one value
    assert math.isnan(tail_mean(np.zeros(0), 0.1))
