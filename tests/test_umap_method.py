"""Known answers for UMap scoring and Consistency Adjustment, and a tiny corridor end to end."""

from __future__ import annotations

import csv
import math

import cv2
import numpy as np
import pytest

from placeloc.umap import ca
from placeloc.umap.bits import and_count, iou_naive, iou_scores, pack, popcount_rows, unpack


def test_pack_roundtrip_and_layout():
    rng = np.random.default_rng(1)
    imgs = (rng.random((3, 7, 13)) < 0.3).astype(np.uint8)   # 91 pixels: two words, padded
    words = pack(imgs)
    assert words.shape == (3, 2) and words.dtype == np.uint64
    assert (unpack(words, 7, 13) == imgs).all()
    one = np.zeros((1, 8, 8), np.uint8)
    one[0, 1, 2] = 1                                          # pixel 10 -> bit 10 of word 0
    assert int(pack(one)[0, 0]) == 1 << 10


def test_iou_on_hand_made_masks():
    db = np.zeros((3, 4, 16), np.uint8)
    db[0, 1, 0:8] = 1          # 8 px
    db[1, 1, 4:16] = 1         # 12 px
    db[2, 3, :] = 1            # 16 px, disjoint from the query
    q = np.zeros((4, 16), np.uint8)
    q[1, 0:6] = 1              # 6 px
    words = pack(db)
    counts = popcount_rows(words)
    assert counts.tolist() == [8, 12, 16]
    assert and_count(words, pack(q)).tolist() == [6, 2, 0]
    # M = LC / (A(DB) + A(SEN) - LC): 6 / 8, 2 / 16, 0 / 22
    s = iou_scores(words, counts, pack(q))
    assert s == pytest.approx([6 / 8, 2 / 16, 0.0])
    assert s == pytest.approx(iou_naive(db, q))
    assert iou_scores(words, counts, pack(q), rows=np.array([1])) == pytest.approx([2 / 16])
    with pytest.raises(ValueError, match="differ in size"):
        and_count(words, pack(np.zeros((5, 16), np.uint8)))


def test_iou_fast_equals_naive_on_random_images():
    rng = np.random.default_rng(2)
    db = (rng.random((200, 24, 32)) < 0.1).astype(np.uint8)
    q = (rng.random((24, 32)) < 0.1).astype(np.uint8)
    words = pack(db)
    assert iou_scores(words, popcount_rows(words), pack(q)) == pytest.approx(iou_naive(db, q))


def test_eq2_eq3_by_hand():
    # |n| = 100 px, width 400, phi = 45 deg: omega = 90 - atan(100 * 1 / 400) = 90 - 14.036 deg
    # theta = 30 deg, d = 2 m: m = 2 tan(30 + 14.036) - 2 tan(30) = 2 (0.966912 - 0.577350) = 0.779123 m
    assert ca.moved_distance_paper(100, 2.0, 30.0, 45.0, 400) == pytest.approx(0.779123, abs=1e-5)
    assert ca.moved_distance_paper(-100, 2.0, 30.0, 45.0, 400) == pytest.approx(0.779123, abs=1e-5)  # |n|
    assert ca.moved_distance_paper(0, 2.0, 30.0, 45.0, 400) == 0.0
    # the effective phi makes eq. (2)'s angle the pinhole angle: |n| tan(phi) / width = |n| / f
    f = 200 / math.tan(math.radians(30))
    assert math.tan(math.radians(ca.effective_phi(60.0))) / 400 == pytest.approx(1 / f)
    # exact: centroid moves from the centre (beta 0) to 100 px right (wall on the right):
    # the wall point's angle from the normal drops from 45 to 45 - atan(100 / f) deg.
    got = ca.moved_distance_exact(199.5, 299.5, 1.6, 45.0, f, 199.5, wall_right=True)
    want = 1.6 * (1 - math.tan(math.radians(45) - math.atan(100 / f)))
    assert got == pytest.approx(want)


def test_exact_moved_distance_on_a_projected_wall_point():
    # Camera at (0, 1.6) looking at heading 315 (wall y = 0 on its right), moves +x by 0.7 m.
    f, cx = 277.128, 159.5
    p = np.array([2.0, 0.0])

    def u_of(cam_x: float) -> float:
        h = math.radians(315)
        d = p - np.array([cam_x, 1.6])
        fwd = d @ [math.cos(h), math.sin(h)]
        right = d @ [math.sin(h), -math.cos(h)]
        return cx + f * right / fwd

    m = ca.moved_distance_exact(u_of(0.0), u_of(0.7), 1.6, 45.0, f, cx, wall_right=True)
    assert m == pytest.approx(0.7, abs=1e-6)


