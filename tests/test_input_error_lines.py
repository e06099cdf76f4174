"""Bad input files get one line naming where to look: the file's line for a CSV, the key a
floor plan should have."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from placeloc.coembed.observations import ObservationError, read_observations_csv, read_points_csv
from placeloc.geometry.floorplan import ModelError, load_model


def test_observations_csv_error_names_the_file_line(tmp_path: Path) -> None:
    """Line 6 of the file (header, two rows, two blank lines, then the short row) is line 6,
    not numpy's "row 3", and numpy's advice about ``usecols`` does not reach the user."""
    path = tmp_path / "obs.csv"
    path.write_text("step,feature,value\n0,1,0.5\n1,2,0.25\n\n\n2,3\n")
    with pytest.raises(ObservationError) as err:
        read_observations_csv(path)
    msg = str(err.value)
    assert f"{path} line 6 has 2 fields but the header names 3 (step, feature, value)" in msg
    assert "usecols" not in msg and "row 3" not in msg


def test_points_csv_names_the_line_of_a_non_number(tmp_path: Path) -> None:
    path = tmp_path / "landmarks.csv"
    path.write_text("\ufefffeature,x,y\n1,0.0,1.0\n# a comment\n2,zero,2.0\n")
    with pytest.raises(ObservationError, match=r"landmarks: .*landmarks\.csv line 4: 'zero' is not a number"):
        read_points_csv(path)


def test_observations_csv_reads_numbers_blank_lines_and_comments(tmp_path: Path) -> None:
    path = tmp_path / "obs.csv"
    path.write_text("t,feature,x,y\n0,7,1.5,2.5\n\n# seen again\n1,7,1.25,-2\n1,9,3,4\n")
    obs = read_observations_csv(path)
    assert obs.step_ids.tolist() == [0, 1] and obs.feature_ids.tolist() == [7, 9]
    assert obs.value_dim == 2 and obs.nnz == 3
    header_only = tmp_path / "empty.csv"
    header_only.write_text("feature,x,y\n")
    ids, xy = read_points_csv(header_only)
    assert ids.shape == (0,) and xy.shape == (0, 2) and xy.dtype == np.float64


def test_plan_of_the_wrong_shape_asks_for_rooms(tmp_path: Path) -> None:
    path = tmp_path / "plan.yaml"
    path.write_text("room:\n  - {name: kitchen, polygon: [[0, 0], [4, 0], [4, 3]]}\n")
    with pytest.raises(ModelError, match=r"plan\.yaml: expected a floor plan with 'rooms:' .*docs/umap\.md"):
        load_model(path)


@pytest.mark.parametrize("sep, said", [(";", "semicolons"), ("\t", "tabs")])
def test_a_csv_separated_otherwise_is_named_with_the_fix(tmp_path: Path, sep: str, said: str) -> None:
    """A spreadsheet's export in a comma-decimal locale separates by ';' (another by tabs):
    the observations, the intrinsics and the poses say so, where each named only the
    columns it missed."""
    from placeloc.coembed.camera import read_intrinsics
    from placeloc.evaluation.poses import PoseError, read_poses

    fix = f"(this file separates its columns by {said}: save it comma-separated)"
    obs = tmp_path / "obs.csv"
    obs.write_text(sep.join(["image", "track", "x", "y"]) + "\n" + sep.join(["1", "0", "380", "437"]) + "\n")
    with pytest.raises(ObservationError, match=r"needs a header row with at least 3 columns " + fix.replace("(", r"\(")
                       .replace(")", r"\)")):
        read_observations_csv(obs)
    intr = tmp_path / "intrinsics.csv"
    intr.write_text(sep.join(["f", "cx", "cy"]) + "\n" + sep.join(["600", "320", "240"]) + "\n")
    with pytest.raises(ObservationError, match=r"missing 'f' \(this file separates"):
        read_intrinsics(intr)
    poses = tmp_path / "poses.csv"
    poses.write_text(sep.join(["frame", "x", "y"]) + "\n" + sep.join(["0", "1", "2"]) + "\n")
    with pytest.raises(PoseError, match=f"separates its columns by {said}"):
        read_poses(poses)


def test_intrinsics_with_a_byte_order_mark_before_f_are_read(tmp_path: Path) -> None:
    """Excel writes a byte-order mark: before 'f' as the first column it made the key
    '\\ufefff' and the file "missing 'f'"."""
    from placeloc.coembed.camera import read_intrinsics

    intr = tmp_path / "intrinsics.csv"
    intr.write_text("\ufefff,cx,cy,k1\n600,320,240,0.1\n", encoding="utf-8")
    got = read_intrinsics(intr)
    assert (got.f, got.cx, got.cy, got.dist[0]) == (600.0, 320.0, 240.0, 0.1)
