"""Known answers for the room each photo was taken in (``umap.room_hints``): the hint file read
and checked, the rooms a hint names, the region a photo may stand in, and twin rooms, where
lines alone cannot choose, searched in the room named."""

from __future__ import annotations

import csv
import logging

import numpy as np
import pytest
import yaml

from placeloc.core.errors import ConfigError
from placeloc.umap.room_hints import RoomRegion, matching_rooms, read_room_hints, room_label

# two rooms alike to the centimetre, side by side with a wall between, each with its door
# at the same place in its south wall: every view in one is a view in the other, 3.2 m east
TWINS = {"floor_z": 0.0, "ceiling_z": 2.5,
         "rooms": [{"name": "room_1 (bedroom)", "polygon": [[0, 0], [3, 0], [3, 2.5], [0, 2.5]]},
                   {"name": "room_2 (bedroom)", "polygon": [[3.2, 0], [6.2, 0], [6.2, 2.5], [3.2, 2.5]]},
                   {"name": "closet", "polygon": [[0, 2.5], [1.2, 2.5], [1.2, 3.5], [0, 3.5]]}],
         "doors": [{"from": [0.6, 0], "to": [1.5, 0], "height": 2.0}, {"from": [3.8, 0], "to": [4.7, 0], "height": 2.0}]}
NAMES = [r["name"] for r in TWINS["rooms"]]


def test_a_hint_names_a_room_by_its_name_or_its_label():
    assert room_label("complete_room_3 (kitchen)") == "kitchen" and room_label("hall") == "hall"
    assert matching_rooms("room_2 (bedroom)", NAMES) == [1]
    assert matching_rooms(" Bedroom ", NAMES) == [0, 1]       # every room labelled so, any case
    assert matching_rooms("CLOSET", NAMES) == [2]
    assert matching_rooms("kitchen", NAMES) == [] and matching_rooms("room_2", NAMES) == []


def test_the_region_is_the_rooms_and_a_margin_around_them():
    region = RoomRegion([np.array(TWINS["rooms"][0]["polygon"], float)], margin_m=0.3)
    pts = np.array([[1.5, 1.2],     # inside
                    [1.0, -0.2],    # 0.2 m out through its door: a camera in the doorway
                    [3.1, 1.0],     # in the wall between the twins, 0.1 m out
                    [3.35, 1.0],    # in the twin, 0.35 m from the outline
                    [4.6, 1.2]])    # the twin's middle
    assert region(pts).tolist() == [True, True, True, False, False]
    assert RoomRegion([np.array(TWINS["rooms"][0]["polygon"], float)], margin_m=0.0)(pts).tolist() == \
        [True, False, False, False, False]
    both = RoomRegion([np.array(r["polygon"], float) for r in TWINS["rooms"][:2]], margin_m=0.0)
    assert both(pts).tolist() == [True, False, False, True, True]


def test_the_hint_file_is_read_and_checked(tmp_path):
    f = tmp_path / "rooms.csv"
    f.write_text("\ufeffframe, room\na.png,bedroom\nb.png,\nc.png,closet\nz.png,closet\n")
    hints, stray = read_room_hints(f, ["a.png", "b.png", "c.png", "d.png"], NAMES)
    assert hints == ["bedroom", None, "closet", None] and stray == ["z.png"]
    # a frame given with its folder names the query frame of its file name (frames are file
    # names); one given both ways keeps the plain name's row
    f.write_text("frame,room\nphotos/a.png,closet\n./b.png,bedroom\nc.png,closet\nold/c.png,bedroom\n")
    hints, stray = read_room_hints(f, ["a.png", "b.png", "c.png"], NAMES)
    assert hints == ["closet", "bedroom", "closet"] and stray == ["old/c.png"]
    for text, match in (("frame,where\na.png,closet\n", r"rooms.csv: umap.room_hints needs a CSV with the columns frame, room"),
                        ("frame,room\na.png,kitchen\n", r"rooms.csv:2: 'kitchen' names none of the plan's rooms "
                                                        r"\(room_1 \(bedroom\), room_2 \(bedroom\), closet\)"),
                        ("frame,room\na.png,closet\na.png,bedroom\n", r"rooms.csv:3: a.png is given twice"),
                        ("frame,room\n,closet\n", r"rooms.csv:2: a row with no frame")):
        f.write_text(text)
        with pytest.raises(ConfigError, match=match):
            read_room_hints(f, ["a.png"], NAMES)
    with pytest.raises(ConfigError, match=r"the model names no rooms"):
        read_room_hints(f, ["a.png"], [])
    with pytest.raises(ConfigError, match=r"umap.room_hints: cannot read .*missing.csv"):
        read_room_hints(tmp_path / "missing.csv", ["a.png"], NAMES)


