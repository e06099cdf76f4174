"""The per-position renderer (visibility once per grid position, lines drawn dilated)
against hand-computed visibility and against the per-pixel reference renderer."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from placeloc.geometry import Camera, pose_grid
from placeloc.geometry.floorplan import floor_plan_model, free_space_mask
from placeloc.geometry.visibility import visible_pieces
from placeloc.umap.bits import pack, unpack
from placeloc.umap.render import dilation_half_widths, render_grid, render_packed

CAM = Camera(160, 120, 60.0)


def test_vertical_segment_behind_a_lintel_is_cut_at_the_solved_height():
    # camera at (0, 0, 1); lintel over x = 1, |y| <= 0.5, from 1.5 m to 2.5 m; the ray to a
    # point (2, 0, z) crosses it halfway, at height 1 + (z - 1) / 2: hidden for z in [2, 4]
    faces = np.array([[1.0, -0.5, 1.0, 0.5, 1.5, 2.5]])
    seg = np.array([[2.0, 0.0, 0.0, 2.0, 0.0, 2.5]])
    got = visible_pieces(seg, faces, np.array([0.0, 0.0, 1.0]))
    assert got.shape == (1, 6)
    assert got[0, 2] == pytest.approx(0.0) and got[0, 5] == pytest.approx(2.0, abs=1e-9)


def test_floor_line_behind_a_wall_keeps_its_two_visible_ends():
    # a floor-to-ceiling wall at x = 1, |y| <= 0.5, hides the floor line x = 2 for |y| <= 1
    faces = np.array([[1.0, -0.5, 1.0, 0.5, 0.0, 2.5]])
    seg = np.array([[2.0, -2.0, 0.0, 2.0, 2.0, 0.0]])
    got = visible_pieces(seg, faces, np.array([0.0, 0.0, 1.0]))
    ends = sorted((round(float(min(p[1], p[4])), 2), round(float(max(p[1], p[4])), 2)) for p in got)
    assert len(ends) == 2
    assert ends[0] == pytest.approx((-2.0, -1.0), abs=0.01) and ends[1] == pytest.approx((1.0, 2.0), abs=0.01)


@pytest.mark.parametrize("tol", [1, 2, 3])
def test_lines_drawn_thick_equal_cv2_dilate_of_the_thin_render(tol):
    m = floor_plan_model({"floor_z": 0.0, "ceiling_z": 2.5, "outline": [[0, 0], [6, 0], [6, 4], [0, 4]],
                          "obstacles": [[[2, 1.5], [3, 1.5], [3, 2.5], [2, 2.5]]]})
    poses = pose_grid([0.5, 5.5, 1.0], [0.5, 3.5, 1.5], 1.2, [0.0, 100.0, 250.0])
    thin = unpack(render_grid(m.segments, m.faces, poses, CAM, near=0.05, hidden=True, tolerance_px=0), 120, 160)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * tol + 1, 2 * tol + 1))
    want = pack(np.stack([cv2.dilate(im, k) for im in thin]))
    assert np.array_equal(render_grid(m.segments, m.faces, poses, CAM, near=0.05, hidden=True, tolerance_px=tol), want)
    assert len(dilation_half_widths(tol)) == 2 * tol + 1


def test_agrees_with_the_per_pixel_renderer_on_a_generated_home():
    from placeloc.synth.home import plan

    fp, _ = plan(np.random.default_rng(3), 3)
    m = floor_plan_model(fp)
    # without hidden lines both draw the same segments the same way: identical
    poses = np.array([[2.0, 2.5, 1.14, 30.0], [5.0, 0.7, 1.3, 200.0]])
    assert np.array_equal(render_grid(m.segments, m.faces, poses, CAM, near=0.05, hidden=False, tolerance_px=0),
                          render_packed(m.segments, m.faces, poses, CAM, hidden=False))
    # with them: 12 positions x 16 headings, views in the order given
    xy = np.concatenate(m.polygons)
    g = pose_grid([xy[:, 0].min(), xy[:, 0].max(), 0.7], [xy[:, 1].min(), xy[:, 1].max(), 0.7], 1.14,
                  list(np.arange(0.0, 360.0, 22.5)))
    keep, _ = free_space_mask(g[:, :2], m, inside_only=True, wall_margin_m=0.1)
    g = g[keep]
    g = g[np.isin(np.unique(g[:, :2], axis=0, return_inverse=True)[1].ravel(), np.arange(0, 60, 5))]
    rng = np.random.default_rng(0)
    g = g[rng.permutation(len(g))]
    old = unpack(render_packed(m.segments, m.faces, g, CAM), 120, 160).astype(bool)
    new = unpack(render_grid(m.segments, m.faces, g, CAM, near=0.05, hidden=True, tolerance_px=0), 120, 160).astype(bool)
    both = np.count_nonzero(old & new)
    assert both >= 0.99 * np.count_nonzero(old) and both >= 0.99 * np.count_nonzero(new)
    # every view agrees closely, so no view is a wrong pose's render
    n_old, n_new = old.sum((1, 2)), new.sum((1, 2))
    seen = n_old > 0
    assert np.array_equal(n_new[~seen], n_old[~seen])  # a blank view stays blank
    assert ((old & new).sum((1, 2))[seen] / n_old[seen]).min() >= 0.95


def test_pruned_search_finds_exactly_the_best_view_and_pooled_cells_match():
    from placeloc.umap.bits import best_iou, iou_scores, pool_or, popcount_rows

    m = floor_plan_model({"floor_z": 0.0, "ceiling_z": 2.5, "outline": [[0, 0], [9, 0], [9, 4], [0, 4]],
                          "obstacles": [[[2, 1.5], [3, 1.5], [3, 2.5], [2, 2.5]], [[6, 1], [6.5, 1], [6.5, 3], [6, 3]]]})
    poses = pose_grid([0.3, 8.7, 0.4], [0.3, 3.7, 0.4], 1.2, list(np.arange(0.0, 360.0, 30.0)))
    poses = poses[m.inside(poses[:, :2])]
    db, cells = render_grid(m.segments, m.faces, poses, CAM, near=0.05, hidden=True, tolerance_px=2, pooled=True)
    assert np.array_equal(cells[::7], pool_or(db[::7], 120, 160))
    counts = popcount_rows(db)
    thin = unpack(render_grid(m.segments, m.faces, poses[::331], CAM, near=0.05, hidden=True, tolerance_px=0), 120, 160)
    rng = np.random.default_rng(1)
    for q in thin:
        qw = pack((q & (rng.random(q.shape) < 0.6)) | (rng.random(q.shape) < 0.02))
        full = iou_scores(db, counts, qw)
        assert best_iou(db, counts, cells, qw, 120, 160) == (int(np.argmax(full)), float(full.max()))
        rows = np.arange(5, len(db), 3)
        sub = iou_scores(db, counts, qw, rows)
        assert best_iou(db, counts, cells, qw, 120, 160, rows=rows) == (int(rows[np.argmax(sub)]), float(sub.max()))
