"""Known answers for the robust UMap+CA tracker: signed wall steps, the metric vote, CA
calibration statistics, and a planted bad CA measurement that must be caught and recovered."""

from __future__ import annotations

import math

import numpy as np
import pytest

from placeloc.core.params import defaults
from placeloc.synth.corridor import building
from placeloc.umap import ca
from placeloc.umap.bits import pack, popcount_rows
from placeloc.umap.params import UMapParams
from placeloc.umap.scoring import Scorer
from placeloc.umap.tracker import ca_track

DEFAULTS = defaults(UMapParams)


def _track(*args, c: dict, **kw):
    """ca_track with its tuning taken from a ``umap.ca`` dict (the defaults plus overrides)."""
    return ca_track(*args, error_mean_m=c["error_mean_m"], error_std_m=c["error_std_m"],
                    fallback_radius_m=c["fallback_radius_m"], fallback_step_m=c["fallback_step_m"],
                    wall_right=c["wall_side"] == "right", keep_heading=c["keep_heading"], tie_tol=c["tie_tol"],
                    recover_ratio=c["recover_ratio"], laser_tol_m=c["laser_tol_m"], **kw)


def _project(cam_xy: np.ndarray, heading_deg: float, pts: np.ndarray, focal: float, cx: float) -> np.ndarray:
    """Pixel column of plan points seen from a pinhole camera (image right = clockwise)."""
    h = math.radians(heading_deg)
    fwd = np.array([math.cos(h), math.sin(h)])
    right = np.array([math.sin(h), -math.cos(h)])
    rel = pts - cam_xy
    return cx + focal * (rel @ right) / (rel @ fwd)


@pytest.mark.parametrize("wall_right", [True, False])
def test_wall_steps_equal_the_true_displacement_along_the_wall(wall_right):
    # Wall y = 0, camera at y = 2 looking at 315 deg (wall on the right, theta 45) or at
    # 225 deg (wall on the left, theta 45); it moves 0.8 m along +x.
    heading = 315.0 if wall_right else 225.0
    focal, cx, d, theta = 300.0, 199.5, 2.0, 45.0
    pts = np.array([[x, 0.0] for x in np.linspace(-3.0, 5.0, 9)])
    a, b = np.array([0.0, 2.0]), np.array([0.8, 2.0])
    ua, ub = _project(a, heading, pts, focal, cx), _project(b, heading, pts, focal, cx)
    vis = (np.abs(ua - cx) < 200) & (np.abs(ub - cx) < 200)
    pa = np.stack([ua[vis], np.zeros(vis.sum())], 1)
    pb = np.stack([ub[vis], np.zeros(vis.sum())], 1)
    steps = ca.wall_steps(pa, pb, d, theta, focal, cx, wall_right)
    t = ca.wall_tangent(heading, theta, wall_right)
    assert vis.sum() >= 3
    assert steps == pytest.approx(np.full(len(steps), (b - a) @ t), abs=1e-9)
    assert abs((b - a) @ t) == pytest.approx(0.8)


def test_wall_tangent_directions():
    # heading 315, wall right at theta 45: the laser points at 270 deg, the tangent is +x
    assert ca.wall_tangent(315.0, 45.0, True) == pytest.approx([1.0, 0.0])
    assert ca.wall_tangent(135.0, 45.0, True) == pytest.approx([-1.0, 0.0])


def test_metric_vote_keeps_the_planted_group_and_scales_its_window():
    rng = np.random.default_rng(4)
    good = 1.5 + rng.uniform(-0.05, 0.05, 12)          # within 0.05 + 0.03 * 1.5 of each other
    bad = np.r_[rng.uniform(-3, 0.8, 8), 0.02, 0.03, 0.05]
    keep = ca.metric_vote(np.r_[good, bad], 0.05, 0.03)
    assert keep[:12].all() and not keep[12:].any()
    assert ca.metric_vote(np.zeros(0), 0.05, 0.03).shape == (0,)


def _corridor_scorer() -> tuple[Scorer, np.ndarray, np.ndarray]:
    """A 1-D corridor of 60 database poses (x = 0..5.9 m, step 0.1, heading 0): the line image of
    pose i is one vertical line at column i. Query frames are exact database images."""
    n = 60
    imgs = np.zeros((n, 4, 64), np.uint8)
    for i in range(n):
        imgs[i, :, i] = 1
    words = pack(imgs)
    poses = np.stack([np.arange(n) * 0.1, np.zeros(n), np.zeros(n), np.zeros(n)], 1)
    return Scorer(words, popcount_rows(words), poses, np.array([math.nan])), poses, imgs


