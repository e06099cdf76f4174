"""Known answers for the search over a floor plan's ceiling height (``umap.grid.ceilings``):
each ceiling replaces every room's, the grid is drawn at each, and the home's ceiling is the
one whose layers score the run's panoramas best; every answer comes from its layers."""

from __future__ import annotations

import csv
import logging

import numpy as np
import pytest
import yaml

from placeloc.geometry.floorplan import ModelError, floor_plan_model, load_model, scaled_plan, with_ceiling
from placeloc.geometry.panorama import render_panoramas
from placeloc.umap.bits import unpack
from placeloc.umap.panorama import CeilingChoice, parabola_peak

# the L-shaped room of tests/test_umap_panorama.py, its ceiling drawn at 2.6 m
PLAN = {"floor_z": 0.0, "ceiling_z": 2.6, "outline": [[0, 0], [6, 0], [6, 4], [3.5, 4], [3.5, 7], [0, 7]],
        "doors": [{"from": [2, 0], "to": [2.9, 0], "height": 2.0}, {"from": [0, 5], "to": [0, 5.9], "height": 2.0}]}
ROOMS = {"floor_z": 0.0, "ceiling_z": 2.5,
         "rooms": [{"name": "a", "polygon": [[0, 0], [3, 0], [3, 3], [0, 3]], "ceiling_z": 2.7},
                   {"name": "b", "polygon": [[3, 0], [6, 0], [6, 3], [3, 3]]}],
         "openings": [{"from": [3, 1], "to": [3, 2], "height": 2.0}]}


def test_with_ceiling_replaces_every_rooms_ceiling(tmp_path):
    assert with_ceiling(PLAN, None) is PLAN
    assert with_ceiling(PLAN, 2.9)["ceiling_z"] == 2.9 and PLAN["ceiling_z"] == 2.6   # a copy
    rooms = with_ceiling(ROOMS, 2.4)
    assert rooms["ceiling_z"] == 2.4 and [r.get("ceiling_z") for r in rooms["rooms"]] == [2.4, None]
    # the model's ceiling edges all at the height given, its floor edges where they were
    for plan in (PLAN, ROOMS):
        path = tmp_path / "plan.yaml"
        path.write_text(yaml.safe_dump(plan))
        m = load_model(path, ceiling=2.35)
        tops = np.unique(np.concatenate([m.segments[:, 2], m.segments[:, 5]]))
        assert 2.35 in tops and not np.any(tops > 2.35 + 1e-12)
        assert np.array_equal(m.segments, floor_plan_model(with_ceiling(plan, 2.35)).segments)
        assert not np.array_equal(m.segments, load_model(path).segments)
    wire = tmp_path / "wire.yaml"
    wire.write_text(yaml.safe_dump({"segments": [[0, 0, 0, 1, 0, 0]]}))
    with pytest.raises(ModelError, match="a wireframe has no ceiling height to replace"):
        load_model(wire, ceiling=2.5)
    assert len(load_model(wire).segments) == 1


def test_parabola_peak_by_hand():
    # y = -(x - 2.45)^2 sampled unevenly: the vertex itself
    x = [2.3, 2.4, 2.6]
    assert parabola_peak(x, [-(v - 2.45) ** 2 for v in x]) == pytest.approx(2.45)
    # development home 0's grid means at 2.3 / 2.4 / 2.5 m under a 2.37 m ceiling: 0.3 of a step below 2.4
    assert parabola_peak([2.3, 2.4, 2.5], [0.5424, 0.5472, 0.5280]) == pytest.approx(2.37)
    # a line or a valley: the middle; a peak beyond the outer points is kept between them
    assert parabola_peak([1.0, 2.0, 3.0], [1.0, 1.0, 1.0]) == 2.0
    assert parabola_peak([1.0, 2.0, 3.0], [1.0, 0.5, 1.0]) == 2.0
    assert parabola_peak([1.0, 2.0, 3.0], [0.0, 1.0, 1.0]) == pytest.approx(2.5)
    choice = CeilingChoice(2.3, 2.3, {2.3: 0.5, 2.4: 0.4}, (0, 10))
    assert choice.at_edge and not CeilingChoice(2.4, 2.42, {2.3: 0.4, 2.4: 0.5, 2.5: 0.45}, (10, 20)).at_edge


