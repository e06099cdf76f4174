"""``placeloc plan``: what a floor plan holds, by hand-computed areas and counts, the grid
localize would search, and the map's lines from a point at the azimuths geometry gives."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml
from PIL import Image
from test_umap_panorama import PLAN
from typer.testing import CliRunner

from placeloc.cli import app
from placeloc.geometry.floorplan import floor_plan_model, plan_grid
from placeloc.umap.plan_report import photo_at, polygon_area, summarise, view_lines

ROOMS = {"floor_z": 0.0, "ceiling_z": 2.6, "camera_z": 1.5,
         "rooms": [{"name": "kitchen", "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]], "ceiling_z": 2.4,
                    "internal": [[[1, 2.5], [2, 2.5], [2, 2.7], [1, 2.7]]]},
                   {"name": "hall", "polygon": [[4.1, 0], [8, 0], [8, 3], [4.1, 3]]}],
         "doors": [{"from": [4, 1], "to": [4, 2], "height": 2.0}, {"from": [4.1, 1], "to": [4.1, 2], "height": 2.0}],
         "openings": [{"from": [8, 0.5], "to": [8, 2.5], "height": 2.6}],
         "windows": [{"from": [0, 0.5], "to": [0, 2.5], "sill": 0.9, "top": 2.1}]}


def test_polygon_area_by_hand():
    assert polygon_area([[0, 0], [4, 0], [4, 3], [0, 3]]) == 12.0
    assert polygon_area([[0, 3], [4, 3], [4, 0], [0, 0]]) == 12.0          # either way round
    assert polygon_area(PLAN["outline"]) == pytest.approx(6 * 4 + 3.5 * 3)   # the L: 24 + 10.5


def test_a_rooms_plan_summarised(tmp_path):
    path = tmp_path / "floor_plan.yaml"
    path.write_text(yaml.safe_dump(ROOMS))
    s, model = summarise(path)
    assert s.kind == "rooms" and s.bounds == (0.0, 0.0, 8.0, 3.0)
    # kitchen 4 x 3 less its 1 x 0.2 block, at its own 2.4 m; hall 3.9 x 3 at the plan's 2.6 m
    assert s.rooms == [("kitchen", pytest.approx(11.8), 2.4), ("hall", pytest.approx(11.7), 2.6)]
    assert s.counts == {"doors": 2, "openings": 1, "windows": 1, "internal blocks": 1}
    np.testing.assert_array_equal(s.windows, [[0, 0.5, 0, 2.5]])
    assert s.camera_z == 1.5 and s.z == 1.5 and (s.step_m, s.wall_margin_m) == (0.25, 0.1)   # umap.grid's defaults
    want, _ = plan_grid(model, step_m=0.25, z=1.5, wall_margin_m=0.1)
    np.testing.assert_array_equal(s.grid, want)
    text = "\n".join(s.lines())
    assert "8.00 m x 3.00 m" in text and "2 rooms, 23.5 m2 in all" in text and "kitchen    11.8 m2, ceiling 2.40 m" in text
    assert "2 doors, 1 opening, 1 window, 1 internal block" in text
    assert f"grid: {len(want):,} places at 0.25 m" in text
    # a coarser grid, a camera given: fewer places, at that height
    coarse, _ = summarise(path, step_m=0.5, z=1.2)
    assert 0 < len(coarse.grid) < len(s.grid) and np.all(coarse.grid[:, 2] == 1.2)


def test_an_outline_without_a_camera_height_has_no_grid_and_says_so(tmp_path):
    path = tmp_path / "plan.yaml"
    path.write_text(yaml.safe_dump(PLAN))
    s, _ = summarise(path)
    assert s.kind == "outline" and s.rooms == [("inside the outline", pytest.approx(34.5), 2.6)]
    assert s.counts == {"doors": 2, "openings": 0, "windows": 0} and len(s.grid) == 0 and s.z is None
    np.testing.assert_array_equal(s.gaps, [[2, 0, 2.9, 0], [0, 5, 0, 5.9]])   # drawn as gaps in the walls
    assert any("not in the plan; give umap.grid.z" in line for line in s.lines())
    with pytest.raises(ValueError, match="step"):
        summarise(path, step_m=0.0)
    # a step of a millimetre over 6 x 7 m (42 million points): refused before any is laid
    with pytest.raises(ValueError, match=r"a grid step of 0.001 m lays 42,013,001 points .* give a larger --step"):
        summarise(path, step_m=0.001, z=1.4)


def test_the_view_shows_a_square_room_s_corners_where_geometry_puts_them():
    # a 4 x 4 room, the camera at its centre facing +x: its four vertical corners at
    # azimuths +-45 and +-135 deg, column u = (180 - azimuth) W / 360 - 0.5 (azimuth growing
    # to the left); at the horizon's row every other column is a wall's horizontal middle
    model = floor_plan_model({"floor_z": 0.0, "ceiling_z": 2.5, "outline": [[0, 0], [4, 0], [4, 4], [0, 4]]})
    w = 360
    lines = view_lines(model, 2.0, 2.0, 1.25, 0.0, width=w)
    assert lines.shape == (180, 360)
    horizon = lines[90]
    for azimuth in (45, 135, -45, -135):
        u = (180 - azimuth) * w / 360 - 0.5
        assert horizon[int(np.floor(u)):int(np.ceil(u)) + 1].any(), azimuth
    assert horizon.sum() <= 8                                  # nothing else crosses the horizon
    # facing +y instead (heading 90): the same corners, a quarter turn along
    turned = view_lines(model, 2.0, 2.0, 1.25, 90.0, width=w)
    np.testing.assert_array_equal(turned, np.roll(lines, -90, axis=1))


def test_the_command_prints_and_draws(tmp_path):
    path = tmp_path / "floor_plan.yaml"
    path.write_text(yaml.safe_dump(ROOMS))
    out = tmp_path / "check"
    r = CliRunner().invoke(app, ["plan", str(path), "--out", str(out), "--at", "2,1.5", "--heading", "30"])
    assert r.exit_code == 0, r.output
    assert "2 rooms, 23.5 m2 in all" in r.output and f"wrote {out / 'view.png'}" in r.output
    for name in ("plan.png", "view.png"):
        with Image.open(out / name) as im:
            assert im.size[0] >= 640 and im.size[1] >= 400
    assert "lies outside" not in r.output
    r = CliRunner().invoke(app, ["plan", str(path), "--out", str(out), "--at", "20,1.5"])   # beyond the hall
    assert r.exit_code == 0 and "note: (20, 1.5) lies outside the plan's rooms" in r.output
    r = CliRunner().invoke(app, ["plan", str(path), "--out", str(out), "--at", "2;1"])
    assert r.exit_code != 0 and "--at '2;1': give the point as X,Y" in r.output


def _photo(model, x, y, z, heading, path):
    """A 360 deg 'photo' of the map: its lines (3 px wide, light on dark) at 1024 x 512."""
    lines = view_lines(model, x, y, z, heading, width=1024)
    cv2.imwrite(str(path), np.where(cv2.dilate(lines.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0, 230, 60)
                .astype(np.uint8))
    return path


def test_a_photo_held_at_its_own_place_finds_its_heading(tmp_path):
    # a photo of the L-shaped room from (4.7, 3.1) facing 70 deg: held there, its lines match
    # best at 70 deg (to the localizer's 2.5 deg column) and score far above the same photo
    # held in the other arm of the L (measured: 0.94 against 0.48)
    model = floor_plan_model(PLAN)
    path = _photo(model, 4.7, 3.1, 1.4, 70.0, tmp_path / "pano.png")
    here = photo_at(model, 4.7, 3.1, 1.4, path)
    assert abs((here.heading_deg - 70.0 + 180) % 360 - 180) <= 2.5
    elsewhere = photo_at(model, 1.0, 6.0, 1.4, path)
    assert here.score > 0.85 and elsewhere.score < here.score - 0.3
    assert here.photo_lines.shape == here.map_lines.shape == (72, 144)


def test_the_command_holds_a_photo_against_the_map(tmp_path):
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump({**PLAN, "camera_z": 1.4}))
    model = floor_plan_model(PLAN)
    photo = _photo(model, 4.7, 3.1, 1.4, 200.0, tmp_path / "pano.png")
    out = tmp_path / "check"
    r = CliRunner().invoke(app, ["plan", str(plan), "--out", str(out), "--at", "4.7,3.1", "--photo", str(photo)])
    assert r.exit_code == 0, r.output
    assert "pano.png: its lines match the map's at (4.7, 3.1) best at heading 200 deg" in r.output
    assert (out / "photo.png").is_file() and (out / "view.png").is_file()
    r = CliRunner().invoke(app, ["plan", str(plan), "--out", str(out), "--photo", str(photo)])
    assert r.exit_code != 0 and "--photo needs --at X,Y" in r.output


def test_the_command_writes_a_rooms_file_to_fill_in(tmp_path):
    # --rooms-for PHOTOS: rooms.csv with a row for each photo (named as localize names them),
    # its room empty; read back as umap.room_hints it names no room yet, and filled in it is
    # read as the plan's rooms. An outline plan has no rooms to name: refused
    import csv

    from placeloc.umap.room_hints import read_room_hints

    path = tmp_path / "floor_plan.yaml"
    path.write_text(yaml.safe_dump(ROOMS))
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("b.jpg", "a.jpg", "c.png"):
        cv2.imwrite(str(photos / name), np.zeros((32, 64), np.uint8))
    (photos / "notes.txt").write_text("not a photo")
    out = tmp_path / "check"
    r = CliRunner().invoke(app, ["plan", str(path), "--out", str(out), "--rooms-for", str(photos)])
    assert r.exit_code == 0, r.output
    assert f"wrote {out / 'rooms.csv'}: 3 photos; fill in the room of each you know" in r.output
    rows = list(csv.DictReader(open(out / "rooms.csv")))
    assert [(row["frame"], row["room"]) for row in rows] == [("a.jpg", ""), ("b.jpg", ""), ("c.png", "")]
    assert read_room_hints(out / "rooms.csv", ["a.jpg", "b.jpg", "c.png"], ["kitchen", "hall"]) == ([None] * 3, [])
    (out / "rooms.csv").write_text("frame,room\na.jpg,kitchen\nb.jpg,\nc.png,Hall\n")
    assert read_room_hints(out / "rooms.csv", ["a.jpg", "b.jpg", "c.png"], ["kitchen", "hall"])[0] == \
        ["kitchen", None, "Hall"]
    outline = tmp_path / "outline.yaml"
    outline.write_text(yaml.safe_dump({**PLAN, "camera_z": 1.4}))
    r = CliRunner().invoke(app, ["plan", str(outline), "--out", str(out), "--rooms-for", str(photos)])
    assert r.exit_code != 0 and "an outline plan names no rooms; umap.room_hints needs a plan of rooms" in r.output
    r = CliRunner().invoke(app, ["plan", str(path), "--out", str(out), "--rooms-for", str(tmp_path / "nothere")])
    assert r.exit_code != 0 and "nothere: not a folder; give the folder of photos" in r.output


def _two_rooms(tmp_path, second):
    """Room a (3 x 3 m, a door in its south wall 1-1.9 m along) and room ``second`` with a
    door 1-1.9 m along its own south wall; the camera at 1.5 m."""
    x0 = second[0][0]
    plan = {"floor_z": 0.0, "ceiling_z": 2.5, "camera_z": 1.5,
            "rooms": [{"name": "a", "polygon": [[0, 0], [3, 0], [3, 3], [0, 3]]}, {"name": "b", "polygon": second}],
            "doors": [{"from": [1, 0], "to": [1.9, 0], "height": 2.0},
                      {"from": [x0 + 1, 0], "to": [x0 + 1.9, 0], "height": 2.0}]}
    path = tmp_path / f"plan{x0:g}.yaml"
    path.write_text(yaml.safe_dump(plan))
    return summarise(path)


def test_rooms_that_repeat_each_others_views_look_alike(tmp_path):
    from placeloc.umap.plan_report import LOOK_ALIKE, look_alike_lines, look_alike_rooms

    # b the same room as a, 3.5 m east (seven of the check's 0.5 m steps, so each of a's places
    # has b's copy on the grid) and no opening between them: every view of a is one of b's,
    # to the pixel, so each room's median best score in the other is 1
    s, m = _two_rooms(tmp_path, [[3.5, 0], [6.5, 0], [6.5, 3], [3.5, 3]])
    twins = look_alike_rooms(m, z=s.z, wall_margin_m=s.wall_margin_m)
    assert [(a.room, a.like) for a in twins] == [("a", "b"), ("b", "a")] or \
        [(a.room, a.like) for a in twins] == [("b", "a"), ("a", "b")]
    assert all(a.score == pytest.approx(1.0, abs=1e-6) and a.places == 36 for a in twins), twins
    said = look_alike_lines(twins)
    assert len(said) == 3 and all("look alike: name the room" in line for line in said[1:])
    # b a long 7 x 1.8 m room: no view of one is near one of the other
    s, m = _two_rooms(tmp_path, [[3.5, 0], [10.5, 0], [10.5, 1.8], [3.5, 1.8]])
    apart = look_alike_rooms(m, z=s.z, wall_margin_m=s.wall_margin_m)
    assert len(apart) == 2 and all(a.score < LOOK_ALIKE - 0.1 for a in apart), apart
    assert not any("look alike:" in line for line in look_alike_lines(apart))
    # an outline names no rooms: nothing to compare
    path = tmp_path / "outline.yaml"
    path.write_text(yaml.safe_dump({**PLAN, "camera_z": 1.5}))
    s, m = summarise(path)
    assert look_alike_rooms(m, z=s.z, wall_margin_m=s.wall_margin_m) == [] and look_alike_lines([]) == []


def test_the_command_says_which_rooms_look_alike_unless_told_not_to(tmp_path):
    path = tmp_path / "floor_plan.yaml"
    path.write_text(yaml.safe_dump(ROOMS))
    r = CliRunner().invoke(app, ["plan", str(path), "--out", str(tmp_path / "a")])
    assert r.exit_code == 0 and "rooms that look alike from inside" in r.output, r.output
    assert any(line.strip().startswith("kitchen") and " like hall" in line for line in r.output.splitlines())
    r = CliRunner().invoke(app, ["plan", str(path), "--out", str(tmp_path / "b"), "--no-look-alike"])
    assert r.exit_code == 0 and "look alike" not in r.output


def test_a_large_plan_is_checked_on_a_coarser_grid(tmp_path, monkeypatch):
    # 72 places at 0.5 m in the two rooms; allowed 20, the step grows by sqrt(72 / 20) to about
    # 0.95 m: about 20 places, still both rooms
    from placeloc.umap import plan_report
    from placeloc.umap.plan_report import look_alike_places

    s, m = _two_rooms(tmp_path, [[3.5, 0], [6.5, 0], [6.5, 3], [3.5, 3]])
    assert len(look_alike_places(m, z=s.z, wall_margin_m=s.wall_margin_m).xy) == 72
    monkeypatch.setattr(plan_report, "LOOK_ALIKE_MAX_PLACES", 20)
    got = look_alike_places(m, z=s.z, wall_margin_m=s.wall_margin_m)
    assert 8 <= len(got.xy) <= 25 and set(got.room) == {"a", "b"}, got


def test_plan_png_names_the_look_alike_rooms(tmp_path, monkeypatch):
    # the picture's room labels and title say what the printed lines say: a marked room is
    # labelled with the room it looks like, an unmarked one keeps its name
    from placeloc.evaluation import pose_estimates
    from placeloc.umap.plan_report import LookAlike, draw

    seen = {}

    def fake_plot(path, *args, **kwargs):
        seen.update(kwargs)
        return path

    monkeypatch.setattr(pose_estimates, "plot_estimates_on_plan", fake_plot)
    path = tmp_path / "floor_plan.yaml"
    path.write_text(yaml.safe_dump(ROOMS))
    s, model = summarise(path)
    draw(s, model, tmp_path / "out", look_alike=[LookAlike("kitchen", 0.81, "hall", 20), LookAlike("hall", 0.55, "kitchen", 20)])
    assert seen["labels"] == ["kitchen: like hall (0.81)", "hall"]
    assert seen["title"].endswith("; look-alike rooms: kitchen (name the room of photos taken there)")
    draw(s, model, tmp_path / "out")
    assert seen["labels"] == ["kitchen", "hall"] and "look-alike" not in seen["title"]


def test_rooms_narrower_than_the_checks_step_are_not_compared(tmp_path):
    # two 0.3 m closets: the 0.05 m grid has places in them, the check's 0.5 m grid none
    from placeloc.umap.plan_report import look_alike_places, look_alike_rooms

    path = tmp_path / "closets.yaml"
    path.write_text(yaml.safe_dump({"floor_z": 0.0, "ceiling_z": 2.5, "camera_z": 1.5, "rooms": [
        {"name": "a", "polygon": [[0, 0], [0.3, 0], [0.3, 0.3], [0, 0.3]]},
        {"name": "b", "polygon": [[0.4, 0], [0.7, 0], [0.7, 0.3], [0.4, 0.3]]}]}))
    s, m = summarise(path, step_m=0.05)
    assert len(s.grid) > 0
    assert len(look_alike_places(m, z=s.z, wall_margin_m=s.wall_margin_m).xy) == 0
    assert look_alike_rooms(m, z=s.z, wall_margin_m=s.wall_margin_m) == []


def test_the_rooms_file_says_which_photos_matter_most(tmp_path):
    # two rooms that repeat each other's views: the rooms.csv line names them as the ones to
    # fill in first; with the check off, the line is as before
    s, _ = _two_rooms(tmp_path, [[3.5, 0], [6.5, 0], [6.5, 3], [3.5, 3]])
    photos = tmp_path / "photos"
    photos.mkdir()
    cv2.imwrite(str(photos / "a.jpg"), np.zeros((32, 64), np.uint8))
    r = CliRunner().invoke(app, ["plan", s.source, "--out", str(tmp_path / "o"), "--rooms-for", str(photos)])
    assert r.exit_code == 0, r.output
    assert "umap.room_hints; those taken in a, b (look-alike rooms) matter most" in r.output
    r = CliRunner().invoke(app, ["plan", s.source, "--out", str(tmp_path / "o"), "--rooms-for", str(photos),
                                 "--no-look-alike"])
    assert r.exit_code == 0 and r.output.rstrip().endswith("give the file as umap.room_hints"), r.output