def test_planted_bad_ca_step_is_detected_and_recovered():
    scorer, poses, imgs = _corridor_scorer()
    truth = np.array([0, 8, 16, 24, 32, 40])              # 0.8 m steps along +x
    lines = pack(imgs[truth])[:, None, :]
    # heading 0 with theta 90 and the wall on the right: the tangent is +x (wall normal at -90 deg)
    theta = np.full(len(truth), 90.0)
    step = np.full(len(truth), 0.8)
    step[3] = 0.05                                         # planted: a wrong majority group (true 0.8 m)
    reliable = np.ones(len(truth), bool)
    c = dict(DEFAULTS["ca"], error_mean_m=0.0, error_std_m=0.05)
    ub = np.array([scorer.best(lines[k])[0] for k in range(len(truth))])
    us = np.array([scorer.best(lines[k])[1] for k in range(len(truth))])
    best, score, radius = _track(0, ub, us, step, reliable, theta, poses, lines, scorer, c=c)
    assert best.tolist() == truth.tolist()
    assert radius[3] == c["fallback_radius_m"]            # the gate was widened: recovered
    assert radius[2] == pytest.approx(0.2)                 # 0 + 2 x 0.05 + 0.1 grid quantisation
    # Without re-localization the planted step would pin frame 3 to a wrong pose.
    best2, _, _ = _track(0, ub, us, step, reliable, theta, poses, lines, scorer, c=dict(c, recover_ratio=math.inf))
    assert best2[3] != truth[3]


def test_flat_scores_follow_the_ca_prediction_and_unreliable_steps_use_the_fallback():
    # Every database image identical (a wall without features): scores tie everywhere, so the
    # estimate must follow the CA steps; an unreliable step uses fallback_step_m.
    scorer, poses, imgs = _corridor_scorer()
    flat = np.zeros_like(imgs)
    flat[:, 0, :] = 1
    words = pack(flat)
    scorer = Scorer(words, popcount_rows(words), poses, np.array([math.nan]))
    lines = pack(flat[:5])[:, None, :]
    step = np.array([math.nan, 0.5, 1.0, 0.05, 0.7])
    reliable = np.array([False, True, True, False, True])
    theta = np.full(5, 90.0)
    c = dict(DEFAULTS["ca"], error_mean_m=0.0, error_std_m=0.05, fallback_step_m=1.2)
    us = np.full(5, 1.0)
    best, _, radius = _track(0, np.zeros(5, int), us, step, reliable, theta, poses, lines, scorer, c=c)
    assert poses[best, 0] == pytest.approx([0.0, 0.5, 1.5, 2.7, 3.4])
    assert radius[3] == c["fallback_radius_m"]


def test_synthetic_corridor_has_its_junction():
    # the cross corridor at the centre is what breaks the 180 deg symmetry
    outline = np.array(building()["outline"])
    assert (outline[:, 1] > 8.0).sum() == 2
    assert sorted(outline[outline[:, 1] > 8.0, 0].tolist()) == pytest.approx([43.8, 46.2])


def test_signed_step_on_rendered_corridor_views():
    # Two ray-cast views of the synthetic corridor 0.6 m apart along +x (heading 315, the
    # laser at 270 deg hits the y = 0 wall at d = 1.6 m, theta 45): CA must measure +0.6 m.
    from placeloc.geometry import Camera
    from placeloc.synth.corridor import _scene, render_view

    scene = _scene(building(), np.random.default_rng(0))
    cam = Camera(320, 240, 60.0)
    views = []
    for x in (14.0, 14.6):
        img = render_view(np.array([x, 1.6, 1.14, 315.0]), cam, scene)
        views.append(ca.akaze((np.clip(img, 0, 1) * 255).astype(np.uint8), 0.00003))
    st, kept, second, _ = ca.signed_step(*views[0], *views[1], 1.6, 45.0, cam.focal, (cam.width - 1) / 2.0, True, 0.05, 0.03)
    assert st == pytest.approx(0.6, abs=0.05)
    assert ca.is_reliable(kept, second, reliable_matches=15, reliable_ratio=1.5)
