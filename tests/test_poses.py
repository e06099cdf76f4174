"""The one pose reader: column aliases, units, keys, and errors that name file and line."""

from __future__ import annotations

import math

import numpy as np
import pytest

from placeloc.evaluation.poses import PoseError, read_poses


def test_frame_numbers_degrees_and_alignment(tmp_path):
    p = tmp_path / "poses.csv"
    p.write_text("frame,x,y,z,heading_deg\n1,1.0,2.0,1.1,90\n0,0.5,0.0,1.1,180\n")
    poses = read_poses(p)
    assert poses.keys == ("1", "0") and poses.frames.tolist() == [1, 0]
    assert np.allclose(poses.heading, [math.pi / 2, math.pi]) and np.allclose(poses.z, 1.1)
    rows = poses.rows_for_frames(2)
    assert np.allclose(poses.xy[rows], [[0.5, 0.0], [1.0, 2.0]])
    with pytest.raises(PoseError, match=r"no pose for 1 of 3 frames \(first: frame 2\)"):
        poses.rows_for_frames(3)


def test_image_names_and_utm_columns(tmp_path):
    p = tmp_path / "gps.csv"
    p.write_text("image,utm_e,utm_n\nq/a.jpg,500000.0,4649776.2\nb.jpg,500010.0,4649776.2\n")
    poses = read_poses(p)
    assert poses.frames is None and poses.heading is None
    assert poses.rows_for_names(["b.jpg", "a.jpg"]).tolist() == [1, 0]
    with pytest.raises(PoseError, match="first: c.jpg"):
        poses.rows_for_names(["c.jpg"])


@pytest.mark.parametrize("text, match", [
    ("frame,x\n0,1\n", "needs a header with a frame column"),
    ("frame,x,y\n0,1,oops\n", r"poses.csv:2: positions must be numbers"),
    ("frame,x,y\n0,1,2\n0,3,4\n", "lists frame '0' twice"),
    ("frame,x,y\n", "no rows"),
    # a short row, and a lone carriage return splitting one ("0.0\r,0": csv ends the row there)
    ("frame,x,y\n0,1\n", r"poses.csv:2: 2 values where the header has 3 \(frame,x,y\); complete the row"),
    ("frame,x,y\n0,1.0\r,2\n", r"poses.csv:2: 2 values where the header has 3"),
])
def test_bad_pose_files_name_the_file_line_and_fix(tmp_path, text, match):
    p = tmp_path / "poses.csv"
    p.write_text(text)
    with pytest.raises(PoseError, match=match):
        read_poses(p)
