"""Known answers for the search over camera heights (``umap.grid.heights``): each
panorama's answer is the best over the grid's layers, one per height, its rival taken over
every layer, and the height found is written beside the answer."""

from __future__ import annotations

import csv
import logging

import numpy as np
import pytest

from placeloc.umap.panorama import PanoramaAnswers, best_over_heights

# the L-shaped room of tests/test_umap_panorama.py: no two places in it look alike
PLAN = {"floor_z": 0.0, "ceiling_z": 2.6, "outline": [[0, 0], [6, 0], [6, 4], [3.5, 4], [3.5, 7], [0, 7]],
        "doors": [{"from": [2, 0], "to": [2.9, 0], "height": 2.0}, {"from": [0, 5], "to": [0, 5.9], "height": 2.0}]}


def _answers(best, xy, heading, score, rival=np.nan, rival_xy=(np.nan, np.nan), rival_heading=np.nan, before=None):
    """One panorama's answer of one layer."""
    return PanoramaAnswers(np.array([best]), np.array([xy], float), np.array([heading], float), np.array([score]),
                           np.array([rival], float), np.array([rival_xy], float), np.array([rival_heading], float),
                           np.array([score if before is None else before]))


def test_best_over_heights_by_hand():
    # Layer 1 (rows from 100) scores highest: its answer wins, its grid row made global. Its
    # own rival scored 0.40; layer 0's answer 3 m away (0.55 before its final search) is a
    # better rival; layer 2's answer is the same place facing 10 deg off (no rival), and
    # its rival lies 0.5 m from the answer, facing the same way (no rival either).
    found = [_answers(7, (4.0, 1.0), 90.0, 0.56, before=0.55),
             _answers(3, (1.0, 1.0), 30.0, 0.60, rival=0.40, rival_xy=(1.0, 5.0), rival_heading=30.0, before=0.59),
             _answers(5, (1.1, 1.0), 40.0, 0.58, rival=0.57, rival_xy=(1.5, 1.0), rival_heading=35.0)]
    got = best_over_heights(found, [0, 100, 200], distance_m=1.0, yaw_deg=30.0)
    assert got.best.tolist() == [103] and got.score.tolist() == [0.60] and got.before_final.tolist() == [0.59]
    assert got.xy.tolist() == [[1.0, 1.0]] and got.heading.tolist() == [30.0]
    assert got.rival.tolist() == [0.55] and got.rival_xy.tolist() == [[4.0, 1.0]] and got.rival_heading.tolist() == [90.0]
    assert got.margin.tolist() == [pytest.approx(0.04)]
    # a turned answer is a rival: layer 2 facing 180 deg from the answer scores 0.58
    found[2] = _answers(5, (1.0, 1.0), 210.0, 0.58)
    got = best_over_heights(found, [0, 100, 200], distance_m=1.0, yaw_deg=30.0)
    assert got.rival.tolist() == [0.58] and got.rival_heading.tolist() == [210.0]
    # a layer that did not search this panorama (height_layers) is never its answer, nor its rival
    from placeloc.umap.panorama import scatter_answers, unsearched

    skipped = scatter_answers(unsearched(2), np.array([1]), _answers(9, (5.0, 5.0), 0.0, 0.9))
    assert skipped.score[0] == -np.inf and np.isnan(skipped.xy[0]).all() and skipped.best[1] == 9
    first = _answers(4, (1.0, 1.0), 0.0, 0.5)
    got = best_over_heights([PanoramaAnswers(*(np.concatenate([a, a]) for a in first)), skipped], [0, 50],
                            distance_m=1.0, yaw_deg=30.0)
    assert got.best.tolist() == [4, 59] and np.isnan(got.rival[0]) and got.rival[1] == 0.5
    # equal scores: the first layer's answer
    got = best_over_heights([_answers(1, (0, 0), 0, 0.5), _answers(2, (3, 3), 0, 0.5)], [0, 10], distance_m=1.0,
                            yaw_deg=30.0)
    assert got.best.tolist() == [1] and got.rival.tolist() == [0.5]


def _photo_run(d, z_camera: float, grid: dict, truth_xy=(1.3, 2.2), heading=75.0, panorama=None):
    """A grey panorama of the L-shaped room's lines seen from ``truth_xy`` at height
    ``z_camera`` and the run config over it with ``grid``."""
    import cv2
    import yaml

    from placeloc.core.config import load_config
    from placeloc.geometry.floorplan import floor_plan_model
    from placeloc.geometry.panorama import render_panoramas
    from placeloc.umap.bits import unpack

    (d / "q").mkdir(parents=True)
    (d / "plan.yaml").write_text(yaml.safe_dump(PLAN))
    m = floor_plan_model(PLAN)
    pose = np.array([[*truth_xy, z_camera, heading]])
    lines = unpack(render_panoramas(m.segments, m.faces, pose, width=512, height=256, hidden=True), 256, 512)[0]
    cv2.imwrite(str(d / "q" / "phone.png"), np.where(cv2.dilate(lines, np.ones((2, 2), np.uint8)) > 0, 60, 190)
                .astype(np.uint8))
    (d / "poses.csv").write_text(f"frame,x,y,heading_deg\nphone.png,{truth_xy[0]},{truth_xy[1]},{heading}\n")
    return load_config(data={"method": "umap", "query": {"images": str(d / "q")},
                             "ground_truth": {"kind": "poses", "path": str(d / "poses.csv")},
                             "umap": {"model": str(d / "plan.yaml"), "query_kind": "panorama",
                                      "grid": {"x": [0.15, 6.0, 0.3], "y": [0.15, 7.0, 0.3], "headings": [0.0], **grid},
                                      "panorama": {"orientation_bins": 1, **(panorama or {})}},
                             "plots": False}, base_dir=d)