def test_majority_vote_keeps_planted_group():
    rng = np.random.default_rng(3)
    inliers = np.array([-40.0, 3.0]) + rng.normal(0, 1.0, (30, 2))
    outliers = rng.uniform(-150, 150, (12, 2))
    keep = ca.majority_vote(np.vstack([inliers, outliers]), bin_px=8.0)
    assert keep[:30].all()
    assert keep[30:].sum() <= 1  # a random outlier may land inside the group by chance
    assert ca.majority_vote(np.zeros((0, 2)), 8.0).size == 0


def test_akaze_and_centroid_shift_on_shifted_texture():
    rng = np.random.default_rng(4)
    tex = cv2.GaussianBlur((rng.random((240, 400)) * 255).astype(np.uint8), (0, 0), 2.0)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX)
    a, b = tex[:, 40:360], tex[:, 15:335]         # the scene slid 25 px to the right in b
    pa, da = ca.akaze(a, 0.0001)
    pb, db = ca.akaze(b, 0.0001)
    assert len(pa) > 20 and da.shape[1] == 61
    shift = ca.centroid_shift(pa, da, pb, db, 8.0, 5)
    assert shift is not None and shift[0] == pytest.approx(25.0, abs=0.5)


# ------------------------------------------------------------------ end to end

def _tiny_corridor(tmp_path, size=(160, 120)):
    """A 12 m corridor with doors at different places, rendered as line drawings (query =
    the wireframe's own render, thickened and with clutter), plus poses and sensor CSVs."""
    from placeloc.geometry import Camera
    from placeloc.geometry.floorplan import floor_plan_model
    from placeloc.umap.render import render_packed

    plan = {"floor_z": 0.0, "ceiling_z": 2.6, "outline": [[0, 0], [12, 0], [12, 2.4], [0, 2.4]],
            "doors": [{"from": [2, 0], "to": [2.9, 0], "height": 2.0}, {"from": [7.5, 0], "to": [8.4, 0], "height": 2.0},
                      {"from": [4.0, 2.4], "to": [4.9, 2.4], "height": 2.0}]}
    import yaml

    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(plan))
    m = floor_plan_model(plan)
    cam = Camera(size[0], size[1], 60.0)
    (tmp_path / "q").mkdir()
    truth = [(1.0 + 0.6 * k, 1.2, 1.14, 315.0) for k in range(8)]
    rng = np.random.default_rng(0)
    with open(tmp_path / "poses.csv", "w", newline="") as f, open(tmp_path / "sensor.csv", "w", newline="") as g:
        w, s = csv.writer(f), csv.writer(g)
        w.writerow(["frame", "x", "y", "z", "heading_deg"])
        s.writerow(["frame", "d", "theta_deg"])
        for k, pose in enumerate(truth):
            img = unpack(render_packed(m.segments, m.faces, np.array([pose]), cam), cam.height, cam.width)[0]
            img = cv2.dilate(img * 200, np.ones((2, 2), np.uint8)) + 30
            cv2.line(img, (int(rng.integers(0, 80)), 10), (int(rng.integers(80, 160)), 30), 220, 1)  # clutter
            # a textured band so AKAZE finds features that move with the camera
            name = f"f{k}.png"
            cv2.imwrite(str(tmp_path / "q" / name), img)
            w.writerow([name, *pose])
            s.writerow([name, 1.2, 45.0])
    return tmp_path


def _config(tmp_path, **umap):
    from placeloc.core.config import load_config

    data = {"method": "umap", "query": {"images": str(tmp_path / "q")},
            "ground_truth": {"kind": "poses", "path": str(tmp_path / "poses.csv")},
            "umap": {"model": str(tmp_path / "plan.yaml"), "sensor_csv": str(tmp_path / "sensor.csv"), "mode": "umap",
                     "grid": {"x": [0.4, 11.6, 0.2], "y": [0.4, 2.0, 0.4], "z": 1.14, "headings": [45.0, 135.0, 225.0, 315.0]},
                     **umap},
            "plots": True}
    return load_config(data=data, base_dir=tmp_path)


