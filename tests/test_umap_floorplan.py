"""Known answers for multi-room floor plans: walls per room with their own ceiling, doors as
real gaps, windows as frames, free-space grids and the warnings for settings that do nothing."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.geometry.floorplan import Model, ModelError, floor_plan_model, free_space_mask

# Two 4 x 3 m rooms side by side, sharing the wall x = 4; a 1 m door in it at y 1..2; the
# right room has a lower ceiling; a window on the left room's outer wall x = 0.
PLAN = {"floor_z": 0.0, "ceiling_z": 2.6,
        "rooms": [{"name": "living", "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]]},
                  {"name": "bed", "polygon": [[4, 0], [8, 0], [8, 3], [4, 3]], "ceiling_z": 2.4}],
        "openings": [{"from": [4, 1], "to": [4, 2], "height": 2.0}],
        "windows": [{"from": [0, 0.5], "to": [0, 2.5], "sill": 0.9, "top": 2.1}]}


def _has(segs, row, tol=1e-9):
    """The segment is there, in either direction."""
    row = np.asarray(row, float)
    flipped = np.r_[row[3:], row[:3]]
    return bool((np.abs(segs - row).max(axis=1) < tol).any() or (np.abs(segs - flipped).max(axis=1) < tol).any())


def test_door_is_a_gap_and_ceilings_are_per_room():
    m = floor_plan_model(PLAN)
    s = m.segments
    assert m.rooms and len(m.polygons) == 2
    # the floor line of the shared wall stops at the door on both sides (x = 4, y 0..1 and 2..3)
    assert _has(s, [4, 0, 0, 4, 1, 0]) and _has(s, [4, 2, 0, 4, 3, 0])
    floor_on_door = [r for r in s if r[0] == 4 and r[3] == 4 and r[2] == 0 and r[5] == 0 and min(r[1], r[4]) < 1.5 < max(r[1], r[4])]
    assert floor_on_door == []
    # jambs and lintel at the door height
    assert _has(s, [4, 1, 0, 4, 1, 2]) and _has(s, [4, 2, 0, 4, 2, 2]) and _has(s, [4, 1, 2, 4, 2, 2])
    # ceiling edges at each room's own height
    assert _has(s, [0, 0, 2.6, 4, 0, 2.6]) and _has(s, [4, 0, 2.4, 8, 0, 2.4])
    # wall faces: no face across the door below its top, a face above it up to the ceiling
    f = m.faces
    door_faces = f[(f[:, 0] == 4) & (f[:, 2] == 4) & (np.minimum(f[:, 1], f[:, 3]) < 1.5) & (np.maximum(f[:, 1], f[:, 3]) > 1.5)]
    assert len(door_faces) == 2 and (door_faces[:, 4] == 2.0).all()
    assert sorted(door_faces[:, 5].tolist()) == [2.4, 2.6]
    # the window is a frame of four lines on the wall x = 0
    for row in ([0, 0.5, 0.9, 0, 2.5, 0.9], [0, 0.5, 2.1, 0, 2.5, 2.1], [0, 0.5, 0.9, 0, 0.5, 2.1], [0, 2.5, 0.9, 0, 2.5, 2.1]):
        assert _has(s, row)


def test_free_space_is_inside_any_room_and_away_from_walls():
    m = floor_plan_model(PLAN)
    xy = np.array([[2.0, 1.5], [6.0, 1.5], [9.0, 1.5], [0.05, 1.5], [4.0, 1.5]])
    keep, notes = free_space_mask(xy, m, inside_only=True, wall_margin_m=0.2)
    # the doorway itself (x = 4, y = 1.5) is 0.5 m from its jambs; its lintel face (from 2.0 m
    # up) is no wall for a camera below it
    assert keep.tolist() == [True, True, False, False, True] and notes == []


def test_grid_settings_that_do_nothing_are_reported():
    wire = Model(np.array([[0, 0, 0, 1, 0, 0.0]]), np.zeros((0, 6)), source="w.yaml")
    keep, notes = free_space_mask(np.array([[0.5, 0.5]]), wire, inside_only=True, wall_margin_m=0.1)
    assert keep.all() and len(notes) == 2
    assert "grid.inside_only does nothing for w.yaml" in notes[0] and "grid.wall_margin_m does nothing" in notes[1]
    faced = Model(np.array([[0, 0, 0, 1, 0, 0.0]]), np.array([[0, 0, 4, 0, 0, 2.5]]), source="f.yaml")
    keep, notes = free_space_mask(np.array([[1.0, 0.05], [1.0, 1.0]]), faced, inside_only=False, wall_margin_m=0.1)
    assert keep.tolist() == [False, True] and notes == []


def test_bad_rooms_are_named():
    with pytest.raises(ModelError, match=r"rooms\[1\] \(bed\): ceiling_z 0.0 must be above"):
        floor_plan_model({**PLAN, "rooms": [PLAN["rooms"][0], {**PLAN["rooms"][1], "ceiling_z": 0.0}]})
    with pytest.raises(ModelError, match=r"windows\[0\] needs"):
        floor_plan_model({**PLAN, "windows": [{"from": [0, 0.5], "to": [0, 2.5]}]})


# Two rooms with a 0.2 m thick wall between them (each polygon stops at its own side, as in
# ZInD), a door through it at y 1..2 under a 2.0 m lintel, a kitchen wall block inside the
# left room, and the camera height in the plan.
THICK = {"floor_z": 0.0, "ceiling_z": 2.6, "camera_z": 1.4,
         "rooms": [{"name": "left", "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]],
                    "internal": [[[1, 2.5], [2, 2.5], [2, 2.7], [1, 2.7]]]},
                   {"name": "right", "polygon": [[4.2, 0], [8, 0], [8, 3], [4.2, 3]]}],
         "doors": [{"from": [4, 1], "to": [4, 2], "height": 2.0}, {"from": [4.2, 1], "to": [4.2, 2], "height": 2.0}],
         "openings": [{"from": [8, 0.5], "to": [8, 2.5], "height": 2.6}]}


def test_doorway_is_free_space_and_lintels_are_no_walls():
    from placeloc.geometry.floorplan import blocking_faces

    m = floor_plan_model(THICK)
    # in the door gap, inside the wall's thickness, 0.02-0.12 m from the lintel faces: free
    doorway = np.array([[4.1, 1.5], [4.02, 1.3], [4.18, 1.7]])
    keep, notes = free_space_mask(doorway, m, inside_only=True, wall_margin_m=0.2, z=1.4)
    assert keep.all() and not notes
    # the lintels are faces from 2.0 m to the ceiling: they do not span a 1.4 m camera
    lintels = m.faces[(m.faces[:, 4] == 2.0)]
    assert len(lintels) == 2
    assert not any((blocking_faces(m.faces, 1.4) == row).all(1).any() for row in lintels)
    # but inside the wall beside the door (not a gap), and beyond the gap depth: not free
    keep, _ = free_space_mask(np.array([[4.1, 0.5], [4.1, 2.6], [8.5, 1.5]]), m, inside_only=True, wall_margin_m=0.0)
    assert list(keep) == [False, False, False]
    # an opening on the outer wall admits its doorway only up to GAP_DEPTH_M outside
    keep, _ = free_space_mask(np.array([[8.2, 1.5], [8.3, 1.5]]), m, inside_only=True, wall_margin_m=0.0)
    assert list(keep) == [True, False]


def test_internal_walls_are_walls_and_not_free_space():
    m = floor_plan_model(THICK)
    # its four edges are full-height faces, its corners vertical lines
    block = m.faces[(m.faces[:, 0] >= 1) & (m.faces[:, 0] <= 2) & (m.faces[:, 1] >= 2.5) & (m.faces[:, 1] <= 2.7)
                    & (m.faces[:, 2] >= 1) & (m.faces[:, 2] <= 2) & (m.faces[:, 3] >= 2.5) & (m.faces[:, 3] <= 2.7)]
    assert len(block) == 4 and (block[:, 4] == 0).all() and (block[:, 5] == 2.6).all()
    assert _has(m.segments, [2, 2.7, 0, 2, 2.7, 2.6])
    keep, _ = free_space_mask(np.array([[1.5, 2.6], [1.5, 1.5]]), m, inside_only=True, wall_margin_m=0.0)
    assert list(keep) == [False, True]


def test_grid_from_the_model_by_default():
    from placeloc.geometry.floorplan import plan_grid

    m = floor_plan_model(THICK, "two-rooms.yaml")
    poses, notes = plan_grid(m, step_m=0.25, wall_margin_m=0.1)
    assert not notes
    assert (poses[:, 2] == 1.4).all()                       # z: the plan's camera height
    assert poses[:, 0].min() == pytest.approx(0.125) and poses[:, 1].min() == pytest.approx(0.125)
    assert poses[:, 0].max() <= 8.0 and poses[:, 1].max() <= 3.0
    # the door gap is on the grid (x 4.125 lies in the wall's thickness)
    assert ((np.abs(poses[:, 0] - 4.125) < 1e-9) & (poses[:, 1] > 1.0) & (poses[:, 1] < 2.0)).sum() >= 3
    # a grid that misses the model: an error naming the grid and the model's bounds
    with pytest.raises(ValueError, match=r"keeps no position of two-rooms.yaml \(plan x 0.00..8.00 m, y 0.00..3.00 m\)"):
        plan_grid(m, x=[20, 30, 0.5], y=[0, 3, 0.5])
    # z outside the storey, and a grid that covers a corner of the plan only: said
    with pytest.raises(ValueError, match=r"grid z 3.0 m lies outside the storey"):
        plan_grid(m, z=3.0)
    _, notes = plan_grid(m, x=[0.1, 1.0, 0.25], y=[0.1, 1.0, 0.25])
    assert any("covers only" in n and "two-rooms.yaml" in n for n in notes)
    # no camera height anywhere: the caller is told to give one
    with pytest.raises(ValueError, match=r"no camera height \(camera_z\)"):
        plan_grid(floor_plan_model({**THICK, "camera_z": None}))


def test_a_door_or_window_on_no_wall_is_warned_about(caplog):
    """A door 5 cm off its wall (a rounded coordinate) cuts no wall, yet its doorway counts as
    free space: the loader names it, how far off it is and the fix; elements on their walls
    (within 1 cm) say nothing."""
    import copy
    import logging

    with caplog.at_level(logging.WARNING, logger="placeloc"):
        floor_plan_model(PLAN, "plan.yaml")
    assert not [r for r in caplog.records if "lies on no room's edge" in r.getMessage()]
    plan = copy.deepcopy(PLAN)
    plan["doors"] = [{"from": [4.05, 1.2], "to": [4.05, 1.9], "height": 2.0}]
    plan["windows"].append({"from": [2, 3.3], "to": [3, 3.3], "sill": 1.0, "top": 2.0})
    with caplog.at_level(logging.WARNING, logger="placeloc"):
        m = floor_plan_model(plan, "plan2.yaml")
    said = [r.getMessage() for r in caplog.records if "lies on no room's edge" in r.getMessage()]
    assert said == [
        "plan2.yaml: doors[0] [4.05, 1.2] -> [4.05, 1.9] lies on no room's edge (its ends are at best 0.05 m from one; "
        "both must be within 0.01 m): it cuts no wall and its doorway still counts as free space; move it onto its wall",
        "plan2.yaml: windows[1] [2, 3.3] -> [3, 3.3] lies on no room's edge (its ends are at best 0.30 m from one; "
        "both must be within 0.01 m): it cuts no wall; move it onto its wall"]
    assert len(m.gaps) == 2  # the plan loads as it is


def test_label_points_by_hand():
    """Where a room's name is written: the highest, then leftmost, point of the 0.1 m lattice
    at least 0.25 m inside (a 4 x 3 m room: (0.3, 2.7); a hall 1.4 m wide: its left end; an
    L: the top of its upright arm); a polygon too thin for that: its point farthest from the
    edges (the first of equals)."""
    from placeloc.geometry.floorplan import label_points

    room = np.array([[0, 0], [4, 0], [4, 3], [0, 3]], float)
    hall = np.array([[0, 0], [10, 0], [10, 1.4], [0, 1.4]], float)
    ell = np.array([[0, 0], [6, 0], [6, 2], [2, 2], [2, 6], [0, 6]], float)
    thin = np.array([[0, 0], [5, 0], [5, 0.3], [0, 0.3]], float)
    assert np.allclose(label_points([room, hall, ell, thin]), [[0.3, 2.7], [0.3, 1.1], [0.3, 5.7], [0.1, 0.1]])
    assert np.allclose(label_points([room + [6, 0]]), [[6.3, 2.7]])