def test_a_photo_taken_lower_than_the_grid_is_found_at_its_own_height(tmp_path, caplog):
    # A phone held at 1.1 m where the grid stands at 1.5 m: with the heights 1.1, 1.3 and
    # 1.5 searched, the answer is found in the layer at 1.1 m (estimates.csv's height_m, the
    # log's line), within 0.05 m of the truth and scoring higher than the grid at 1.5 m
    # alone, whose estimates.csv has no height column.
    from placeloc.core.runner import run_stage

    runs = {}
    for name, grid in (("one", {"z": 1.5}), ("three", {"z": 1.5, "heights": [1.1, 1.3, 1.5]})):
        d = tmp_path / name
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="placeloc"):
            run_stage(_photo_run(d, 1.1, grid), d / "run", "localize", quiet=True)
        (runs[name],) = list(csv.DictReader(open(d / "run" / "estimates.csv")))
        said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("camera heights found")]
        assert said == (["camera heights found (umap.grid.heights): 1.10 m for 1 of 1"] if name == "three" else [])
    # searched whole only in the layer whose grid table scores it best: the same answer
    d = tmp_path / "best-layer"
    run_stage(_photo_run(d, 1.1, {"z": 1.5, "heights": [1.1, 1.3, 1.5]}, panorama={"height_layers": 1}), d / "run",
              "localize", quiet=True)
    (best_layer,) = list(csv.DictReader(open(d / "run" / "estimates.csv")))
    keys = ("x", "y", "heading_deg", "height_m", "score")
    assert {k: best_layer[k] for k in keys} == {k: runs["three"][k] for k in keys}
    one, three = runs["one"], runs["three"]
    assert "height_m" not in one and three["height_m"] == "1.10"
    from placeloc.evaluation.report import answer_lines

    assert ", height_m 1.10, doubtful " in answer_lines(tmp_path / "three" / "run")[0]   # what `placeloc run` prints
    assert np.hypot(float(three["x"]) - 1.3, float(three["y"]) - 2.2) <= 0.05, three
    assert float(three["score"]) > float(one["score"]) + 0.05, (one, three)


def test_heights_are_for_panoramas_only(tmp_path):
    from placeloc.core.config import ConfigError, load_config
    from placeloc.core.runner import run_stage

    cfg = _photo_run(tmp_path / "p", 1.1, {"z": 1.5, "heights": [1.1, 1.5]})
    with pytest.raises(ConfigError, match=r"umap.grid.heights searches the camera height of whole panoramas"):
        load_config(data={**cfg, "umap": {**cfg["umap"], "query_kind": "pinhole"}}, base_dir=tmp_path / "p")
    with pytest.raises(ConfigError, match=r"umap.grid.heights lists 1.3 more than once; give each height once"):
        _photo_run(tmp_path / "d", 1.1, {"heights": [1.1, 1.3, 1.3]})
    cfg = _photo_run(tmp_path / "q", 1.1, {"heights": [1.1, 3.0]})
    with pytest.raises(ConfigError, match=r"umap.grid.heights: grid z 3.0 m lies outside the storey"):
        run_stage(cfg, tmp_path / "q" / "run", "build-dictionary", quiet=True)


def test_the_disk_and_memory_a_run_needs_grow_with_the_heights(tmp_path):
    """Three heights: three layers of the database and its spectra to write (index's disk
    three times one height's, but for the per-view counts), while localize holds one
    layer's spectra at a time; the message names the heights and the fix."""
    from placeloc.umap.resources import needs

    one = needs(_photo_run(tmp_path / "a", 1.1, {"z": 1.5}), {}, ["index", "localize"])
    three = needs(_photo_run(tmp_path / "b", 1.1, {"heights": [1.1, 1.3, 1.5]}), {}, ["index", "localize"])
    (i1, l1), (i3, l3) = [[n for n in ns if n.stage in ("index", "localize")] for ns in (one, three)]
    assert i3.disk == pytest.approx(3 * i1.disk, rel=0.01)
    assert l3.memory < 2 * l1.memory
    assert ", 3 layers of heights and ceilings)" in i3.what and "fewer heights or ceilings" in i3.key