def test_tiny_corridor_right_pose_wins(tmp_path):
    from placeloc.core.runner import run_all

    _tiny_corridor(tmp_path)
    cfg = _config(tmp_path)
    run_all(cfg, tmp_path / "run", quiet=True)
    import json

    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["n_frames"] == 8
    assert m["max_error_m"] <= 0.25 and m["within_0_5m"] == 1.0
    rows = list(csv.DictReader(open(tmp_path / "run" / "estimates.csv")))
    assert [r["heading_deg"] for r in rows] == ["315.0"] * 8
    assert (tmp_path / "run" / "error_cdf.png").stat().st_size > 1000
    assert (tmp_path / "run" / "estimates_on_plan.png").stat().st_size > 1000
    import h5py

    # the database is stored once: drawn dilated by build-dictionary, only counted by index
    with h5py.File(tmp_path / "run" / "index.h5") as f:
        assert "bits" not in f and f.attrs["bits_in"] == "build-dictionary/db"
    with h5py.File(tmp_path / "run" / "build-dictionary.h5") as f:
        assert int(f.attrs["dilated_px"]) == 2


def test_bad_inputs(tmp_path):
    from placeloc.core.config import ConfigError
    from placeloc.core.images import ImageError
    from placeloc.core.runner import run_stage

    _tiny_corridor(tmp_path)
    # a grid that misses the model names both
    with pytest.raises(ConfigError, match=r"grid \(x 20.00..30.00 m, y 0.40..2.00 m\) keeps no position of .*plan.yaml "
                                          r"\(plan x 0.00..12.00 m, y 0.00..2.40 m\)"):
        run_stage(_config(tmp_path, grid={"x": [20.0, 30.0, 0.5], "y": [0.4, 2.0, 0.4], "z": 1.14}), tmp_path / "r1",
                  "build-dictionary", quiet=True)
    # no z and a plan without camera_z: told to give one
    with pytest.raises(ConfigError, match=r"gives no camera height \(camera_z\): set grid.z"):
        run_stage(_config(tmp_path, grid={}), tmp_path / "r1", "build-dictionary", quiet=True)
    with pytest.raises(ConfigError, match="umap.sensor_csv"):
        _config(tmp_path, mode="umap+ca", sensor_csv=None)
    # a query of another size (aspect) than the database camera (its pose is known, so the
    # ground-truth check before any stage passes and the image check at extract speaks)
    cv2.imwrite(str(tmp_path / "q" / "f9.png"), np.zeros((100, 100), np.uint8))
    with open(tmp_path / "poses.csv", "a") as f:
        f.write("f9.png,1.0,1.2,1.14,315.0\n")
    with pytest.raises(ImageError, match=r"f9.png: query image is 100x100"):
        run_stage(_config(tmp_path), tmp_path / "r2", "extract", quiet=True)


def test_localize_only_key_does_not_rerun_extract_or_render(tmp_path):
    # ca.tie_tol is read by localize only: extract, the database and the index stay as they are.
    from placeloc.core.runner import run_all

    _tiny_corridor(tmp_path)
    run = tmp_path / "run"
    run_all(_config(tmp_path, mode="umap+ca"), run, quiet=True)
    first = {p.name: p.stat().st_mtime_ns for p in run.glob("*.h5")}
    run_all(_config(tmp_path, mode="umap+ca", ca={"tie_tol": 0.01}), run, quiet=True)
    after = {p.name: p.stat().st_mtime_ns for p in run.glob("*.h5")}
    for stage in ("extract.h5", "build-dictionary.h5", "index.h5"):
        assert after[stage] == first[stage], stage
    assert after["localize.h5"] != first["localize.h5"]
    # an extract key (the AKAZE threshold) re-runs extract
    run_all(_config(tmp_path, mode="umap+ca", ca={"tie_tol": 0.01, "akaze_threshold": 0.0001}), run, quiet=True)
    assert {p.name: p.stat().st_mtime_ns for p in run.glob("*.h5")}["extract.h5"] != after["extract.h5"]