def _twins_run(d, hints: str | None, panorama=None):
    """Two grey panoramas taken in the west twin, and the run config over them (with the
    hint file ``hints`` where given)."""
    import cv2

    from placeloc.core.config import load_config
    from placeloc.geometry.floorplan import floor_plan_model
    from placeloc.geometry.panorama import render_panoramas
    from placeloc.umap.bits import unpack

    (d / "q").mkdir(parents=True)
    (d / "plan.yaml").write_text(yaml.safe_dump(TWINS))
    m = floor_plan_model(TWINS)
    truth = [("a.png", 1.13, 1.61, 75.0), ("b.png", 2.21, 0.74, 200.0)]
    for name, x, y, heading in truth:
        lines = unpack(render_panoramas(m.segments, m.faces, np.array([[x, y, 1.5, heading]]), width=512, height=256,
                                        hidden=True), 256, 512)[0]
        cv2.imwrite(str(d / "q" / name), np.where(cv2.dilate(lines, np.ones((2, 2), np.uint8)) > 0, 60, 190)
                    .astype(np.uint8))
    (d / "poses.csv").write_text("frame,x,y,heading_deg\n" + "".join(f"{n},{x},{y},{h}\n" for n, x, y, h in truth))
    extra = {}
    if hints is not None:
        (d / "rooms.csv").write_text(hints)
        extra = {"room_hints": "rooms.csv"}
    return load_config(data={"method": "umap", "query": {"images": str(d / "q")},
                             "ground_truth": {"kind": "poses", "path": str(d / "poses.csv")},
                             "umap": {"model": str(d / "plan.yaml"), "query_kind": "panorama",
                                      "grid": {"x": [0.15, 6.2, 0.3], "y": [0.15, 3.5, 0.3], "headings": [0.0], "z": 1.5},
                                      "panorama": {"orientation_bins": 1, **(panorama or {})}, **extra},
                             "plots": False}, base_dir=d)


