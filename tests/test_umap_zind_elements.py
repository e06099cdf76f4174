"""The ZInD importer element by element, on a two-floor ``zind_data.json`` written from the
published format (zillow/zind data_organization.md: merger -> floor -> complete room ->
partial room -> pano with layout_complete {vertices, doors, openings, windows, internal},
floor_plan_transformation, camera_height, ceiling_height, is_primary). Every expected value
is computed by hand in the comments."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import yaml

from placeloc.geometry.floorplan import ModelError, floor_plan_model, load_model
from placeloc.geometry.zind import import_zind, zind_home

# local units: camera height 1.0; transformation scale 2, floor scale 0.75 m per coordinate
# -> 1.5 m per local unit. Identity rotation, so world = (local * 2 + t) * 0.75 with y flipped.
TR = {"translation": [0.0, 0.0], "rotation": 0.0, "scale": 2.0}


def _pano(layout=None, primary=True, name="p.jpg", tr=TR, cam=1.0, ceil=1.8):
    d = {"label": "kitchen", "is_primary": primary, "is_inside": True, "is_ceiling_flat": True, "ceiling_height": ceil,
         "camera_height": cam, "floor_number": 1, "image_path": f"panos/{name}", "floor_plan_transformation": tr}
    if layout is not None:
        d["layout_complete"] = layout
        d["layout_raw"] = {**layout, "internal": []}
    return d


KITCHEN = {"vertices": [[-2, -2], [2, -2], [2, 2], [-2, 2]],
           "doors": [[2, -1], [2, -0.5], [-1, 0.4]],                 # top 0.4 above the camera -> 1.4 * 1.5 = 2.1 m
           "openings": [[-1, 2], [1, 2], [-1, 0.8]],                 # top 0.8 -> 2.7 m (the ceiling)
           "windows": [[-2, -1], [-2, 1], [-0.4, 0.4]],             # sill 0.6 * 1.5 = 0.9 m, top 1.4 * 1.5 = 2.1 m
           "internal": [[[0, 0], [1, 0], [1, 0.2], [0, 0.2]]]}      # a kitchen wall block


def _file(tmp_path, second_floor=True):
    floors = {"floor_01": {"complete_room_01": {
        "partial_room_01": {"pano_01": _pano(KITCHEN, name="k1.jpg"),
                            "pano_02": _pano(primary=False, name="k2.jpg",
                                             tr={"translation": [1.0, 1.0], "rotation": 0.0, "scale": 2.0}, cam=1.0)}}}}
    scales = {"floor_01": 0.75}
    if second_floor:
        floors["floor_02"] = {"complete_room_01": {"partial_room_01": {"pano_01": _pano(
            {"vertices": [[-1, -1], [1, -1], [1, 1], [-1, 1]], "doors": [], "openings": [], "windows": [], "internal": []},
            name="up.jpg", cam=1.0, ceil=1.6)}}}
        scales["floor_02"] = 0.5
    p = tmp_path / "zind_data.json"
    p.write_text(json.dumps({"scale_meters_per_coordinate": scales, "merger": floors, "redraw": {},
                             "floorplan_to_redraw_transformation": {}}))
    return p


def test_room_outline_and_heights(tmp_path):
    plan, _ = zind_home(_file(tmp_path), "floor_01")
    r = np.array(plan["rooms"][0]["polygon"])
    # x: -2..2 local * 1.5 -> -3..3; y flipped -> -3..3
    assert r.min(0) == pytest.approx([-3, -3]) and r.max(0) == pytest.approx([3, 3])
    assert plan["rooms"][0]["ceiling_z"] == pytest.approx(2.7)   # 1.8 * 1.5
    assert plan["camera_z"] == pytest.approx(1.5)                # 1.0 * 1.5, the median of the panoramas


def test_internal_walls(tmp_path):
    plan, _ = zind_home(_file(tmp_path), "floor_01")
    (block,) = plan["rooms"][0]["internal"]
    b = np.array(block)   # x 0..1 -> 0..1.5, y 0..0.2 -> 0..-0.3
    assert b.min(0) == pytest.approx([0, -0.3]) and b.max(0) == pytest.approx([1.5, 0])
    m = floor_plan_model(plan)
    # it is in the map as four full-height wall faces, and its inside is not free space
    assert ((m.faces[:, 4] == 0) & np.isclose(m.faces[:, 5], 2.7)
            & (np.abs(m.faces[:, [0, 2]]).max(1) <= 1.5) & (m.faces[:, [1, 3]].min(1) >= -0.3)).sum() == 4
    assert not m.inside(np.array([[0.75, -0.15]]))[0] and m.inside(np.array([[0.75, -1.0]]))[0]


def test_doors_openings_and_windows_are_kept_apart(tmp_path):
    plan, _ = zind_home(_file(tmp_path), "floor_01")
    (door,), (opening,), (window,) = plan["doors"], plan["openings"], plan["windows"]
    assert np.array([door["from"], door["to"]]) == pytest.approx(np.array([[3, 1.5], [3, 0.75]]))
    assert door["height"] == pytest.approx(2.1)
    assert np.array([opening["from"], opening["to"]]) == pytest.approx(np.array([[-1.5, -3], [1.5, -3]]))
    assert opening["height"] == pytest.approx(2.7)
    assert (window["sill"], window["top"]) == pytest.approx((0.9, 2.1))
    m = floor_plan_model(plan)
    # the door cuts the wall at x = 3 between y 0.75 and 1.5 and leaves a lintel face from 2.1 m up;
    # the ceiling-high opening leaves none
    lintels = m.faces[(m.faces[:, 4] > 0)]
    assert len(lintels) == 1 and lintels[0, 4] == pytest.approx(2.1) and lintels[0, 0] == pytest.approx(3)
    # the window is a frame: the wall face behind it stays whole
    assert (np.isclose(m.faces[:, 0], -3) & np.isclose(m.faces[:, 2], -3) & (m.faces[:, 4] == 0)
            & np.isclose(np.abs(m.faces[:, 1] - m.faces[:, 3]), 6)).any()


def test_primary_and_secondary_panoramas(tmp_path):
    _, panos = zind_home(_file(tmp_path), "floor_01")
    by = {p["frame"]: p for p in panos}
    assert by["k1.jpg"]["primary"] and not by["k2.jpg"]["primary"]
    # the secondary one: local origin -> (0 * 2 + 1) * 0.75 = 0.75, y (0 * 2 + 1) * 0.75 flipped -> -0.75
    assert (by["k2.jpg"]["x"], by["k2.jpg"]["y"], by["k2.jpg"]["z"]) == pytest.approx((0.75, -0.75, 1.5))


def test_every_floor_and_floor_selects(tmp_path):
    p = _file(tmp_path)
    with pytest.raises(ModelError, match=r"2 floors \(floor_01, floor_02\); choose one with floor:"):
        zind_home(p)
    with pytest.raises(ModelError, match=r"no floor 'floor_09'; the file has floor_01, floor_02"):
        zind_home(p, "floor_09")
    up, panos = zind_home(p, "floor_02")
    assert [q["frame"] for q in panos] == ["up.jpg"] and up["rooms"][0]["ceiling_z"] == pytest.approx(1.6)  # 1.6 * 2 * 0.5
    # import without a floor: every floor into a folder of its own
    summary = import_zind(p, tmp_path / "out")
    assert set(summary) == {"floor_01", "floor_02"}
    assert summary["floor_01"]["internal walls"] == 1 and summary["floor_01"]["panoramas"] == 2
    rows = list(csv.DictReader(open(tmp_path / "out" / "floor_02" / "poses.csv")))
    assert [r["frame"] for r in rows] == ["up.jpg"]
    # the model loader reads zind_data.json directly, the floor chosen
    m = load_model(p, "floor_02")
    assert m.camera_z == pytest.approx(1.0) and len(m.polygons) == 1
    with pytest.raises(ModelError, match="choose one with floor:"):
        load_model(p)


def test_command_line_import(tmp_path):
    from typer.testing import CliRunner

    from placeloc.cli import app

    p = _file(tmp_path)
    res = CliRunner().invoke(app, ["import", "zind", str(p), str(tmp_path / "cli"), "--floor", "floor_01"])
    assert res.exit_code == 0, res.output
    assert "internal walls: 1" in res.output and "panoramas: 2" in res.output
    plan = yaml.safe_load((tmp_path / "cli" / "floor_plan.yaml").read_text())
    assert plan["camera_z"] == pytest.approx(1.5) and len(plan["doors"]) == 1 and len(plan["openings"]) == 1
    res = CliRunner().invoke(app, ["import", "zind", str(tmp_path / "missing.json"), str(tmp_path / "x")])
    assert res.exit_code != 0 and "missing.json" in res.output


def test_a_generated_home_in_zind_format_localizes_with_the_defaults(tmp_path):
    # A generated home written as zind_data.json; the config names only the method, the
    # images, the model, the query kind and the ground truth: the grid (bounds, doorways,
    # z = the camera height) and the score are the defaults.
    from placeloc.core.config import load_config
    from placeloc.core.runner import read_metrics, run_all
    from placeloc.synth import generate

    generate("home", tmp_path / "home", seed=5, panoramas=4, width=512)
    import_zind(tmp_path / "home" / "zind_data.json", tmp_path / "imported")
    cfg = load_config(data={"method": "umap", "query": {"images": str(tmp_path / "home" / "panoramas")},
                            "umap": {"model": str(tmp_path / "home" / "zind_data.json"), "query_kind": "panorama"},
                            "ground_truth": {"kind": "poses", "path": str(tmp_path / "imported" / "poses.csv")},
                            "plots": False},
                      base_dir=tmp_path)
    run_all(cfg, tmp_path / "run", quiet=True)
    m = read_metrics(tmp_path / "run")
    assert m["within_1m_30deg"] >= 0.75, m