def test_on_error_skip_leaves_out_a_broken_query_image(tmp_path):
    import json

    from placeloc.core.artifacts import read_strings
    from placeloc.core.images import ImageError
    from placeloc.core.runner import run_all, run_stage

    _tiny_corridor(tmp_path)
    (tmp_path / "q" / "f3b.png").write_bytes(b"not an image")
    with open(tmp_path / "poses.csv", "a") as f:
        f.write("f3b.png,3.0,1.2,1.14,315.0\n")
    with pytest.raises(ImageError, match="f3b.png: cannot be read"):
        run_stage(_config(tmp_path), tmp_path / "r1", "extract", quiet=True)
    cfg = _config(tmp_path)
    cfg["query"]["on_error"] = "skip"
    run_all(cfg, tmp_path / "r2", quiet=True)
    m = json.loads((tmp_path / "r2" / "metrics.json").read_text())
    assert m["n_frames"] == 8 and m["within_0_5m"] == 1.0
    import h5py

    with h5py.File(tmp_path / "r2" / "extract.h5") as f:
        assert "f3b.png" not in read_strings(f["names"]) and len(read_strings(f["skipped"])) == 1


def test_poses_file_lacking_a_query_frame_is_refused_before_any_stage(tmp_path):
    """The poses contract checks its ground truth when the config is loaded: a query image
    without a pose is one error naming the file and the frame, and no stage has run."""
    from placeloc.core.config import ConfigError

    _tiny_corridor(tmp_path)
    cv2.imwrite(str(tmp_path / "q" / "f8.png"), cv2.imread(str(tmp_path / "q" / "f0.png")))
    with pytest.raises(ConfigError, match=r"poses.csv: no pose for 1 of 9 query frames \(first: f8.png\)"):
        _config(tmp_path)


def test_panorama_overlay_draws_each_image_column_at_its_azimuth(tmp_path):
    """plot_panorama_overlay: detected lines grey, the map at the estimate red, at the truth
    green, both brown, image column c at its place across the axes (fixed margins: 7 % to
    98 % of the 1000 px width)."""
    from PIL import Image

    from placeloc.umap.plots import plot_panorama_overlay

    h, w = 72, 144
    query, at_est, at_truth = (np.zeros((h, w), np.uint8) for _ in range(3))
    query[:, 10] = 1
    at_est[:, 60] = at_est[:, 100] = 1
    at_truth[:, 100] = at_truth[:, 130] = 1
    plot_panorama_overlay(tmp_path / "p.png", query, at_est, at_truth, "pano.png: error 0.10 m")
    img = np.asarray(Image.open(tmp_path / "p.png").convert("RGB")).astype(int)
    assert img.shape[:2] == (560, 1000)
    row = img[280]

    def colour_at(col: int) -> np.ndarray:
        return row[int(round(70 + (col + 0.5) / w * 910))]

    for col, rgb in ((10, (0.55, 0.55, 0.55)),    # grey: detected
                     (60, (0.85, 0.1, 0.1)),      # red: the map at the estimate
                     (130, (0.1, 0.65, 0.1)),     # green: at the truth
                     (100, (0.55, 0.35, 0.0)),    # brown: both
                     (30, (1.0, 1.0, 1.0))):      # nothing
        assert np.abs(colour_at(col) - 255 * np.array(rgb)).max() <= 1, (col, colour_at(col))


def test_a_query_image_of_the_wrong_shape_is_named_with_its_fix():
    """A 4000 x 3000 photo given as a panorama: the error names the file, its size and
    aspect, what a panorama needs and the setting for ordinary photos; a second image of
    another size than the first names both sizes."""
    from pathlib import Path

    from placeloc.core.images import ImageError
    from placeloc.geometry import Camera
    from placeloc.umap.lines import check_query_size

    cam = Camera(640, 480, 90.0)
    with pytest.raises(ImageError, match=r"IMG_1\.jpg: query image is 4000x3000 \(aspect 1\.333\); an equirectangular "
                                         r"panorama needs width = 2 x height .*set umap\.query_kind: pinhole"):
        check_query_size(Path("IMG_1.jpg"), (3000, 4000, 3), None, cam, "equirect")
    check_query_size(Path("p.jpg"), (2880, 5760, 3), None, cam, "equirect")          # 2:1: fine
    with pytest.raises(ImageError, match=r"is 5760x2880 but the first query image is 4096x2048"):
        check_query_size(Path("p.jpg"), (2880, 5760, 3), (2048, 4096), cam, "equirect")
