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
    # the doorway itself (x = 4, y = 1.5) is 0.5 m from its jambs but under its lintel face
    assert keep.tolist() == [True, True, False, False, False] and notes == []


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
