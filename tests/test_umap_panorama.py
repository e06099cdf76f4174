"""Known answers for whole-panorama queries: the equirectangular map renderer's yaw
convention, scores over every yaw, and panoramas localized end to end with the yaw unknown."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest

from placeloc.geometry.floorplan import floor_plan_model
from placeloc.geometry.panorama import panorama_line_image, render_panoramas
from placeloc.umap.bits import pack, popcount_rows, unpack
from placeloc.umap.panorama import (
    best_pose,
    chamfer_yaw_scores,
    closeness,
    iou_yaw_scores,
)

# An L-shaped room: no two positions see the same panorama.
PLAN = {"floor_z": 0.0, "ceiling_z": 2.6, "outline": [[0, 0], [6, 0], [6, 4], [3.5, 4], [3.5, 7], [0, 7]],
        "doors": [{"from": [2, 0], "to": [2.9, 0], "height": 2.0}, {"from": [0, 5], "to": [0, 5.9], "height": 2.0}]}
W, H = 144, 72


def _render(pose, width=W, height=H):
    m = floor_plan_model(PLAN)
    return unpack(render_panoramas(m.segments, m.faces, np.array([pose]), width=width, height=height, hidden=True),
                  height, width)[0]


def test_heading_is_a_circular_shift_of_columns():
    # 50 deg at 2.5 deg per column = 20 columns: query[:, u] = db[:, u - 20]
    a = _render([2.0, 2.0, 1.4, 0.0])
    b = _render([2.0, 2.0, 1.4, 50.0])
    assert a.sum() > 200
    dil = cv2.dilate(np.roll(a, 20, axis=1), np.ones((3, 3), np.uint8))
    assert (b & (1 - dil)).sum() == 0                   # every pixel within one of the shifted image
    assert (np.roll(a, 20, axis=1) == b).mean() > 0.99
    # the wall straight ahead (x = 6 at heading 0) is the centre column; its top edge is
    # at elevation atan(1.2 / 4) = 16.7 deg -> row (90 - 16.7) / 180 * 72 = 29.3
    assert a[29, W // 2 - 1] or a[29, W // 2] or a[28, W // 2]


def test_yaw_scores_find_the_planted_view_and_shift():
    rng = np.random.default_rng(0)
    db_imgs = (rng.random((5, 12, 40)) < 0.1).astype(np.uint8)
    query = np.roll(db_imgs[3], 7, axis=1)               # position 3 seen at heading 7 columns
    words = pack(db_imgs)
    s = iou_yaw_scores(words, popcount_rows(words), query)
    assert s.shape == (5, 40)
    assert best_pose(s) == (3, 7, pytest.approx(1.0))
    c = chamfer_yaw_scores(words, closeness(db_imgs, 2.0), query, tau_px=2.0)
    i, k, v = best_pose(c)
    assert (i, k) == (3, 7) and v == pytest.approx(1.0)


def test_closeness_wraps_around_the_seam():
    img = np.zeros((3, 10), np.uint8)
    img[1, 0] = 1
    c = closeness(img, 4.0)
    assert c[1, 0] == 1.0
    assert c[1, 9] == pytest.approx(0.75, abs=0.02) and c[1, 1] == pytest.approx(0.75, abs=0.02)
    assert c[1, 5] == 0.0


def _grey_panorama(pose, rng):
    """A grey 512 x 256 panorama whose edges are the map's lines plus clutter lines that are
    not in the map (posters, a cabinet edge)."""
    lines = _render(pose, 512, 256)
    img = np.where(cv2.dilate(lines, np.ones((2, 2), np.uint8)) > 0, 60, 190).astype(np.uint8)
    for _ in range(6):
        x, y = int(rng.integers(0, 480)), int(rng.integers(110, 200))
        cv2.rectangle(img, (x, y), (x + int(rng.integers(10, 30)), y + int(rng.integers(10, 40))), 20, 2)
    return img


def test_panorama_line_image_lies_on_the_map_lines():
    img = _grey_panorama([2.1, 5.3, 1.4, 62.5], np.random.default_rng(1))
    q = panorama_line_image(img, width=W, height=H, face_px=256, min_length=8.0)
    ref = _render([2.1, 5.3, 1.4, 62.5])
    near = np.ones((3, 3), np.uint8)
    found = (cv2.dilate(q, near) & ref).sum() / ref.sum()        # map line pixels detected
    on_map = (q & cv2.dilate(ref, near)).sum() / q.sum()          # detected pixels on map lines
    assert found > 0.8 and 0.5 < on_map < 0.98                     # the clutter rectangles are off the map


@pytest.mark.parametrize("score", ["iou", "chamfer"])
def test_panoramas_localized_with_unknown_yaw(tmp_path, score):
    import yaml

    from placeloc.core.config import load_config
    from placeloc.core.runner import run_all

    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(PLAN))
    (tmp_path / "q").mkdir()
    truth = [(1.2, 1.1, 1.4, 30.0), (4.9, 2.6, 1.4, 200.0), (2.3, 5.8, 1.4, 287.5)]
    rng = np.random.default_rng(2)
    with open(tmp_path / "poses.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "z", "heading_deg"])
        for k, pose in enumerate(truth):
            cv2.imwrite(str(tmp_path / "q" / f"p{k}.png"), _grey_panorama(pose, rng))
            w.writerow([f"p{k}.png", *pose])
    cfg = load_config(data={"method": "umap", "query": {"images": str(tmp_path / "q")},
                            "ground_truth": {"kind": "poses", "path": str(tmp_path / "poses.csv")},
                            "umap": {"model": str(tmp_path / "plan.yaml"), "query_kind": "panorama",
                                     "grid": {"x": [0.2, 5.8, 0.2], "y": [0.2, 6.8, 0.2], "z": 1.4, "headings": [0.0]},
                                     "panorama": {"score": score}},
                            "plots": False}, base_dir=tmp_path)
    run_all(cfg, tmp_path / "run", quiet=True)
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["max_error_m"] <= 0.3
    if score == "chamfer":
        # the truths lie 0.1 m off the 0.2 m grid; the local refinement (0.05 m) reaches them (the
        # dilated IoU is flat over a few centimetres, so it is only held to the grid's accuracy)
        assert m["median_error_m"] <= 0.06
    rows = list(csv.DictReader(open(tmp_path / "run" / "estimates.csv")))
    for r, t in zip(rows, truth):
        assert abs((float(r["heading_deg"]) - t[3] + 180) % 360 - 180) <= 2.5


def test_direction_split_partitions_the_lines():
    # map: vertical segments (corners, jambs) and the rest together make the full image
    from placeloc.geometry.panorama import vertical_segments

    m = floor_plan_model(PLAN)
    v = vertical_segments(m.segments)
    assert v.sum() == int((np.abs(m.segments[:, 2] - m.segments[:, 5]) > 0).sum())
    pose = np.array([[2.0, 2.0, 1.4, 30.0]])
    parts = [unpack(render_panoramas(m.segments, m.faces, pose, width=W, height=H, hidden=True, which=w), H, W)[0]
             for w in ("all", "vertical", "other")]
    assert ((parts[1] | parts[2]) == parts[0]).all() and parts[1].sum() > 0 and parts[2].sum() > parts[1].sum()
    # query: the two channels of the split line image are the unsplit image
    img = _grey_panorama([2.1, 5.3, 1.4, 62.5], np.random.default_rng(1))
    both = panorama_line_image(img, width=W, height=H, face_px=256, min_length=8.0, split=True)
    one = panorama_line_image(img, width=W, height=H, face_px=256, min_length=8.0)
    assert ((both[0] | both[1]) == one).all() and both[0].sum() > 0


def test_distinct_candidates_and_local_grid():
    from placeloc.umap.panorama import distinct_candidates, local_grid

    xy = np.array([[0.0, 0.0], [0.2, 0.0], [3.0, 0.0], [3.1, 0.0], [6.0, 0.0]])
    scores = np.array([[0.9, 0.1], [0.1, 0.85], [0.2, 0.8], [0.7, 0.0], [0.5, 0.6]])
    # best per position 0.9, 0.85, 0.8, 0.7, 0.6: row 1 is 0.2 m from row 0, row 3 0.1 m from row 2
    assert distinct_candidates(scores, xy, count=3, min_separation_m=0.5).tolist() == [0, 2, 4]
    assert distinct_candidates(scores, xy, count=2, min_separation_m=0.0).tolist() == [0, 1]
    g = local_grid(1.0, 2.0, radius_m=0.1, step_m=0.05)
    assert g.shape == (25, 2) and [1.0, 2.0] in g.tolist()
    assert np.allclose(g.min(0), [0.9, 1.9]) and np.allclose(g.max(0), [1.1, 2.1])


def test_chamfer_spectra_equal_the_pixel_loop_and_weights_drop_rows():
    from placeloc.umap.panorama import chamfer_spectra, chamfer_table, chamfer_yaw_scores, closeness, row_weights

    rng = np.random.default_rng(3)
    db = (rng.random((12, H, W)) < 0.03).astype(np.uint8)
    qs = (rng.random((3, H, W)) < 0.03).astype(np.uint8)
    ones = np.ones(H, np.float32)
    fast = chamfer_table(chamfer_spectra(db, tau_px=3.0, weights=ones), qs, tau_px=3.0, weights=ones)
    slow = np.stack([chamfer_yaw_scores(pack(db), closeness(db, 3.0), q, tau_px=3.0) for q in qs])
    assert np.abs(fast - slow).max() < 1e-5
    # weight 0 beyond 60 degrees: the same as the plain score on images whose polar rows are
    # empty (closeness does not reach across: tau 1 px and the rows next to them cleared too)
    wts = row_weights(H, polar_deg=60.0, polar_weight=0.0)
    assert wts[0] == 0 and wts[H // 2] == 1 and (wts == 0).sum() == 2 * round(H * 30 / 180)
    keep = np.convolve(wts, np.ones(3), "same") == 3
    cleared_db, cleared_q = db * keep[None, :, None], qs * keep[None, :, None]
    weighted = chamfer_table(chamfer_spectra(cleared_db, tau_px=1.0, weights=wts), qs * keep[None, :, None], tau_px=1.0,
                             weights=wts)
    plain = chamfer_table(chamfer_spectra(cleared_db, tau_px=1.0, weights=ones), cleared_q, tau_px=1.0, weights=ones)
    assert np.abs(weighted - plain).max() < 1e-5


def test_refine_steps_halve_down_to_the_finest():
    from placeloc.umap.panorama import refine_steps

    assert refine_steps(0.15, 0.05) == [0.1, 0.05]        # reaches 0.15 m
    assert refine_steps(0.35, 0.05) == [0.2, 0.1, 0.05]   # reaches 0.35 m
    assert refine_steps(0.05, 0.05) == [0.05]
