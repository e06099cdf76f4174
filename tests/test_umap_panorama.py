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
    compatible_lines,
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
    for chance in ("none", "area", "yaw"):
        c = chamfer_yaw_scores(words, closeness(db_imgs, 2.0), query, tau_px=2.0, chance=chance)
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


@pytest.mark.parametrize("score,bins", [("iou", 1), ("chamfer", 1), ("chamfer", 4)])
def test_panoramas_localized_with_unknown_yaw(tmp_path, score, bins):
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
                                     "panorama": {"score": score, "orientation_bins": bins}},
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
        # the L-shaped room has no look-alike: each answer beats every other place and heading,
        # and the margin is its score minus its rival's, the score taken before the final
        # search of the last centimetres (which moves it by at most a few hundredths: up, its
        # polish; or a little down, as its end is the answer whatever it scores when it starts
        # from the plan's lattice, refine_final_radius_m)
        assert float(r["rival_score"]) < float(r["score"])
        # doubtful_margin is in the chamfer score's units (the IoU's margins here are 0.016-0.03)
        assert score == "iou" or r["doubtful"] == "false"
        ahead = float(r["score"]) - float(r["rival_score"])
        assert ahead - 0.02 <= float(r["margin"]) <= ahead + 0.005
    # the margin reaches evaluate as the poses contract's confidence
    assert m["kept_at_100_precision"] == 1.0 and m["confidence_average_precision"] == 1.0
    scored = list(csv.DictReader(open(tmp_path / "run" / "per_query.csv")))
    assert [s["confidence"] for s in scored] == [r["margin"] for r in rows]


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
    spectra = chamfer_spectra(db, tau_px=3.0, weights=ones)
    for chance in ("none", "area", "yaw"):
        fast = chamfer_table(spectra, qs, tau_px=3.0, weights=ones, chance=chance)
        slow = np.stack([chamfer_yaw_scores(pack(db), closeness(db, 3.0), q, tau_px=3.0, chance=chance) for q in qs])
        assert np.abs(fast - slow).max() < 1e-5
    # weight 0 beyond 60 degrees: the same as the plain score on images whose polar rows are
    # empty (closeness does not reach across: tau 1 px and the rows next to them cleared too)
    wts = row_weights(H, polar_deg=60.0, polar_weight=0.0, solid_angle=False)
    assert wts[0] == 0 and wts[H // 2] == 1 and (wts == 0).sum() == 2 * round(H * 30 / 180)
    keep = np.convolve(wts, np.ones(3), "same") == 3
    cleared_db, cleared_q = db * keep[None, :, None], qs * keep[None, :, None]
    for chance in ("none", "yaw"):  # (area: the image's area shrinks with the weights, so only these two agree)
        weighted = chamfer_table(chamfer_spectra(cleared_db, tau_px=1.0, weights=wts), qs * keep[None, :, None], tau_px=1.0,
                                 weights=wts, chance=chance)
        plain = chamfer_table(chamfer_spectra(cleared_db, tau_px=1.0, weights=ones), cleared_q, tau_px=1.0, weights=ones,
                              chance=chance)
        assert np.abs(weighted - plain).max() < 1e-5


def test_score_table_is_the_same_to_the_bit_for_any_thread_count_and_batch(monkeypatch):
    # the search computes its tables with BLAS and the transforms on every core, and in
    # batches of PANORAMA_BATCH queries: none of that may change a score's last bit
    from threadpoolctl import threadpool_limits

    import placeloc.umap.panorama as pano
    from placeloc.umap.panorama import chamfer_spectra, chamfer_table, orientation_channels, row_weights

    rng = np.random.default_rng(11)
    db = (rng.random((700, H, W)) < 0.03).astype(np.uint8)
    qs = (rng.random((5, H, W)) < 0.03).astype(np.uint8)
    wts = row_weights(H, polar_deg=60.0, polar_weight=1.0, solid_angle=True)
    for spread, make in ((None, lambda x: x), (1, lambda x: orientation_channels(x, 4))):
        spectra = chamfer_spectra(make(db), tau_px=3.0, weights=wts, spread=spread)
        tables = []
        for threads in (1, 2, 4):
            monkeypatch.setattr(pano, "usable_cores", lambda t=threads: t)
            with threadpool_limits(limits=threads, user_api="blas"):
                tables.append(chamfer_table(spectra, make(qs), tau_px=3.0, weights=wts, chance="none", spread=spread))
                alone = [chamfer_table(spectra, make(qs[i:i + 1]), tau_px=3.0, weights=wts, chance="none", spread=spread)
                         for i in range(2)]
            assert all(np.array_equal(a[0], tables[-1][i]) for i, a in enumerate(alone))
        assert all(np.array_equal(t, tables[0]) for t in tables[1:])
        assert np.array_equal(chamfer_spectra(make(db), tau_px=3.0, weights=wts, spread=spread), spectra)
        # the spectra are made SPECTRA_BLOCK positions at a time, and the index stage writes them
        # so: any cut of the positions (here across block edges) gives each one's to the bit
        for cut in (1, pano.SPECTRA_BLOCK - 1, pano.SPECTRA_BLOCK + 3, 333):
            parts = [chamfer_spectra(make(db[a:b]), tau_px=3.0, weights=wts, spread=spread)
                     for a, b in ((0, cut), (cut, len(db)))]
            assert np.array_equal(np.concatenate(parts, axis=1), spectra), cut


def test_spectra_are_the_plain_formula_to_the_bit():
    """chamfer_spectra writes each half into one buffer and conjugates straight into its
    output (the index is memory-bound); the same bits as the formula written array by array:
    [weighted lines / their weighted sum, weighted closeness (or likelihood)], row spectra,
    conjugated, frequency first."""
    from placeloc.umap.panorama import (
        _rfft,
        chamfer_spectra,
        closeness,
        likelihood_image,
        orientation_channels,
        oriented_closeness,
        row_weights,
        stack_channels,
    )

    rng = np.random.default_rng(5)
    db = (rng.random((70, H, W)) < 0.03).astype(np.uint8)
    wts = row_weights(H, polar_deg=60.0, polar_weight=1.0, solid_angle=True)

    def formula(lines: np.ndarray, close: np.ndarray, w: np.ndarray) -> np.ndarray:
        img = lines.astype(np.float32) * w
        n = np.maximum(img.sum(axis=(1, 2)), 1e-9)[:, None, None]
        return np.conj(_rfft(np.concatenate([img / n, close * w], axis=1))).transpose(2, 0, 1)

    w = np.asarray(wts, np.float32)[None, :, None]
    for lines in (db, db.astype(bool)):
        assert np.array_equal(chamfer_spectra(lines, tau_px=3.0, weights=wts), formula(lines, closeness(lines, 3.0), w))
    like = likelihood_image(closeness(db, 3.0), wts, 0.5)
    assert np.array_equal(chamfer_spectra(db, tau_px=3.0, weights=wts, clutter_share=0.5), formula(db, like, w))
    ch = orientation_channels(db, 4)
    w4 = np.tile(np.asarray(wts, np.float32), 4)[None, :, None]
    assert np.array_equal(chamfer_spectra(ch, tau_px=3.0, weights=wts, spread=1),
                          formula(stack_channels(ch), stack_channels(oriented_closeness(ch, 3.0, 1)), w4))


def test_chance_levels_by_hand():
    # one map row of 10 columns, tau 2: map lines at columns 0 and 5 -> closeness 1, .5, 0, 0, .5, 1, .5, 0, 0, .5
    # (wrapping), i.e. it averages 0.4 over the image; the query has one line pixel at column 1
    from placeloc.umap.panorama import chamfer_yaw_scores, closeness

    db = np.zeros((1, 1, 10), np.uint8)
    db[0, 0, [0, 5]] = 1
    q = np.zeros((1, 10), np.uint8)
    q[0, 1] = 1
    close_db = closeness(db, 2.0)
    assert close_db.mean() == pytest.approx(0.4)
    none = chamfer_yaw_scores(pack(db), close_db, q, tau_px=2.0, chance="none")
    area = chamfer_yaw_scores(pack(db), close_db, q, tau_px=2.0, chance="area")
    # shift 1 (query column c is map column c - 1): precision 1 (the query's pixel on the map's
    # column 0), recall: map columns 0 and 5 seen at query columns 1 and 6, closeness 1 and 0
    assert none[0, 1] == pytest.approx(0.5 * (0.5 + 1.0))
    # area: precision (1 - 0.4) / (1 - 0.4) = 1; recall's chance is the query's closeness
    # mean (1 + .5 + .5) / 10 = 0.2: (0.5 - 0.2) / 0.8
    assert area[0, 1] == pytest.approx(0.5 * ((0.5 - 0.2) / 0.8 + 1.0))
    # shift 3: the query's pixel on map column 8 (closeness 0), map columns 0 and 5 at query
    # columns 3 and 8 (closeness 0): both halves below chance
    assert area[0, 3] == pytest.approx(0.5 * ((0.0 - 0.2) / 0.8 + (0.0 - 0.4) / 0.6))
    yaw = chamfer_yaw_scores(pack(db), close_db, q, tau_px=2.0, chance="yaw")
    assert yaw.mean() == pytest.approx(0.0, abs=1e-9)   # corrected for its own mean over the shifts


def test_chance_correction_does_not_reward_a_busy_view():
    # The failure the plain score has on real homes: a sparse query (a few true lines plus
    # clutter) against its own sparse view and a busy view (the same lines plus many more:
    # a hall junction). Clutter lands near the busy view's extra lines by chance, so the
    # plain score's precision half prefers it; corrected for the area the busy view's
    # closeness covers, the true view wins.
    from placeloc.umap.panorama import chamfer_spectra, chamfer_table

    rng = np.random.default_rng(7)
    h, w = 24, 96
    sparse = np.zeros((h, w), np.uint8)
    sparse[12, 10:40] = 1                         # two true lines (a white room: little to see)
    sparse[4, 50:90] = 1
    busy = sparse.copy()
    busy[2:22, 0:w:8] = 1                         # plus a vertical line every 8 columns (doors, jambs)
    query = sparse.copy()
    query[12, 22:40] = 0                          # the low-contrast lines only partly detected
    query[4, 62:90] = 0
    for c in rng.integers(0, w, 10):
        query[6:20, c] = 1                        # clutter: vertical edges of furniture, a fan
    db = np.stack([sparse, busy])
    ones = np.ones(h, np.float32)
    sp = chamfer_spectra(db, tau_px=3.0, weights=ones)
    plain = chamfer_table(sp, query[None], tau_px=3.0, weights=ones, chance="none")[0, :, 0]
    fair = chamfer_table(sp, query[None], tau_px=3.0, weights=ones, chance="area")[0, :, 0]
    assert plain[1] > plain[0]                    # the busy view wins the plain score
    assert fair[0] > fair[1]                      # and loses the corrected one


def test_refine_steps_halve_down_to_the_finest():
    from placeloc.umap.panorama import grid_step, refine_steps

    # after the cell stage (a third of the grid step): a sixth, a twelfth, ... while >= the finest
    assert refine_steps(0.24, 0.02) == pytest.approx([0.04, 0.02])
    assert refine_steps(0.24, 0.01) == pytest.approx([0.04, 0.02, 0.01])
    assert refine_steps(0.24, 0.05) == pytest.approx([0.04])
    xy = np.array([[0.125, 0.5], [0.375, 0.5], [0.375, 0.75], [1.125, 0.5]])
    assert grid_step(xy) == pytest.approx(0.25)


def _closeness_by_transform(lines, tau_px):
    """The reference closeness: OpenCV's 5 x 5 chamfer distance transform of each image,
    wrapped around horizontally by padding both sides."""
    h, w = lines.shape[-2:]
    pad = int(np.ceil(tau_px)) + 1
    out = np.zeros(lines.shape, np.float32)
    for i, img in enumerate(lines):
        wrapped = np.concatenate([img[:, -pad:], img, img[:, :pad]], axis=1)
        if wrapped.any():
            d = cv2.distanceTransform((wrapped == 0).astype(np.uint8), cv2.DIST_L2, 5)[:, pad:pad + w]
            out[i] = np.maximum(0.0, 1.0 - d / tau_px)
    return out


def _blur_by_hand(img, r):
    """The mean over the (2r + 1)-pixel square, columns wrapping, zero beyond the rows."""
    h, w = img.shape
    out = np.zeros((h, w))
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            moved = np.zeros((h, w))
            src = np.roll(img, dx, axis=1)            # out[y, x] += img[y - dy, x - dx]
            if dy >= 0:
                moved[dy:] = src[:h - dy]
            else:
                moved[:h + dy] = src[-dy:]
            out += moved
    return out / (2 * r + 1) ** 2


def _chamfer_reference(db, q, *, tau, weights, prows, spread, recall_tau=None, blur=0, recall_weight=0.5):
    """The chamfer score (chance none) pixel by pixel, for the oriented and the tolerant
    tables: (P, B, H, W) map channels, (B, H, W) query channels (B = 1: the plain score),
    each element's closeness to the other side's lines of compatible bins
    (:func:`_closeness_by_transform`); the recall half's query closeness at ``recall_tau``
    (None: ``tau``), the precision half's query pixels (times the precision rows) blurred
    over ``blur`` pixels, each against the map's closeness at ``tau``; every query shift by
    rolling its columns; the halves mixed as ``recall_weight`` says (0.5: their mean)."""
    recall_tau = tau if recall_tau is None else recall_tau
    b, h, w = q.shape
    wr = weights[:, None]
    out = np.zeros((len(db), w))
    for p, m in enumerate(db):
        m_near = _closeness_by_transform(compatible_lines(m, spread), tau)
        for k in range(w):
            qk = np.roll(q, -k, axis=2)               # the query taken at heading k, turned back to heading 0
            q_near = _closeness_by_transform(compatible_lines(qk, spread), recall_tau)
            rec = sum((m[c] * wr * q_near[c]).sum() for c in range(b)) / max((m * wr).sum(), 1e-9)
            qb = [_blur_by_hand(qk[c] * prows[:, None], blur) * wr for c in range(b)]
            pre = sum((qb[c] * m_near[c]).sum() for c in range(b)) / max(sum(x.sum() for x in qb), 1e-9)
            out[p, k] = recall_weight * rec + (1.0 - recall_weight) * pre
    return out


@pytest.mark.parametrize("tau", [0.7, 1.0, 2.0, 2.5, 3.0, 4.2, 6.0])
def test_stamped_closeness_equals_the_distance_transform_bit_for_bit(tau):
    rng = np.random.default_rng(int(tau * 10))
    for density in (0.002, 0.03, 0.2, 0.7):
        imgs = (rng.random((6, 30, 48)) < density).astype(np.uint8)
        imgs[0] = 0                                       # an empty image
        imgs[1, :, :] = 0
        imgs[1, 0, 0] = imgs[1, 29, 47] = imgs[1, 15, 1] = 1   # corners and the seam
        assert np.array_equal(closeness(imgs, tau), _closeness_by_transform(imgs, tau)), density


def test_scores_at_shifts_equal_the_table():
    from placeloc.umap.panorama import chamfer_at_shifts, chamfer_spectra, chamfer_table, row_weights

    rng = np.random.default_rng(11)
    db = (rng.random((7, H, W)) < 0.03).astype(np.uint8)
    db[2] = 0                                             # an empty view
    q = (rng.random((H, W)) < 0.04).astype(np.uint8)
    shifts = rng.integers(0, W, size=(7, 5))
    shifts[0, 0] = W - 1                                  # the seam
    for wts in (np.ones(H, np.float32), row_weights(H, polar_deg=60.0, polar_weight=0.3, solid_angle=False)):
        sp = chamfer_spectra(db, tau_px=3.0, weights=wts)
        for chance in ("none", "area", "yaw"):
            table = chamfer_table(sp, q[None], tau_px=3.0, weights=wts, chance=chance)[0]
            at = chamfer_at_shifts(db, q, shifts, tau_px=3.0, weights=wts, chance=chance)
            assert np.abs(at - np.take_along_axis(table, shifts, axis=1)).max() < 1e-4, chance


def test_search_finds_a_narrow_peak_wherever_the_grid_falls():
    # A camera 0.35 m from a wall, its true pose between grid points: the answer (within
    # 0.05 m and one yaw column) is the same for grid origins shifted by 0, 1/3 and 2/3 of a step.
    from dataclasses import replace

    from placeloc.geometry.floorplan import plan_grid
    from placeloc.umap.panorama import chamfer_spectra, row_weights, search_panoramas
    from placeloc.umap.params import PanoramaParams

    m = floor_plan_model(PLAN)
    truth = np.array([[5.65, 1.37, 1.4, 117.5], [0.35, 5.52, 1.4, 250.0]])
    q = _render_all(m, truth)
    q[:, ::3, ::4] = 0                                    # a few line pixels lost
    pp = replace(PanoramaParams(), chamfer_chance="area", orientation_bins=1)
    wts = row_weights(H, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
    answers = []
    for frac in (0.0, 1 / 3, 2 / 3):
        step = 0.3
        start = 0.1 + frac * step
        poses, _ = plan_grid(m, x=[start, 6.0, step], y=[start, 7.0, step], z=1.4, headings=[0.0])
        imgs = _render_all(m, poses)
        db = {"spectra": chamfer_spectra(imgs, tau_px=pp.chamfer_tau_px, weights=wts)}
        _, xy, hd, *_ = search_panoramas(q, poses, m.segments, m.faces, db, pp, tolerance_px=2, wall_margin_m=0.1, hidden=True)
        assert np.hypot(*(xy - truth[:, :2]).T).max() <= 0.05, frac
        assert np.abs((hd - truth[:, 3] + 180) % 360 - 180).max() <= 2.5, frac
        answers.append(xy)
    assert np.abs(np.array(answers) - answers[0]).max() <= 0.05


def _render_all(m, poses):
    return unpack(render_panoramas(m.segments, m.faces, np.asarray(poses, float), width=W, height=H, hidden=True), H, W)


def search_answer(q, poses, m, db, pp, truth_xy, truth_heading_deg):
    """The first query's answer by :func:`search_panoramas` on a small plan (tolerance 2 px,
    walls kept 0.1 m off, hidden lines): (metres off ``truth_xy``, signed degrees off
    ``truth_heading_deg``, its score)."""
    from placeloc.umap.panorama import search_panoramas

    found = search_panoramas(q, poses, m.segments, m.faces, db, pp, tolerance_px=2, wall_margin_m=0.1, hidden=True)
    return (float(np.hypot(*(found.xy[0] - np.asarray(truth_xy)[:2]))),
            float((found.heading[0] - truth_heading_deg + 180) % 360 - 180), float(found.score[0]))


def test_segments_skipped_whole_are_hidden_at_every_point():
    # The renderer skips a segment that one wall face hides whole; each of its points must
    # then be hidden by the per-point test (with every face a candidate), on a generated
    # home seen from a grid over its free space, and most hidden segments must be skipped.
    from placeloc.geometry.floorplan import plan_grid
    from placeloc.geometry.panorama import _segment_hidden
    from placeloc.geometry.rays import occluded
    from placeloc.synth.home import plan as home_plan

    fp, _ = home_plan(np.random.default_rng(0), 3)
    m = floor_plan_model({**fp, "camera_z": 1.5})
    faces = np.ascontiguousarray(m.faces, np.float64)
    every = np.arange(len(faces), dtype=np.int64)
    segs = m.segments.reshape(-1, 6)
    ts = np.linspace(0.0, 1.0, 33)
    skipped = hidden_whole = 0
    for px, py, pz, _ in plan_grid(m, step_m=0.9)[0]:
        for s in segs:
            a, b = s[:3], s[3:]
            pts = a[None] + ts[:, None] * (b - a)[None]
            hid = [occluded(px, py, pz, *q, faces, every, len(every)) for q in pts]
            if _segment_hidden(a[0] - px, a[1] - py, a[2], b[0] - px, b[1] - py, b[2], faces, px, py, pz):
                skipped += 1
                assert all(hid)
            hidden_whole += all(hid)
    assert skipped >= 0.7 * hidden_whole > 100


def test_segment_hidden_by_hand():
    from placeloc.geometry.panorama import _segment_hidden

    # a wall from (2, -1) to (2, 1), 0-2.5 m high; camera at the origin, 1.5 m up
    wall = np.array([[2.0, -1.0, 2.0, 1.0, 0.0, 2.5]])
    behind = (3.0, -0.5, 0.0, 3.0, 0.5, 0.0)             # a floor line behind the wall's middle
    assert _segment_hidden(*behind, wall, 0.0, 0.0, 1.5)
    assert not _segment_hidden(3.0, -0.5, 0.0, 3.0, 2.0, 0.0, wall, 0.0, 0.0, 1.5)   # reaches past its end
    assert not _segment_hidden(2.003, -0.5, 0.0, 2.003, 0.5, 0.0, wall, 0.0, 0.0, 1.5)  # within 5 mm of it
    assert not _segment_hidden(1.5, -0.5, 0.0, 1.5, 0.5, 0.0, wall, 0.0, 0.0, 1.5)    # in front of it
    assert not _segment_hidden(3.0, -0.5, 3.0, 3.0, 0.5, 3.0, wall, 0.0, 0.0, 1.5)    # seen over its top
    assert not _segment_hidden(*behind, wall[:, [0, 1, 2, 3, 4, 5]] + [0, 0, 0, 0, 0.5, 0], 0.0, 0.0, 1.5)  # a lintel


def test_solid_angle_weights_by_hand_and_floor_clutter_loses_its_pull():
    from placeloc.umap.panorama import chamfer_spectra, chamfer_table, row_weights

    # 4 rows at elevations 67.5, 22.5, -22.5, -67.5 degrees; beyond 60 degrees polar_weight 0.5
    w = row_weights(4, polar_deg=60.0, polar_weight=0.5, solid_angle=True)
    assert w == pytest.approx([0.5 * np.cos(np.radians(67.5)), np.cos(np.radians(22.5)), np.cos(np.radians(22.5)),
                               0.5 * np.cos(np.radians(67.5))], abs=1e-6)
    assert row_weights(4, polar_deg=60.0, polar_weight=0.5, solid_angle=False).tolist() == [0.5, 1.0, 1.0, 0.5]
    # View 0 (the truth) and view 1 differ at the walls (4 rows near the horizon) and on the
    # floor right under the camera (4 rows 70-86 degrees down). The query sees 9 of view 0's
    # 12 wall columns and, on its floor, stripes that lie on view 1's extra floor lines
    # (sunlight through blinds). tau 1 px: a pixel matches only on a line. Per pixel, view 0
    # scores (36/112 + 36/100) / 2 = 0.34 and view 1 (64/176 + 64/100) / 2 = 0.50; per solid
    # angle (the floor rows weigh 0.19 on average) view 0 scores about 0.67, view 1 0.22.
    h, wd = 72, 144
    db = np.zeros((2, h, wd), np.uint8)
    db[0, 30:42:3, 0:wd:12] = 1                         # view 0: wall lines near the horizon
    db[1, 30:42:3, 6:wd:12] = 1                         # view 1: others
    db[:, 64:72:2, 3:wd:9] = 1                          # both: the same floor lines
    db[1, 64:72:2, 5:wd:9] = 1                          # view 1: more of them
    q = np.zeros((h, wd), np.uint8)
    q[30:42:3, 0:108:12] = 1                            # 9 of view 0's 12 wall columns
    q[64:72:2, 5:wd:9] = 1                              # the stripes, on view 1's floor lines
    for solid, want in ((False, 1), (True, 0)):
        wts = row_weights(h, polar_deg=60.0, polar_weight=1.0, solid_angle=solid)
        table = chamfer_table(chamfer_spectra(db, tau_px=1.0, weights=wts), q[None], tau_px=1.0, weights=wts,
                              chance="none")[0]
        assert int(np.argmax(table[:, 0])) == want, solid
        if not solid:
            assert table[:, 0] == pytest.approx([(36 / 112 + 36 / 100) / 2, (64 / 176 + 64 / 100) / 2], abs=1e-5)


def test_texture_weights_by_hand():
    from placeloc.umap.panorama import TEXTURE_LINES, texture_weights

    img = np.zeros((12, 20), np.uint8)
    img[3, 2:15] = 1                                      # an isolated line: full weight
    img[6:11, 0:5] = 1                                    # a filled 5 x 5 patch (stripes at 2.5 deg a pixel)
    img[6:11, 18:20] = 1                                  # the patch goes on across the seam (2 more columns)
    w = texture_weights(img, 1)
    assert w.dtype == np.float32 and np.array_equal(w > 0, img > 0)
    assert np.all(w[3, 2:15] == 1.0)
    # inside the patch a 3 x 3 square holds 9 line pixels: two lines' worth is 2 x 3
    assert w[8, 2] == pytest.approx(TEXTURE_LINES * 3 / 9)
    # at the seam the square wraps around: column 0's square holds columns 19, 0 and 1, all lines
    assert w[8, 0] == pytest.approx(TEXTURE_LINES * 3 / 9)
    # the patch's corner (row 6, column 4): 4 line pixels in its square -> weight 1
    assert w[6, 4] == 1.0
    assert np.array_equal(texture_weights(img, 0), img.astype(np.float32))


def test_weighted_query_closeness_and_scores_equal_the_pixel_loop():
    from placeloc.umap.panorama import chamfer_at_shifts, chamfer_spectra, chamfer_table, row_weights, texture_weights

    # closeness of a weighted line image: each line pixel's kernel scaled by its weight (tau 2:
    # 1 on the pixel, 1 - 1/2 one column away)
    img = np.zeros((1, 5, 12), np.float32)
    img[0, 2, 3] = 0.5
    c = closeness(img, 2.0)
    assert c[0, 2, 3] == pytest.approx(0.5) and c[0, 2, 4] == pytest.approx(0.25) and c[0, 2, 6] == 0.0
    assert np.array_equal(closeness(np.ones((1, 5, 12), np.float32), 2.0), closeness(np.ones((1, 5, 12), np.uint8), 2.0))
    rng = np.random.default_rng(5)
    db = (rng.random((6, H, W)) < 0.03).astype(np.uint8)
    qs = (rng.random((2, H, W)) < 0.03).astype(np.uint8)
    qs[:, 50:60, 20:40] = 1                               # a dense patch: weights below 1 there
    weighted = texture_weights(qs, 2)
    assert 0 < weighted[weighted > 0].min() < 1
    for wts in (np.ones(H, np.float32), row_weights(H, polar_deg=60.0, polar_weight=0.3, solid_angle=True)):
        sp = chamfer_spectra(db, tau_px=3.0, weights=wts)
        shifts = rng.integers(0, W, size=(6, 4))
        for chance in ("none", "area", "yaw"):
            table = chamfer_table(sp, weighted, tau_px=3.0, weights=wts, chance=chance)
            if wts.min() == 1.0:                          # the pixel loop has unit row weights
                slow = np.stack([chamfer_yaw_scores(pack(db), closeness(db, 3.0), q, tau_px=3.0, chance=chance)
                                 for q in weighted])
                assert np.abs(table - slow).max() < 1e-5, chance
            at = chamfer_at_shifts(db, weighted[0], shifts, tau_px=3.0, weights=wts, chance=chance)
            assert np.abs(at - np.take_along_axis(table[0], shifts, axis=1)).max() < 1e-4, chance
        # weights of 1 are the plain binary score
        ones = chamfer_table(sp, qs.astype(np.float32), tau_px=3.0, weights=wts, chance="none")
        assert np.abs(ones - chamfer_table(sp, qs, tau_px=3.0, weights=wts, chance="none")).max() < 1e-6


def test_texture_weights_keep_stripes_from_winning_a_pose():
    # The white bonus room's failure: the true view's lines are partly detected, and sunlight
    # stripes on the floor (a dense patch) lie where another place draws its floor lines.
    # Plain, the stripes give that place the precision half; weighted, the patch counts as
    # two lines and the true view wins.
    from placeloc.umap.panorama import chamfer_spectra, chamfer_table, texture_weights

    h, w = 36, 96
    true_view = np.zeros((h, w), np.uint8)
    true_view[14, 0:w] = 1                                # the ceiling line all round
    true_view[22, 0:w] = 1                                # the floor line all round
    true_view[14:23, 0:w:24] = 1                          # four corners
    other = np.zeros((h, w), np.uint8)                    # a place nearer a wall: its lines elsewhere
    other[10, 0:w] = 1
    other[30, 10:50] = 1                                  # its floor line runs through the stripes
    other[10:31, 0:w:24] = 1
    query = true_view.copy()
    query[14, :] = 0                                      # the white ceiling line not detected
    query[22, 40:w] = 0                                   # the floor line partly
    query[27:35, 8:52] = 1                                # sunlight stripes on the carpet: a filled patch
    db = np.stack([true_view, other])
    ones = np.ones(h, np.float32)
    sp = chamfer_spectra(db, tau_px=2.0, weights=ones)
    plain = chamfer_table(sp, query[None], tau_px=2.0, weights=ones, chance="none")[0, :, 0]
    weighted = chamfer_table(sp, texture_weights(query, 2)[None], tau_px=2.0, weights=ones, chance="none")[0, :, 0]
    assert plain[1] > plain[0]
    assert weighted[0] > weighted[1]


def test_square_offsets_cover_the_cell():
    from placeloc.umap.panorama import NEIGHBOURS, refine_steps, square_offsets

    assert sorted(map(tuple, square_offsets(1))) == sorted(map(tuple, NEIGHBOURS))
    sq = square_offsets(3)
    assert len(sq) == 7 * 7 - 1 and not (sq == 0).all(axis=1).any() and np.abs(sq).max() == 3
    # at the first refine step (a sixth of the grid step) three steps reach half a grid step:
    # the square covers the grid cell around the pose, every point within half a step
    # (diagonally 0.015 m at 0.25 m) of a sampled one
    step = refine_steps(0.25, 0.02)[0]
    assert 3 * step == pytest.approx(0.25 / 2)


def test_precision_rows_by_hand():
    # 4 rows at elevations 67.5, 22.5, -22.5, -67.5 deg; the precision half keeps rows within
    # 45 deg. tau 1: closeness 1 on a line pixel, 0 elsewhere. Map pixels (1, 0) and (3, 9),
    # query pixels (1, 0) and (3, 5); 10 columns (query column c is map column c - k).
    from placeloc.umap.panorama import chamfer_spectra, chamfer_table, precision_rows

    assert precision_rows(4, 45.0).tolist() == [0, 1, 1, 0]
    assert precision_rows(72, 90.0).min() == 1 and precision_rows(72, 70.0).sum() == 72 - 2 * 8
    db = np.zeros((1, 4, 10), np.uint8)
    db[0, 1, 0] = db[0, 3, 9] = 1
    q = np.zeros((4, 10), np.uint8)
    q[1, 0] = q[3, 5] = 1
    rows = precision_rows(4, 45.0)
    for k, full, kept in ((0, 0.5 * (0.5 + 0.5), 0.5 * (0.5 + 1.0)),     # the row-3 query pixel is off the map
                          (6, 0.5 * (0.5 + 0.5), 0.5 * (0.5 + 0.0))):    # it lands on the map's row-3 pixel
        plain = chamfer_yaw_scores(pack(db), closeness(db, 1.0), q, tau_px=1.0, chance="none")
        masked = chamfer_yaw_scores(pack(db), closeness(db, 1.0), q, tau_px=1.0, chance="none", precision_rows=rows)
        assert plain[0, k] == pytest.approx(full) and masked[0, k] == pytest.approx(kept)
        ones = np.ones(4, np.float32)
        table = chamfer_table(chamfer_spectra(db, tau_px=1.0, weights=ones), q[None], tau_px=1.0, weights=ones,
                              chance="none", precision_rows=rows)
        assert table[0, 0, k] == pytest.approx(kept, abs=1e-6)


def test_precision_rows_equal_the_pixel_loop_and_the_scores_at_shifts():
    from placeloc.umap.panorama import chamfer_at_shifts, chamfer_spectra, chamfer_table, precision_rows, row_weights

    rng = np.random.default_rng(8)
    db = (rng.random((6, H, W)) < 0.03).astype(np.uint8)
    qs = (rng.random((2, H, W)) < 0.04).astype(np.uint8)
    rows = precision_rows(H, 70.0)
    shifts = rng.integers(0, W, size=(6, 4))
    for wts in (np.ones(H, np.float32), row_weights(H, polar_deg=60.0, polar_weight=1.0, solid_angle=True)):
        sp = chamfer_spectra(db, tau_px=3.0, weights=wts)
        for chance in ("none", "area", "yaw"):
            table = chamfer_table(sp, qs, tau_px=3.0, weights=wts, chance=chance, precision_rows=rows)
            if wts.min() == 1.0:
                slow = np.stack([chamfer_yaw_scores(pack(db), closeness(db, 3.0), q, tau_px=3.0, chance=chance,
                                                    precision_rows=rows) for q in qs])
                assert np.abs(table - slow).max() < 1e-5, chance
            at = chamfer_at_shifts(db, qs[1], shifts, tau_px=3.0, weights=wts, chance=chance, precision_rows=rows)
            assert np.abs(at - np.take_along_axis(table[1], shifts, axis=1)).max() < 1e-4, chance


def test_likelihood_image_by_hand():
    # one row of 10 columns, tau 2: map lines at columns 0 and 5 -> closeness
    # 1, .5, 0, 0, .5, 1, .5, 0, 0, .5, mean A = 0.4; clutter share s = 0.2:
    # log(s + (1 - s) g / A) = log(0.2 + 2 g)
    from placeloc.umap.panorama import likelihood_image

    db = np.zeros((1, 10), np.uint8)
    db[0, [0, 5]] = 1
    g = closeness(db, 2.0)
    lik = likelihood_image(g, np.ones(1, np.float32), 0.2)
    assert lik[0, 0] == pytest.approx(np.log(2.2))
    assert lik[0, 1] == pytest.approx(np.log(1.2))
    assert lik[0, 2] == pytest.approx(np.log(0.2))
    # no lines: nothing explained, log s everywhere
    assert np.allclose(likelihood_image(np.zeros((2, 10), np.float32), np.ones(2, np.float32), 0.2), np.log(0.2))
    # row weights enter the mean: a second, empty row of weight 3 makes A = 0.4 / 4 = 0.1
    two = np.concatenate([g, np.zeros((1, 10), np.float32)])
    lik2 = likelihood_image(two, np.array([1.0, 3.0], np.float32), 0.2)
    assert lik2[0, 0] == pytest.approx(np.log(0.2 + 0.8 * 1.0 / 0.1))


def test_likelihood_score_by_hand_and_against_the_pixel_loop():
    from placeloc.umap.panorama import chamfer_at_shifts, chamfer_spectra, chamfer_table, row_weights

    # the row of the hand case above; the query's one line pixel at column 1, s = 0.2
    db = np.zeros((1, 1, 10), np.uint8)
    db[0, 0, [0, 5]] = 1
    q = np.zeros((1, 10), np.uint8)
    q[0, 1] = 1
    score = chamfer_yaw_scores(pack(db), closeness(db, 2.0), q, tau_px=2.0, chance="likelihood", clutter_share=0.2)
    # shift 1: precision: the query pixel on map column 0, log(0.2 + 0.8 * 1 / 0.4) = log 2.2;
    # recall: the query's closeness 1, .5, .5 at columns 1, 0, 2 (mean A_q 0.2): map columns
    # 0 and 5 land on query columns 1 and 6, closeness 1 and 0: (log(0.2 + 4) + log 0.2) / 2
    assert score[0, 1] == pytest.approx(0.5 * (0.5 * (np.log(4.2) + np.log(0.2)) + np.log(2.2)))
    # the spectra and the scores at shifts equal the pixel loop, with and without row weights
    rng = np.random.default_rng(5)
    dbs = (rng.random((9, H, W)) < 0.03).astype(np.uint8)
    dbs[4] = 0                                           # an empty view
    qs = (rng.random((3, H, W)) < 0.04).astype(np.uint8)
    ones = np.ones(H, np.float32)
    for s in (0.1, 0.5, 0.9):
        fast = chamfer_table(chamfer_spectra(dbs, tau_px=3.0, weights=ones, clutter_share=s), qs, tau_px=3.0,
                             weights=ones, chance="likelihood", clutter_share=s)
        slow = np.stack([chamfer_yaw_scores(pack(dbs), closeness(dbs, 3.0), x, tau_px=3.0, chance="likelihood",
                                            clutter_share=s) for x in qs])
        assert np.abs(fast - slow).max() < 1e-4
    shifts = rng.integers(0, W, size=(9, 4))
    for wts in (ones, row_weights(H, polar_deg=60.0, polar_weight=0.3, solid_angle=True)):
        table = chamfer_table(chamfer_spectra(dbs, tau_px=3.0, weights=wts, clutter_share=0.4), qs[:1], tau_px=3.0,
                              weights=wts, chance="likelihood", clutter_share=0.4)[0]
        at = chamfer_at_shifts(dbs, qs[0], shifts, tau_px=3.0, weights=wts, chance="likelihood", clutter_share=0.4)
        assert np.abs(at - np.take_along_axis(table, shifts, axis=1)).max() < 1e-4


def test_likelihood_score_does_not_reward_a_busy_view():
    # the planted case of test_chance_correction_does_not_reward_a_busy_view: a sparse query
    # (two partly detected lines plus clutter) is won by the busy view under the plain score
    # and by its own view under the likelihood ratio, for any clutter share
    from placeloc.umap.panorama import chamfer_spectra, chamfer_table

    rng = np.random.default_rng(7)
    h, w = 24, 96
    sparse = np.zeros((h, w), np.uint8)
    sparse[12, 10:40] = 1
    sparse[4, 50:90] = 1
    busy = sparse.copy()
    busy[2:22, 0:w:8] = 1
    query = sparse.copy()
    query[12, 22:40] = 0
    query[4, 62:90] = 0
    for c in rng.integers(0, w, 10):
        query[6:20, c] = 1
    db = np.stack([sparse, busy])
    ones = np.ones(h, np.float32)
    plain = chamfer_table(chamfer_spectra(db, tau_px=3.0, weights=ones), query[None], tau_px=3.0, weights=ones,
                          chance="none")[0, :, 0]
    assert plain[1] > plain[0]
    for s in (0.2, 0.5, 0.8):
        lik = chamfer_table(chamfer_spectra(db, tau_px=3.0, weights=ones, clutter_share=s), query[None], tau_px=3.0,
                            weights=ones, chance="likelihood", clutter_share=s)[0, :, 0]
        assert lik[0] > lik[1], s


def test_every_candidate_climbing_makes_the_answer_independent_of_the_grid_origin():
    # Four cameras of the L-shaped room (two 0.35-0.4 m from a wall, one 0.38 m from the
    # far wall of the upper arm), grids of 0.3 m with origins shifted by 0, 1/3 and 2/3 of a
    # step, a beam of one pose climbing by 8 neighbours, no final search: with refine_climb every candidate
    # climbs once before the beam is chosen, and each camera's answer is the same at every
    # origin (within 0.01 m) and within 0.03 m of the truth; without it the camera 0.4 m
    # from the bottom wall ends 0.035 m off at origin 2/3 and 0 m off at the others.
    from dataclasses import replace

    from placeloc.geometry.floorplan import plan_grid
    from placeloc.umap.panorama import chamfer_spectra, row_weights, search_panoramas
    from placeloc.umap.params import PanoramaParams

    m = floor_plan_model(PLAN)
    truth = np.array([[5.65, 1.37, 1.4, 117.5], [0.35, 5.52, 1.4, 250.0], [3.2, 0.4, 1.4, 30.0], [1.8, 6.62, 1.4, 200.0]])
    q = _render_all(m, truth)
    q[:, ::3, ::4] = 0                                    # a few line pixels lost
    answers = {0: [], 1: []}
    for climb in (0, 1):
        pp = replace(PanoramaParams(), refine_beam=1, refine_square=1, refine_climb=climb, orientation_bins=1,
                     refine_final_m=0.0)
        wts = row_weights(H, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
        for frac in (0.0, 1 / 3, 2 / 3):
            start = 0.1 + frac * 0.3
            poses, _ = plan_grid(m, x=[start, 6.0, 0.3], y=[start, 7.0, 0.3], z=1.4, headings=[0.0])
            db = {"spectra": chamfer_spectra(_render_all(m, poses), tau_px=pp.chamfer_tau_px, weights=wts)}
            _, xy, *_ = search_panoramas(q, poses, m.segments, m.faces, db, pp, tolerance_px=2, wall_margin_m=0.1,
                                           hidden=True)
            answers[climb].append(xy)
    climbed = np.array(answers[1])
    assert np.hypot(*(climbed - truth[None, :, :2]).transpose(2, 0, 1)).max() <= 0.03
    assert np.abs(climbed - climbed[0]).max() <= 0.01
    off = np.hypot(*(np.array(answers[0])[:, 2] - truth[2, :2]).T)
    assert off[2] > 0.03 and off[:2].max() < 0.01
