"""Known answers for the synthetic home generator's failure cases: the white bonus room,
kitchen clutter at wall height and cameras close to a wall."""

from __future__ import annotations

import numpy as np

from placeloc.geometry.floorplan import blocking_faces, floor_plan_model, wall_distance
from placeloc.geometry.polygons import point_in_polygon
from placeloc.synth.home import cabinet_poses, line_agreement, near_wall_poses, plan, room_name


def _room(fp, name):
    return np.asarray(next(r["polygon"] for r in fp["rooms"] if r["name"] == name), float)


def test_kitchen_clutter_stands_at_wall_height():
    fp, clutter = plan(np.random.default_rng(3))
    kitchen = _room(fp, "kitchen")
    lo, hi = kitchen.min(axis=0), kitchen.max(axis=0)
    boxes = np.asarray(clutter["boxes"] + clutter["flat"], float)
    inside = (boxes[:, 0] >= lo[0] - 1e-6) & (boxes[:, 3] <= hi[0] + 1e-6) & (boxes[:, 1] >= lo[1] - 1e-6) & (boxes[:, 4] <= hi[1] + 1e-6)
    # between the floor line and the ceiling line (1.0-2.2 m): wall cabinets, hood, fridge, shelves, clock
    at_wall_height = inside & (boxes[:, 5] > 1.2) & (boxes[:, 2] < 2.2)
    assert at_wall_height.sum() >= 5


def test_the_bonus_room_is_white_and_has_a_fan():
    from placeloc.synth.home import scene_arrays

    rng = np.random.default_rng(4)
    fp, clutter = plan(rng)
    bonus = _room(fp, "bonus")
    scene = scene_arrays(fp, clutter, rng)
    white = [r["name"] for r, wt in zip(fp["rooms"], scene["rooms_white"]) if wt]
    assert white == ["bonus"]
    fans = np.asarray(clutter["fans"], float)
    centres = (fans[:, :2] + fans[:, 3:5]) / 2
    assert point_in_polygon(centres, bonus).any()
    assert room_name(fp, *bonus.mean(axis=0)) == "bonus"


def test_near_wall_cameras_stand_0_4_to_0_6_m_from_a_wall():
    rng = np.random.default_rng(5)
    fp, clutter = plan(rng)
    xy = near_wall_poses(fp, clutter, rng, 6, 1.5)
    assert len(xy) == 6
    walls = blocking_faces(floor_plan_model(fp).faces, 1.5)
    d = wall_distance(xy, walls)
    assert (d >= 0.4 - 1e-9).all() and (d <= 0.6 + 1e-9).all()
    rooms = [room_name(fp, *p) for p in xy]
    assert rooms == ["kitchen", "bonus"] * 3
    boxes = np.asarray(clutter["boxes"], float)
    for b in boxes:   # clear of the furniture
        assert not ((xy[:, 0] > b[0] - 0.15) & (xy[:, 0] < b[3] + 0.15) & (xy[:, 1] > b[1] - 0.15) & (xy[:, 1] < b[4] + 0.15)).any()


def test_cabinet_cameras_stand_in_front_of_the_counters():
    # 0.15-0.35 m in front of a counter run's front, the runs in turn, in the kitchen, clear of
    # the furniture that stands in front of the run
    fp, clutter = plan(np.random.default_rng(6))
    xy = cabinet_poses(fp, clutter, np.random.default_rng(7), 4, 1.5)
    assert len(xy) == 4 and all(room_name(fp, *p) == "kitchen" for p in xy)
    runs = np.asarray(clutter["counters"], float)
    for i, p in enumerate(xy):
        a, b, n = runs[i % len(runs), :2], runs[i % len(runs), 2:4], runs[i % len(runs), 4:]
        depth = float((p - a) @ n)
        along = float((p - a) @ (b - a)) / float(np.hypot(*(b - a)))
        assert 0.15 - 1e-9 <= depth <= 0.35 + 1e-9 and 0.3 - 1e-9 <= along <= np.hypot(*(b - a)) - 0.3 + 1e-9
    walls = blocking_faces(floor_plan_model(fp).faces, 1.5)
    assert (wall_distance(xy, walls) >= 0.3 - 1e-9).all()


def test_line_agreement_by_hand():
    m = np.zeros((18, 36), np.uint8)
    m[9, :] = 1                              # a map line on the horizon: 36 pixels
    q = np.zeros_like(m)
    q[10, :18] = 1                           # 18 detected pixels one row below it (on the map within 1 px)
    q[17, :12] = 1                           # 12 clutter pixels in the last row (elevation -85 deg)
    q[4, :6] = 1                             # 6 clutter pixels at +40 deg
    on_map, found, below = line_agreement(q, m)
    assert on_map == 18 / 36
    assert found == 19 / 36                  # columns 0-18 of the map line lie within 1 px of a detection
    assert below == 12 / 18


def test_the_experiment_rule_picks_the_highest_mean_then_the_cheapest():
    # placeloc experiment umap-homes: highest mean share over the development runs; among
    # settings within one panorama of the 180 of it, the fewest candidate cells, then the
    # earlier (plainer) in the sweep
    from placeloc.experiments.umap_homes import NOISE, SWEEP, choose

    names = list(SWEEP)
    climb32 = "solid-angle chamfer, 32 cells"
    square16 = "solid-angle chamfer, 16 cells, beam's cells whole"
    square32 = "solid-angle chamfer, 32 cells, beam's cells whole"
    texture_square32 = "solid-angle chamfer, texture r 1, 32 cells, beam's cells whole"
    assert {climb32, square16, square32, texture_square32} <= set(names)
    nine = [0.95] * 9
    results = {climb32: nine, square32: [0.975] * 9, texture_square32: [0.975] * 9, square16: nine}
    assert choose(results) == square32                        # a tie on 32 cells: the earlier in the sweep
    assert names.index(square32) < names.index(texture_square32)
    results[square16] = [0.975 - NOISE] * 9                   # one panorama below on fewer cells: the cheaper
    assert choose(results) == square16
    results[square16] = [0.975 - 2 * NOISE] * 9               # two panoramas below: the best
    assert choose(results) == square32