def _photo_run(d, ceiling_true: float, grid: dict, z_camera: float = 1.5, panorama=None):
    """Two grey panoramas of the L-shaped room's lines under a ceiling at ``ceiling_true``,
    taken at ``z_camera``, and the run config over them with the plan's ceiling at 2.6 m."""
    import cv2

    from placeloc.core.config import load_config
    from placeloc.geometry.panorama import render_panoramas
    from placeloc.umap.bits import unpack

    (d / "q").mkdir(parents=True)
    (d / "plan.yaml").write_text(yaml.safe_dump(PLAN))
    m = floor_plan_model(with_ceiling(PLAN, ceiling_true))
    truth = [("a.png", 1.3, 2.2, 75.0), ("b.png", 4.6, 1.9, 200.0)]
    for name, x, y, heading in truth:
        lines = unpack(render_panoramas(m.segments, m.faces, np.array([[x, y, z_camera, heading]]), width=512, height=256,
                                        hidden=True), 256, 512)[0]
        cv2.imwrite(str(d / "q" / name), np.where(cv2.dilate(lines, np.ones((2, 2), np.uint8)) > 0, 60, 190)
                    .astype(np.uint8))
    (d / "poses.csv").write_text("frame,x,y,heading_deg\n" + "".join(f"{n},{x},{y},{h}\n" for n, x, y, h in truth))
    return load_config(data={"method": "umap", "query": {"images": str(d / "q")},
                             "ground_truth": {"kind": "poses", "path": str(d / "poses.csv")},
                             "umap": {"model": str(d / "plan.yaml"), "query_kind": "panorama",
                                      "grid": {"x": [0.15, 6.0, 0.3], "y": [0.15, 7.0, 0.3], "headings": [0.0],
                                               "z": 1.5, **grid},
                                      "panorama": {"orientation_bins": 1, **(panorama or {})}},
                             "plots": False}, base_dir=d)