def test_twin_rooms_are_told_apart_by_the_room_named(tmp_path, caplog):
    # Without hints each photo's rival is its twin spot 3.2 m east (scored a few hundredths
    # lower only for want of the answer's refinement). With the west twin named (by its full
    # name, in any case) each answer lies within 0.1 m and 3 deg of the truth, its rival in
    # that room and further behind; with the east twin named, at the twin spot within 0.1 m of
    # (x + 3.2, y), at the same heading. A photo left unnamed gets the plain search's answer.
    from placeloc.core.runner import run_stage

    def answers(name, hints):
        d = tmp_path / name
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="placeloc"):
            run_stage(_twins_run(d, hints), d / "run", "localize", quiet=True)
        return list(csv.DictReader(open(d / "run" / "estimates.csv"))), [r.getMessage() for r in caplog.records]

    truth = {"a.png": (1.13, 1.61, 75.0), "b.png": (2.21, 0.74, 200.0)}

    def near(row, dx=0.0):
        x, y, h = truth[row["frame"]]
        turned = abs((float(row["heading_deg"]) - h + 180.0) % 360.0 - 180.0)
        return np.hypot(float(row["x"]) - x - dx, float(row["y"]) - y) <= 0.1 and turned <= 3.0

    def rival_near(row, dx):
        x, y, _ = truth[row["frame"]]
        return np.hypot(float(row["rival_x"]) - x - dx, float(row["rival_y"]) - y) <= 0.1

    free, _ = answers("free", None)
    assert "room_named" not in free[0] and "room_hint_gap" not in free[0]   # no names, no columns
    for row in free:   # the west spot, its rival the east twin's (unrefined, so a few hundredths lower)
        assert near(row) and rival_near(row, 3.2) and row["rival_room"] == "room_2 (bedroom)", row
    west, said = answers("west", "frame,room\na.png,room_1 (bedroom)\nb.png,Room_1 (Bedroom)\n")
    assert "umap.room_hints: 2 of 2 panoramas searched in the room named for them" in said
    east, _ = answers("east", "frame,room\na.png,room_2 (bedroom)\nb.png,room_2 (bedroom)\n")
    for w, e, f in zip(west, east, free):
        assert near(w) and near(e, 3.2), (w, e)
        assert w["room"] == "room_1 (bedroom)" and e["room"] == "room_2 (bedroom)"
        # no twin left to rival it: the rival, if any, is in the room named, and further behind
        assert w["rival_room"] in ("", "room_1 (bedroom)") and e["rival_room"] in ("", "room_2 (bedroom)"), (w, e)
        assert w["margin"] == "" or float(w["margin"]) > float(f["margin"]), (w, f)
    # with the ceiling and the camera height searched too (each panorama searched whole in its
    # best layer only): the ceiling and the layers are chosen over the named room, the same answers
    d = tmp_path / "layers"
    cfg = _twins_run(d, "frame,room\na.png,room_2 (bedroom)\nb.png,room_2 (bedroom)\n", panorama={"height_layers": 1})
    cfg["umap"]["grid"].update(ceilings=[2.3, 2.5], heights=[1.3, 1.5])
    run_stage(cfg, d / "run", "localize", quiet=True)
    for row in csv.DictReader(open(d / "run" / "estimates.csv")):
        assert near(row, 3.2) and (row["ceiling_m"], row["height_m"]) == ("2.50", "1.50"), row
    # one photo named, the other left to the whole plan (an empty room)
    mixed, said = answers("mixed", "frame,room\na.png,room_2 (bedroom)\nb.png,\n")
    assert "umap.room_hints: 1 of 2 panoramas searched in the room named for them" in said
    assert near(mixed[0], 3.2) and (near(mixed[1]) or near(mixed[1], 3.2))
    assert {k: mixed[1][k] for k in ("x", "y", "heading_deg", "score")} == \
        {k: free[1][k] for k in ("x", "y", "heading_deg", "score")}


def test_room_hints_are_checked(tmp_path):
    from placeloc.core.config import load_config
    from placeloc.core.runner import run_stage

    cfg = _twins_run(tmp_path / "p", "frame,room\na.png,closet\n")
    with pytest.raises(ConfigError, match=r"umap.room_hints keeps whole panoramas' search to a room"):
        load_config(data={**cfg, "umap": {**cfg["umap"], "query_kind": "pinhole"}}, base_dir=tmp_path / "p")
    with pytest.raises(ConfigError, match=r"umap.room_hints: .*nothere.csv does not exist"):
        load_config(data={**cfg, "umap": {**cfg["umap"], "room_hints": "nothere.csv"}}, base_dir=tmp_path / "p")
    # a room the plan does not have: told when the config is read, before any stage runs
    (tmp_path / "p" / "typo.csv").write_text("frame,room\na.png,closset\n")
    with pytest.raises(ConfigError, match=r"typo.csv:2: 'closset' names none of the plan's rooms"):
        load_config(data={**cfg, "umap": {**cfg["umap"], "room_hints": "typo.csv"}}, base_dir=tmp_path / "p")
    # a room the grid lays no position in: said, with the fix
    d = tmp_path / "small"
    cfg = _twins_run(d, "frame,room\na.png,closet\n")
    cfg["umap"]["grid"]["x"] = [3.5, 6.0, 0.3]   # the east twin's grid only
    with pytest.raises(Exception, match=r"umap.room_hints: no grid position lies in 'closet'"):
        run_stage(cfg, d / "run", "localize", quiet=True)
    # the hint file is an input of localize alone: editing it re-runs localize, and the
    # stages before it (the map and its index) are kept as they were
    d = tmp_path / "edit"
    cfg = _twins_run(d, "frame,room\na.png,room_1 (bedroom)\n")
    run_stage(cfg, d / "run", "localize", quiet=True)
    first = (d / "run" / "estimates.csv").read_text()
    before = {s: (d / "run" / f"{s}.h5").stat().st_mtime_ns for s in ("extract", "build-dictionary", "index")}
    (d / "rooms.csv").write_text("frame,room\na.png,room_2 (bedroom)\n")
    run_stage(cfg, d / "run", "localize", quiet=True)
    assert (d / "run" / "estimates.csv").read_text() != first
    assert {s: (d / "run" / f"{s}.h5").stat().st_mtime_ns for s in before} == before


