"""The ZInD importer on a small zind_data.json written by hand from the published format
(two rooms sharing a wall with a door, one window, a secondary panorama), every expected
coordinate computed by hand."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from placeloc.geometry.floorplan import ModelError, floor_plan_model
from placeloc.geometry.zind import import_zind, zind_home

SQUARE = [[-1, -1], [1, -1], [1, 1], [-1, 1]]


def _pano(tr, primary=True, layout=None, name="p.jpg"):
    d = {"label": "room", "is_primary": primary, "is_inside": True, "is_ceiling_flat": True, "ceiling_height": 2.0,
         "camera_height": 1.0, "floor_number": 1, "image_path": f"panos/{name}", "floor_plan_transformation": tr}
    if layout is not None:
        d["layout_complete"] = layout
    return d


def _write(tmp_path, scale=0.5):
    room1 = {"vertices": SQUARE, "doors": [[1, -0.5], [1, 0.5], [-1, 1 / 3]], "openings": [], "internal": [],
             "windows": [[-1, -0.5], [-1, 0.5], [-0.4, 0.4]]}
    room2 = {"vertices": SQUARE, "doors": [], "openings": [], "windows": [], "internal": []}
    data = {"scale_meters_per_coordinate": {"floor_01": scale},
            "merger": {"floor_01": {
                "complete_room_01": {"partial_room_01": {"pano_01": _pano({"translation": [4, 2], "rotation": 0, "scale": 3},
                                                                          layout=room1, name="a.jpg")}},
                "complete_room_02": {"partial_room_02": {
                    "pano_02": _pano({"translation": [10, 2], "rotation": 90, "scale": 3}, layout=room2, name="b.jpg"),
                    "pano_03": _pano({"translation": [9, 3], "rotation": 45, "scale": 3}, primary=False, name="c.jpg")}}}},
            "redraw": {}, "floorplan_to_redraw_transformation": {}}
    p = tmp_path / "zind_data.json"
    p.write_text(json.dumps(data))
    return p


def test_rooms_doors_windows_and_poses_in_metres(tmp_path):
    plan, panos = zind_home(_write(tmp_path))
    # room 1: local square * 3 + (4, 2) -> x 1..7, y -1..5; * 0.5 m, y flipped -> x 0.5..3.5, y -2.5..0.5
    r1 = np.array(plan["rooms"][0]["polygon"])
    assert r1.min(0) == pytest.approx([0.5, -2.5]) and r1.max(0) == pytest.approx([3.5, 0.5])
    assert plan["rooms"][0]["ceiling_z"] == pytest.approx(3.0)          # 2 camera heights of 1.5 m
    # room 2: centred on (10, 2) -> (5, -1) m, rotation keeps the square: x 3.5..6.5, y -2.5..0.5
    r2 = np.array(plan["rooms"][1]["polygon"])
    assert r2.min(0) == pytest.approx([3.5, -2.5]) and r2.max(0) == pytest.approx([6.5, 0.5])
    door = plan["doors"][0]
    assert np.array([door["from"], door["to"]]) == pytest.approx(np.array([[3.5, -0.25], [3.5, -1.75]]))
    assert door["height"] == pytest.approx(2.0)                         # (1/3 + 1) * 1.5 m
    win = plan["windows"][0]
    assert (win["sill"], win["top"]) == pytest.approx((0.9, 2.1))
    by = {p["frame"]: p for p in panos}
    assert (by["a.jpg"]["x"], by["a.jpg"]["y"], by["a.jpg"]["z"]) == pytest.approx((2.0, -1.0, 1.5))
    assert by["a.jpg"]["heading_deg"] == pytest.approx(270.0)
    assert by["b.jpg"]["heading_deg"] == pytest.approx(180.0)          # its centre column looks along -x
    assert (by["c.jpg"]["x"], by["c.jpg"]["y"], by["c.jpg"]["heading_deg"]) == pytest.approx((4.5, -1.5, 225.0))
    assert not by["c.jpg"]["primary"]
    # the door is a real gap in the shared wall of the model built from the plan
    m = floor_plan_model(plan)
    on_wall = m.segments[(np.abs(m.segments[:, 0] - 3.5) < 1e-6) & (np.abs(m.segments[:, 3] - 3.5) < 1e-6)
                         & (m.segments[:, 2] == 0) & (m.segments[:, 5] == 0)]
    assert len(on_wall) and not any(min(s[1], s[4]) < -1.0 < max(s[1], s[4]) for s in on_wall)


def test_import_writes_plan_and_poses(tmp_path):
    summary = import_zind(_write(tmp_path), tmp_path / "out")
    assert summary == {"floor": "floor_01", "out": str(tmp_path / "out"), "rooms": 2, "internal walls": 0, "doors": 1,
                       "openings": 0, "windows": 1, "panoramas": 3, "primary": 2, "camera_z": 1.5}
    rows = list(csv.DictReader(open(tmp_path / "out" / "poses.csv")))
    assert [r["frame"] for r in rows] == ["a.jpg", "b.jpg", "c.jpg"]
    assert [r["primary"] for r in rows] == ["1", "1", "0"]
    # each panorama's room, as the plan names it: a umap.room_hints file (c.jpg, a secondary
    # panorama, in its complete room's)
    rooms = list(csv.DictReader(open(tmp_path / "out" / "rooms.csv")))
    assert [(r["frame"], r["room"]) for r in rooms] == [("a.jpg", "complete_room_01 (room)"),
                                                       ("b.jpg", "complete_room_02 (room)"),
                                                       ("c.jpg", "complete_room_02 (room)")]
    assert floor_plan_model(__import__("yaml").safe_load((tmp_path / "out" / "floor_plan.yaml").read_text())).rooms


def test_uncalibrated_floor_is_refused(tmp_path):
    p = _write(tmp_path)
    data = json.loads(p.read_text())
    data["scale_meters_per_coordinate"]["floor_01"] = None
    p.write_text(json.dumps(data))
    with pytest.raises(ModelError, match="no floor has a scale_meters_per_coordinate"):
        zind_home(p)


def test_a_zind_home_searched_over_ceilings_round_trips_through_json(tmp_path):
    # umap.grid.ceilings keeps the plan as JSON in build-dictionary.h5 and localize draws it
    # again at the ceiling found: a ZInD home's plan must come back the same model
    from placeloc.geometry.floorplan import load_model, load_plan, with_ceiling

    path = _write(tmp_path)
    plan = load_plan(path)
    back = json.loads(json.dumps(plan, default=str))
    assert back == plan
    a = floor_plan_model(with_ceiling(back, 2.7), str(path))
    b = load_model(path, ceiling=2.7)
    assert np.array_equal(a.segments, b.segments) and np.array_equal(a.faces, b.faces)
    # both rooms' ceilings (3.0 m as imported) are at 2.7 m now, the floor where it was
    assert np.max(b.segments[:, [2, 5]]) == pytest.approx(2.7) and np.min(b.segments[:, [2, 5]]) == 0.0