def test_a_plan_drawn_with_the_wrong_ceiling_is_searched_at_the_right_one(tmp_path, caplog):
    # The room's ceiling is 2.75 m, the plan says 2.6: with the ceilings 2.5, 2.7 and 2.9
    # searched, the grid table's means peak at 2.7 and the parabola through the three puts
    # the ceiling within 0.05 m of 2.75 (estimates.csv's ceiling_m, the log's line); both
    # answers within 0.1 m, each scoring higher than with the plan's own ceiling, whose
    # estimates.csv has no ceiling column.
    from placeloc.core.runner import run_stage

    runs = {}
    for name, grid in (("plan", {}), ("three", {"ceilings": [2.5, 2.7, 2.9]})):
        d = tmp_path / name
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="placeloc"):
            run_stage(_photo_run(d, 2.75, grid), d / "run", "localize", quiet=True)
        runs[name] = list(csv.DictReader(open(d / "run" / "estimates.csv")))
        said = [r.getMessage() for r in caplog.records if "ceiling" in r.getMessage()]
        if name == "three":
            assert len(said) == 3 and said[0].startswith("ceiling height found (umap.grid.ceilings): "), said
            assert "; the grid's mean best score at each ceiling searched: 2.50 m 0." in said[0]
            # two photos are few to find a ceiling from: the user is told
            assert said[1].startswith("the ceiling height was found from 2 panoramas: with fewer than 10 it is often")
            # and the other reading of a ceiling above the plan's: a plan drawn too large, by
            # (c' - z) / (c - z) - 1 = (2.75 - 1.5) / (2.6 - 1.5) - 1, about 14 %
            c = float(said[0].split(": ")[1].split(" m;")[0])
            assert said[2].startswith(f"the plan draws its ceiling at 2.60 m: either the home's is {c:.2f} m, or the plan "
                                      f"is drawn about {((c - 1.5) / 1.1 - 1) * 100:.0f} % too large (with a camera at "
                                      "1.50 m"), said[2]
        else:
            assert said == []
    truth = {"a.png": (1.3, 2.2), "b.png": (4.6, 1.9)}
    found = {r["ceiling_m"] for r in runs["three"]}
    assert len(found) == 1 and abs(float(found.pop()) - 2.75) <= 0.05, runs["three"]
    for plan, three in zip(runs["plan"], runs["three"]):
        assert "ceiling_m" not in plan
        assert np.hypot(float(three["x"]) - truth[three["frame"]][0], float(three["y"]) - truth[three["frame"]][1]) <= 0.1
        assert float(three["score"]) > float(plan["score"]) + 0.02, (plan, three)
    from placeloc.evaluation.report import answer_lines

    assert f", ceiling_m {runs['three'][0]['ceiling_m']}, " in answer_lines(tmp_path / "three" / "run")[0]
    # placeloc show draws the ceilings' means where several were searched, not otherwise
    from placeloc.umap.pictures import show_extra

    for name, drawn in (("three", True), ("plan", False)):
        pics = show_extra(tmp_path / name / "run", None, tmp_path / name / "run")
        assert any(p.name == "ceiling_scores.png" for p in pics) == drawn
        assert (tmp_path / name / "run" / "ceiling_scores.png").is_file() == drawn
    # the ceiling found at the highest searched: the answers are still drawn there, and a
    # warning says the home's may lie above
    d = tmp_path / "edge"
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="placeloc"):
        run_stage(_photo_run(d, 2.75, {"ceilings": [2.3, 2.5]}), d / "run", "localize", quiet=True)
    assert {r["ceiling_m"] for r in csv.DictReader(open(d / "run" / "estimates.csv"))} == {"2.50"}
    assert any("is the highest of umap.grid.ceilings: the home's may lie beyond them; search higher ceilings too"
               in r.getMessage() for r in caplog.records)
    # with the camera's height searched too (a layer per height and ceiling): both found
    d = tmp_path / "both"
    run_stage(_photo_run(d, 2.3, {"heights": [1.2, 1.5], "ceilings": [2.3, 2.6]}, z_camera=1.2), d / "run", "localize",
              quiet=True)
    both = list(csv.DictReader(open(d / "run" / "estimates.csv")))
    assert [(r["height_m"], r["ceiling_m"]) for r in both] == [("1.20", "2.30")] * 2
    # each panorama searched whole in one layer of the ceiling's (height_layers 1): the same
    d = tmp_path / "one-layer"
    run_stage(_photo_run(d, 2.3, {"heights": [1.2, 1.5], "ceilings": [2.3, 2.6]}, z_camera=1.2,
                         panorama={"height_layers": 1}), d / "run", "localize", quiet=True)
    keys = ("x", "y", "heading_deg", "height_m", "ceiling_m", "score")
    assert [{k: r[k] for k in keys} for r in csv.DictReader(open(d / "run" / "estimates.csv"))] == \
        [{k: r[k] for k in keys} for r in both]


def test_ceilings_are_checked(tmp_path):
    from placeloc.core.config import ConfigError, load_config
    from placeloc.core.runner import run_stage

    cfg = _photo_run(tmp_path / "p", 2.6, {"ceilings": [2.4, 2.6]})
    with pytest.raises(ConfigError, match=r"umap.grid.ceilings searches a floor plan's ceiling height"):
        load_config(data={**cfg, "umap": {**cfg["umap"], "query_kind": "pinhole"}}, base_dir=tmp_path / "p")
    with pytest.raises(ConfigError, match=r"umap.grid.ceilings lists 2.4 more than once"):
        _photo_run(tmp_path / "d", 2.6, {"ceilings": [2.4, 2.6, 2.4]})
    with pytest.raises(ConfigError, match=r"umap.grid.ceilings: -1 is not a height"):
        _photo_run(tmp_path / "n", 2.6, {"ceilings": [-1.0, 2.6]})
    with pytest.raises(ConfigError, match=r"umap.grid.ceilings chooses the home's ceiling by the chamfer score"):
        _photo_run(tmp_path / "i", 2.6, {"ceilings": [2.4, 2.6]}, panorama={"score": "iou"})
    # a ceiling below the camera: named with the ceiling
    cfg = _photo_run(tmp_path / "low", 2.6, {"ceilings": [1.4, 2.6]})
    with pytest.raises(ConfigError, match=r"umap.grid.ceilings: grid z 1.5 m lies outside the storey.*\(ceiling 1.4 m\)"):
        run_stage(cfg, tmp_path / "low" / "run", "build-dictionary", quiet=True)