def test_the_grid_tables_that_choose_layers_and_ceilings_count_a_named_photos_room_only():
    # grid_table_best with each photo's positions kept (region_masks) is its best over those
    # positions alone: the same number as the table over only those grid rows; a photo with
    # no region keeps every row; a region that keeps none gives -inf
    from dataclasses import replace

    from test_umap_panorama import PLAN, H, _render_all

    from placeloc.geometry.floorplan import floor_plan_model, plan_grid
    from placeloc.umap.panorama import chamfer_spectra, grid_table_best, region_masks, row_weights
    from placeloc.umap.params import PanoramaParams

    m = floor_plan_model(PLAN)
    pp = replace(PanoramaParams(), orientation_bins=1)
    wts = row_weights(H, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
    poses, _ = plan_grid(m, x=[0.2, 6.0, 0.4], y=[0.2, 7.0, 0.4], z=1.4, headings=[0.0])
    spectra = chamfer_spectra(_render_all(m, poses), tau_px=pp.chamfer_tau_px, weights=wts)
    q = _render_all(m, [[1.3, 1.1, 1.4, 30.0], [2.0, 5.5, 1.4, 100.0], [4.0, 2.0, 1.4, 0.0]])
    south = RoomRegion([np.array([[0, 0], [6, 0], [6, 4], [0, 4]], float)], margin_m=0.0)   # the L's south arm
    nowhere = RoomRegion([np.array([[10, 10], [11, 10], [11, 11]], float)], margin_m=0.0)
    keep = region_masks([south, None, nowhere], poses)
    assert keep.shape == (3, len(poses)) and keep[1].all() and not keep[2].any()
    assert 0 < keep[0].sum() < len(poses)
    assert region_masks(None, poses) is None and region_masks([None, None], poses) is None
    best = grid_table_best(q, spectra, pp, keep=keep)
    whole = grid_table_best(q, spectra, pp)
    alone = grid_table_best(q[:1], spectra[:, keep[0]], pp)
    assert best[0] == alone[0] and best[1] == whole[1] and best[2] == -np.inf
    # the second photo stands in the north arm: its best over the south arm alone is lower
    assert grid_table_best(q[1:2], spectra[:, keep[0]], pp)[0] < whole[1]


def test_a_photo_named_for_the_wrong_room_is_flagged(tmp_path, caplog):
    # b.png stands in the middle of the west twin's south half; named "closet" (the small room
    # north of the west twin), its answer in or by the closet scores far below its true place:
    # warned, naming the room where the better place lies, its gap in localize.h5. a.png, named
    # right, is not (its answer, refined in its room, beats every grid place outside it)
    import h5py

    from placeloc.core.runner import run_stage

    d = tmp_path / "w"
    cfg = _twins_run(d, "frame,room\na.png,room_1 (bedroom)\nb.png,closet\n")
    with caplog.at_level(logging.WARNING, logger="placeloc"):
        run_stage(cfg, d / "run", "localize", quiet=True)
    with h5py.File(d / "run" / "localize.h5", "r") as f:
        gap = f["room_hint_gap"][()]
    assert gap[0] < 0.0 and gap[1] > 0.3, gap
    said = [r.getMessage() for r in caplog.records if "umap.room_hint_check" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("1 of 2 photos named for a room score far better elsewhere"), said
    assert "b.png named 'closet' scores 0.4" in said[0] and "in 'room_1 (bedroom)'" in said[0], said
    assert "a.png" not in said[0]
    # estimates.csv: each photo's room as named and its gap, beside its answer
    rows = list(csv.DictReader(open(d / "run" / "estimates.csv")))
    assert [r["room_named"] for r in rows] == ["room_1 (bedroom)", "closet"]
    assert [float(r["room_hint_gap"]) for r in rows] == pytest.approx(gap, abs=1e-4)
