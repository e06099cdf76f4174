"""Levelling a tilted panorama: the zenith found from its vertical lines, against planted
lines whose zenith is known, against a panorama turned by a known tilt, and in the
generated homes' tilted cameras."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from placeloc.geometry.panorama import (
    axis_rotation,
    directions,
    draw_line_image,
    panorama_lines,
    segment_normals,
    turn_panorama,
    upright_rotation,
)
from placeloc.umap.query_features import panorama_arrays
from tests.test_umap_panorama import _grey_panorama, _render


def _normal(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    n = np.cross(a, b)
    return n / np.linalg.norm(n)


def _zenith(rotation: np.ndarray) -> np.ndarray:
    """The direction of the world's zenith in the image of a camera turned by ``rotation``
    (that image's pixel d shows the world at rotation @ d)."""
    return rotation.T @ np.array([0.0, 0.0, 1.0])


def test_axis_rotation_by_hand():
    assert np.allclose(axis_rotation(np.array([0.0, 0.0, 2.0]), 90.0) @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    r = axis_rotation(np.array([1.0, 1.0, 0.0]), 7.0)
    assert np.allclose(r @ r.T, np.eye(3)) and math.degrees(math.acos(r[2, 2])) == pytest.approx(7.0)


def _scene(tilt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lines as a camera 1.5 m up, turned by ``tilt``, sees them: 12 vertical door and corner
    edges 1.5-4 m away, all round, and a plank floor under it (12 boards along x, 0.05-0.6 m
    beside its foot, 3 m long), the planks' great circles passing the nadir 2-22 deg off.
    Returns the normals and spans :func:`upright_rotation` takes."""
    world = []
    for k in range(12):
        az = math.radians(30.0 * k + 7.0)
        d = 1.5 + 0.2 * k
        p = np.array([d * math.cos(az), d * math.sin(az), 0.0])
        world.append((p + [0, 0, -1.2], p + [0, 0, 0.5]))
    for k in range(12):
        y = (0.05 + 0.05 * k) * (1 if k % 2 else -1)
        world.append((np.array([0.3, y, -1.5]), np.array([3.3, y, -1.5])))
    seen = [(tilt.T @ a / np.linalg.norm(a), tilt.T @ b / np.linalg.norm(b)) for a, b in world]   # image directions
    normals = np.array([_normal(a, b) for a, b in seen])
    spans = np.array([math.acos(np.clip(a @ b, -1, 1)) for a, b in seen])
    return normals, spans


@pytest.mark.parametrize("tilt_deg,axis_deg", [(0.0, 0.0), (0.3, 100.0), (3.0, 40.0), (8.0, 200.0), (15.0, 290.0)])
def test_the_zenith_of_planted_lines_is_found_and_planks_do_not_pull_it(tilt_deg, axis_deg):
    a = math.radians(axis_deg)
    tilt = axis_rotation(np.array([math.cos(a), math.sin(a), 0.0]), tilt_deg)
    normals, spans = _scene(tilt)
    rotation, found = upright_rotation(normals, spans, max_tilt_deg=20.0)
    if tilt_deg < 0.5:                               # below a level panorama's own scatter: left as it is
        assert found == 0.0 and np.array_equal(rotation, np.eye(3))
        return
    assert found == pytest.approx(tilt_deg, abs=1e-6)
    # the rotation takes the image's zenith to (0, 0, 1)
    assert np.allclose(rotation @ _zenith(tilt), [0.0, 0.0, 1.0], atol=1e-9)


def test_no_turn_without_enough_lines_or_beyond_the_limit():
    tilt = axis_rotation(np.array([1.0, 0.0, 0.0]), 8.0)
    normals, spans = _scene(tilt)
    # only the planks: no point where their great circles meet near the zenith
    rotation, found = upright_rotation(normals[12:], spans[12:], max_tilt_deg=20.0)
    assert found == 0.0 and np.array_equal(rotation, np.eye(3))
    # three vertical lines: fewer than the four it levels by
    assert upright_rotation(normals[:3], spans[:3], max_tilt_deg=20.0)[1] == 0.0
    # vertical lines seen in one direction only (0 and 180 deg): the zenith is not fixed across them
    one_way = np.array([_normal(directions(np.array(az), np.array(-0.3)), directions(np.array(az), np.array(0.4)))
                        for az in (0.0, 0.0, math.pi, math.pi, 0.0)])
    assert upright_rotation(one_way, np.full(5, 0.7), max_tilt_deg=20.0)[1] == 0.0
    # beyond max_tilt_deg the image is taken as it is; 0 turns levelling off
    assert upright_rotation(normals, spans, max_tilt_deg=5.0)[1] == 0.0
    assert upright_rotation(normals, spans, max_tilt_deg=0.0)[1] == 0.0


def test_turn_panorama_moves_a_direction_where_the_rotation_says():
    img = np.zeros((256, 512), np.uint8)
    img[60:64, 100:104] = 255                        # a spot at a known direction
    rotation = axis_rotation(np.array([0.3, 1.0, 0.2]), 12.0)
    turned = turn_panorama(img, rotation)

    def direction(image):
        v, u = np.argwhere(image > 128).mean(axis=0) + 0.5
        return directions(np.array(math.pi - 2 * math.pi * u / 512), np.array(math.pi / 2 - math.pi * v / 256))

    # the turned image's pixel d shows the original's rotation @ d
    assert math.degrees(math.acos(np.clip((rotation @ direction(turned)) @ direction(img), -1, 1))) < 0.5


@pytest.mark.parametrize("tilt_deg,axis_deg", [(4.0, 30.0), (9.0, 250.0)])
def test_a_tilted_panorama_is_levelled_back_onto_the_map_lines(tilt_deg, axis_deg):
    pose = [2.1, 5.3, 1.4, 62.5]
    img = _grey_panorama(pose, np.random.default_rng(1))
    a = math.radians(axis_deg)
    tilt = axis_rotation(np.array([math.cos(a), math.sin(a), 0.0]), tilt_deg)
    tilted = turn_panorama(img, tilt)
    w, h = 288, 144                                  # 1.25 deg a pixel: a few degrees of tilt show
    ref = _render(pose, w, h)
    near = np.ones((3, 3), np.uint8)

    def image(arrays):
        return np.unpackbits(arrays["lines"][0].view(np.uint8), bitorder="little")[:h * w].reshape(h, w)

    def on_map(arrays):                              # detected line pixels within one pixel of a map line
        q = image(arrays)
        return (q & cv2.dilate(ref, near)).sum() / q.sum()

    kw = {"width": w, "height": h, "face_px": 256, "min_length": 8.0}
    level = panorama_arrays(tilted, level_max_deg=20.0, **kw)
    assert float(level["tilt_deg"]) == pytest.approx(tilt_deg, abs=0.5)
    as_is = panorama_arrays(tilted, level_max_deg=0.0, **kw)
    assert float(as_is["tilt_deg"]) == 0.0
    upright = panorama_arrays(img, level_max_deg=20.0, **kw)
    assert float(upright["tilt_deg"]) == 0.0          # a level panorama is left as it is
    # levelled, the lines lie on the map as the upright panorama's do (0.75 of them: the rest
    # is the clutter); as they are, a good share lies off it (4 deg: 0.43, 9 deg: 0.22)
    assert on_map(level) > 0.95 * on_map(upright)
    assert on_map(as_is) < 0.7 * on_map(upright)
    # the drawing with the rotation found is the same as the levelled arrays
    faces = panorama_lines(tilted, face_px=256, min_length=8.0)
    rotation, _ = upright_rotation(*segment_normals(faces, 256), max_tilt_deg=20.0)
    assert np.array_equal(draw_line_image(faces, face_px=256, width=w, height=h, rotation=rotation), image(level))


def test_generated_cameras_tilt_as_asked_and_are_levelled(tmp_path):
    # tilt_deg 8: each camera tilted by 0-8 deg about a horizontal axis; the poses, headings
    # and plan are those of the level home (a generator of its own), and levelling finds
    # each tilt again
    import csv

    from placeloc.synth.home import generate

    kw = {"seed": 3, "panoramas": 6, "width": 512, "stats_width": 64}
    generate(tmp_path / "level", **kw)
    generate(tmp_path / "tilted", tilt_deg=8.0, **kw)
    rows = {k: list(csv.DictReader(open(tmp_path / k / "poses.csv"))) for k in ("level", "tilted")}
    assert "tilt_deg" not in rows["level"][0]
    for a, b in zip(*rows.values()):
        assert (a["frame"], a["x"], a["y"], a["z"], a["heading_deg"]) == (b["frame"], b["x"], b["y"], b["z"], b["heading_deg"])
        assert 0.0 <= float(b["tilt_deg"]) <= 8.0
        gray = cv2.imread(str(tmp_path / "tilted" / "panoramas" / b["frame"]), cv2.IMREAD_GRAYSCALE)
        found = float(panorama_arrays(gray, width=144, height=72, face_px=128, min_length=4.0,
                                      level_max_deg=20.0)["tilt_deg"])
        assert found == pytest.approx(float(b["tilt_deg"]), abs=1.0), b["frame"]
    # the line statistics are the scene's at the true pose: the tilted camera's lines levelled
    # by its known tilt agree with the level camera's (medians within 5 points; 72 / 71 % here)
    import json
    stats = {k: json.loads((tmp_path / k / "line_stats.json").read_text()) for k in ("level", "tilted")}
    for key in ("detected_on_map", "map_detected"):
        assert stats["tilted"][key] == pytest.approx(stats["level"][key], abs=0.05)


def test_tilted_panoramas_localized_end_to_end(tmp_path):
    # three cameras of the L-shaped room tilted by 6-8 deg, localized levelled (the default)
    # and as they are: levelled, each is found within 0.05 m, its tilt is in estimates.csv and
    # its score is that of a level camera (0.79-0.84 here); as they are, the clean room still
    # places them within 0.1 m, but each scores 0.15 or more lower (0.50-0.62), the margin a
    # look-alike room or clutter takes
    import csv
    import json

    import yaml

    from placeloc.core.config import load_config
    from placeloc.core.runner import run_all
    from tests.test_umap_panorama import PLAN

    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(PLAN))
    (tmp_path / "q").mkdir()
    truth = [(1.2, 1.1, 1.4, 30.0), (4.9, 2.6, 1.4, 200.0), (2.3, 5.8, 1.4, 287.5)]
    tilts = [(6.0, 20.0), (7.0, 140.0), (8.0, 260.0)]
    rng = np.random.default_rng(2)
    with open(tmp_path / "poses.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "z", "heading_deg"])
        for k, (pose, (deg, axis)) in enumerate(zip(truth, tilts)):
            a = math.radians(axis)
            img = turn_panorama(_grey_panorama(pose, rng), axis_rotation(np.array([math.cos(a), math.sin(a), 0.0]), deg))
            cv2.imwrite(str(tmp_path / "q" / f"p{k}.png"), img)
            w.writerow([f"p{k}.png", *pose])
    runs = {}
    for level_max_deg in (20.0, 0.0):
        cfg = load_config(data={"method": "umap", "query": {"images": str(tmp_path / "q")},
                                "ground_truth": {"kind": "poses", "path": str(tmp_path / "poses.csv")},
                                "umap": {"model": str(tmp_path / "plan.yaml"), "query_kind": "panorama",
                                         "grid": {"x": [0.2, 5.8, 0.2], "y": [0.2, 6.8, 0.2], "z": 1.4, "headings": [0.0]},
                                         "panorama": {"level_max_deg": level_max_deg}},
                                "plots": False}, base_dir=tmp_path)
        run_all(cfg, tmp_path / f"run{level_max_deg:g}", quiet=True)
        runs[level_max_deg] = (json.loads((tmp_path / f"run{level_max_deg:g}" / "metrics.json").read_text()),
                               list(csv.DictReader(open(tmp_path / f"run{level_max_deg:g}" / "estimates.csv"))))
    (level, level_rows), (as_is, as_is_rows) = runs[20.0], runs[0.0]
    assert level["max_error_m"] <= 0.05 and as_is["median_error_m"] > level["median_error_m"]
    assert [float(r["tilt_deg"]) for r in level_rows] == pytest.approx([t for t, _ in tilts], abs=0.5)
    assert "tilt_deg" not in as_is_rows[0]
    # what `placeloc run` prints of each answer names its tilt
    from placeloc.evaluation.report import answer_lines
    assert f", tilt_deg {level_rows[0]['tilt_deg']}, " in answer_lines(tmp_path / "run20")[0]
    for a, b in zip(level_rows, as_is_rows):
        assert float(a["score"]) >= float(b["score"]) + 0.15