def test_the_disk_a_run_needs_grows_with_heights_times_ceilings(tmp_path):
    from placeloc.umap.resources import needs

    one = needs(_photo_run(tmp_path / "a", 2.6, {}), {}, ["index"])
    six = needs(_photo_run(tmp_path / "b", 2.6, {"heights": [1.2, 1.5], "ceilings": [2.3, 2.6, 2.9]}), {}, ["index"])
    (i1,), (i6,) = [[n for n in ns if n.stage == "index"] for ns in (one, six)]
    assert i6.disk == pytest.approx(6 * i1.disk, rel=0.01)
    assert ", 6 layers of heights and ceilings)" in i6.what and "fewer heights or ceilings" in i6.key


def test_the_ceiling_picture_marks_the_ceiling_found(tmp_path):
    # three ceilings 2.3 / 2.4 / 2.5 m, found at 2.42: the dashed orange line stands where
    # 2.42 m falls on the x axis (plot box 86-700 px over 2.25-2.55 m: column 434)
    from PIL import Image

    from placeloc.umap.plots import plot_ceiling_scores

    path = plot_ceiling_scores(tmp_path / "c.png", np.array([[2.3, 0.40], [2.4, 0.50], [2.5, 0.45]]), 2.42, 20)
    img = np.asarray(Image.open(path).convert("RGB")).astype(int)
    assert img.shape[:2] == (440, 720)
    orange = np.all(np.abs(img - np.array([255, 127, 14])) <= 40, axis=2)
    column = int(np.argmax(np.bincount(np.nonzero(orange)[1], minlength=img.shape[1])))
    assert abs(column - (86 + (2.42 - 2.25) / 0.30 * 614)) <= 2, column


def test_scaled_plan_scales_positions_not_heights():
    s = 1.25
    for plan in (PLAN, ROOMS):
        big = scaled_plan(plan, s)
        a, b = floor_plan_model(plan), floor_plan_model(big)
        # every segment's x and y times s, its heights as drawn: the same segments in order
        want = a.segments.copy()
        want[:, [0, 1, 3, 4]] *= s
        assert np.allclose(b.segments, want)
        assert np.allclose(b.faces[:, :4], a.faces[:, :4] * s) and np.array_equal(b.faces[:, 4:], a.faces[:, 4:])
        assert scaled_plan(plan, 1.0) == plan and plan == (PLAN if plan is PLAN else ROOMS)   # a copy; the input kept
    assert scaled_plan(ROOMS, 2.0)["openings"][0] == {"from": [6.0, 2.0], "to": [6.0, 4.0], "height": 2.0}


def test_a_plan_scaled_in_height_too_looks_the_same_from_the_scaled_camera():
    # the reason docs/umap.md gives for the ceiling search making up a plan's wrong scale: a
    # world scaled by s in x, y and z, seen from the scaled camera, is the same picture
    s, cam = 1.25, np.array([[2.0, 1.5, 1.5, 30.0], [1.2, 5.5, 1.5, 200.0]])
    small = floor_plan_model(PLAN)
    whole = with_ceiling(scaled_plan(PLAN, s), PLAN["ceiling_z"] * s)
    whole["doors"] = [{**d, "height": d["height"] * s} for d in whole["doors"]]   # the lintels too
    big = floor_plan_model(whole)
    assert np.allclose(big.segments, small.segments * s)
    seen = cam.copy()
    seen[:, :3] *= s
    a = unpack(render_panoramas(small.segments, small.faces, cam, width=256, height=128, hidden=True), 128, 256)
    b = unpack(render_panoramas(big.segments, big.faces, seen, width=256, height=128, hidden=True), 128, 256)
    assert a.sum() > 1000 and np.array_equal(a, b)   # to the pixel (1,790 line pixels)
    # as drawn (heights not scaled) the floor's lines move: not the same picture
    drawn = floor_plan_model(scaled_plan(PLAN, s))
    c = unpack(render_panoramas(drawn.segments, drawn.faces, seen, width=256, height=128, hidden=True), 128, 256)
    assert (a != c).mean() > 0.01                     # 2 % of the pixels differ


def test_scaled_home_scales_the_plan_and_the_truth_and_links_the_photos(tmp_path):
    from placeloc.experiments.umap_scale import scaled_home

    (tmp_path / "panoramas").mkdir()
    (tmp_path / "line_stats.json").write_text("{}")
    (tmp_path / "floor_plan.yaml").write_text(yaml.safe_dump(ROOMS))
    (tmp_path / "poses.csv").write_text("frame,x,y,z,heading_deg\npano_000.png,1.0,2.0,1.5,30.0\n")
    home = scaled_home(tmp_path, 1.1)
    assert home == tmp_path / "scale1.1" and scaled_home(tmp_path, 1.1) == home   # made once
    rows = list(csv.DictReader(open(home / "poses.csv", newline="")))
    assert rows == [{"frame": "pano_000.png", "x": "1.1000", "y": "2.2000", "z": "1.5", "heading_deg": "30.0"}]
    assert yaml.safe_load((home / "floor_plan.yaml").read_text()) == scaled_plan(ROOMS, 1.1)
    assert (home / "panoramas").resolve() == (tmp_path / "panoramas").resolve()


def test_drawn_ceiling_is_the_one_every_room_shares():
    import json
    from types import SimpleNamespace

    from placeloc.umap.artifacts import drawn_ceiling

    def art(plan):
        return SimpleNamespace(attrs={"plan_json": json.dumps(plan)})

    assert drawn_ceiling(art(PLAN)) == 2.6                       # an outline's one ceiling
    assert drawn_ceiling(art(ROOMS)) is None                     # room a at 2.7 m, room b at the plan's 2.5
    assert drawn_ceiling(art(with_ceiling(ROOMS, 2.44))) == 2.44  # every room at the ceiling searched
    assert drawn_ceiling(SimpleNamespace(attrs={})) is None      # a wireframe: no plan kept


def test_the_scale_experiments_table_by_hand():
    from placeloc.experiments.umap_scale import table

    def run(seed, scale, setting, share, err, found=None):
        return {"seed": seed, "scale": scale, "setting": setting, "within_1m_30deg": share, "median_error_m": err,
                "ceiling_found_m": found, "ceiling_derived_m": 1.5 + scale * 1.0}

    runs = {"a": run(21, 1.1, "as drawn", 0.95, 0.056), "b": run(20, 1.1, "as drawn", 1.0, 0.040),
            "c": run(20, 1.1, "ceilings 2.3-3.0 searched", 1.0, 0.020, 2.61),
            "d": run(21, 1.1, "ceilings 2.3-3.0 searched", 1.0, 0.030, 2.59)}
    lines = table(runs)
    assert lines[2] == "| plan's scale | plan | home 20 | home 21 | all | median error, range over the homes |"
    assert lines[4] == "| 1.1 | as drawn | 100% | 95% | 97.5% | 0.040-0.056 m |"
    assert lines[5] == "| 1.1 | ceilings 2.3-3.0 searched | 100% | 100% | 100.0% | 0.020-0.030 m |"
    assert lines[-1].endswith("scale 1.1: 2.61 (2.60), 2.59 (2.60).")   # the homes in order, each beside z + s (c - z)
