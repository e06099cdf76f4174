"""Known answers for a panorama answer's margin: the best score of a rival answer (another
place, or the same place facing elsewhere) by hand, and on scenes where the answer is
certain (an L-shaped room) or a coin toss (two identical rooms)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from placeloc.geometry.floorplan import floor_plan_model, plan_grid
from placeloc.geometry.panorama import render_panoramas
from placeloc.umap.bits import unpack
from placeloc.umap.panorama import chamfer_spectra, rival_pose, row_weights, search_panoramas
from placeloc.umap.params import PanoramaParams

W, H = 144, 72


def test_rival_pose_by_hand():
    # 4 grid positions on a line, 8 columns (45 deg each); the answer at position 0, column 1.
    table = np.array([[0.90, 0.95, 0.70, 0.10, 0.80, 0.20, 0.30, 0.60],    # x = 0: the answer's place
                      [0.40, 0.50, 0.20, 0.20, 0.75, 0.20, 0.20, 0.20],    # x = 0.5: near
                      [0.10, 0.20, 0.30, 0.40, 0.50, 0.60, 0.70, 0.65],    # x = 1.5: far
                      [0.10, 0.10, 0.10, 0.10, 0.10, 0.10, 0.10, 0.10]])   # x = 3: far
    xy = np.array([[0.0, 0.0], [0.5, 0.0], [1.5, 0.0], [3.0, 0.0]])
    none = (np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64))
    # within 1 m, rivals face more than one column (45 deg) from column 1: columns 3-7 (column 7
    # wraps to 2 columns away); best 0.80 at (x = 0, column 4); far: 0.70 at x = 1.5
    assert rival_pose(table, xy, *none, np.zeros(2), 1, distance_m=1.0, yaw_cols=1) == (np.float32(0.80), 0.0, 0.0, 4)
    # every heading within 90 deg (2 columns) is the answer's: near rivals only in columns 4-6
    # (0.80 at x = 0 column 4); with a tolerance of 3 columns only column 5 (0.20), so the far 0.70 wins
    assert rival_pose(table, xy, *none, np.zeros(2), 1, distance_m=1.0, yaw_cols=3) == (np.float32(0.70), 1.5, 0.0, 6)
    # every place within 2 m is the answer's, any heading within 180 deg too: only x = 3
    # (0.10 at every column: the first)
    assert rival_pose(table, xy, *none, np.zeros(2), 1, distance_m=2.0, yaw_cols=4) == (np.float32(0.10), 3.0, 0.0, 0)
    # an off-grid point the local search scored 1.2 m away outscores the grid; one 0.9 m away
    # (nearer than the distance) does not count, however high
    seen = (np.array([[0.9, 0.0], [0.0, 1.2]]), np.array([0.99, 0.85]), np.array([1, 5]))
    assert rival_pose(table, xy, *seen, np.zeros(2), 1, distance_m=1.0, yaw_cols=1) == (0.85, 0.0, 1.2, 5)
    # no rival at all: NaN, column -1
    r = rival_pose(table[:2], xy[:2], *none, np.zeros(2), 1, distance_m=1.0, yaw_cols=4)
    assert math.isnan(r.score) and math.isnan(r.x) and math.isnan(r.y) and r.col == -1


# two identical rooms 4 x 3 m, 6 m apart (their walls hide each other), each with a door
# on the same side: a camera in one sees what the same spot in the other sees
ROOM = [[0, 0], [4, 0], [4, 3], [0, 3]]
TWINS = {"floor_z": 0.0, "ceiling_z": 2.6,
         "rooms": [{"name": "a", "polygon": ROOM}, {"name": "b", "polygon": [[x + 6, y] for x, y in ROOM]}],
         "openings": [{"from": [1, 0], "to": [1.9, 0], "height": 2.0}, {"from": [7, 0], "to": [7.9, 0], "height": 2.0}]}
# the same home with room b turned into an L by a wall closet: nothing looks like room a
ODD = {**TWINS, "rooms": [{"name": "a", "polygon": ROOM},
                          {"name": "b", "polygon": [[6, 0], [10, 0], [10, 1.8], [8.8, 1.8], [8.8, 3], [6, 3]]}]}


def _answers(plan: dict, truth: np.ndarray):
    m = floor_plan_model(plan)
    q = unpack(render_panoramas(m.segments, m.faces, truth, width=W, height=H, hidden=True), H, W)
    poses, _ = plan_grid(m, x=[0.25, 10.0, 0.25], y=[0.25, 3.0, 0.25], z=1.4, headings=[0.0], inside_only=True)
    imgs = unpack(render_panoramas(m.segments, m.faces, poses, width=W, height=H, hidden=True), H, W)
    pp = replace(PanoramaParams(), orientation_bins=1)
    wts = row_weights(H, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
    db = {"spectra": chamfer_spectra(imgs, tau_px=pp.chamfer_tau_px, weights=wts)}
    return search_panoramas(q, poses, m.segments, m.faces, db, pp, tolerance_px=2, wall_margin_m=0.1, hidden=True)


def test_margin_is_zero_in_a_twin_room_and_clear_in_a_room_of_its_own():
    # Cameras in room a, off the grid. With a twin room b the same spot there is a rival as
    # good as the answer (margin 0, to float rounding: the twin's grid and search points are
    # the answer's moved by 6 m, a whole number of steps); with room b changed, the answer
    # stands clear of every other place and heading.
    truth = np.array([[1.37, 1.12, 1.4, 40.0], [2.81, 2.2, 1.4, 200.0]])
    twins = _answers(TWINS, truth)
    assert np.all(np.isfinite(twins.rival))
    assert np.abs(twins.margin).max() <= 1e-4, twins.margin
    # the rival is the same spot in the other room, facing the same way: the answer's
    # alternative is the twin's (one of the two is the truth)
    twin_of = twins.xy + np.where(twins.xy[:, :1] < 5.0, 6.0, -6.0) * np.array([1.0, 0.0])
    assert np.hypot(*(twins.rival_xy - twin_of).T).max() <= 0.1, (twins.rival_xy, twins.xy)
    assert np.abs((twins.rival_heading - twins.heading + 180.0) % 360.0 - 180.0).max() <= 5.0
    odd = _answers(ODD, truth)
    assert np.hypot(*(odd.xy - truth[:, :2]).T).max() <= 0.05
    assert odd.margin.min() >= 0.05, odd.margin
    assert np.all(odd.rival < odd.score)


def _photo_config(d, plan: dict, truth: tuple, photo: str, with_truth: bool):
    """A folder ``d`` holding ``plan``, one grey panorama ``photo`` of its lines seen from
    ``truth`` (x, y, z, heading) and, ``with_truth``, its poses.csv; the UMap config over it
    (a 0.25 m grid, the plain score)."""
    import cv2
    import yaml

    from placeloc.core.config import load_config

    (d / "q").mkdir(parents=True)
    (d / "plan.yaml").write_text(yaml.safe_dump(plan))
    m = floor_plan_model(plan)
    lines = unpack(render_panoramas(m.segments, m.faces, np.array([truth]), width=512, height=256, hidden=True),
                   256, 512)[0]
    cv2.imwrite(str(d / "q" / photo), np.where(cv2.dilate(lines, np.ones((2, 2), np.uint8)) > 0, 60, 190)
                .astype(np.uint8))
    data = {"method": "umap", "query": {"images": str(d / "q")},
            "umap": {"model": str(d / "plan.yaml"), "query_kind": "panorama",
                     "grid": {"x": [0.25, 10.0, 0.25], "y": [0.25, 3.0, 0.25], "z": 1.4, "headings": [0.0]},
                     "panorama": {"orientation_bins": 1}}}
    if with_truth:
        (d / "poses.csv").write_text(f"frame,x,y,heading_deg\n{photo},{truth[0]:.2f},{truth[1]:.2f},{truth[3]:.1f}\n")
        data.update({"ground_truth": {"kind": "poses", "path": str(d / "poses.csv")}, "plots": False})
    return load_config(data=data, base_dir=d)


def test_answers_in_a_twin_room_are_marked_doubtful_end_to_end(tmp_path, caplog, monkeypatch):
    # Through the pipeline: a panorama taken in one of two identical rooms is marked doubtful
    # in estimates.csv and named in the log, its rival is the same spot in the other room
    # (estimates.csv, and the poses contract's alternative), and evaluate counts the answer
    # or its rival right; in the home where room b differs, none of that.
    import csv
    import json
    import logging

    from placeloc.core.runner import run_stage
    from placeloc.evaluation.contracts import read_result
    from placeloc.umap import stages

    monkeypatch.setattr(stages, "_ADVISED", [])   # the room_hints advice is said once a process
    truth = (1.37, 1.12, 1.4, 40.0)
    for name, plan in (("twins", TWINS), ("odd", ODD)):
        d = tmp_path / name
        cfg = _photo_config(d, plan, truth, "p0.png", with_truth=True)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="placeloc"):
            run_stage(cfg, d / "run", "evaluate", quiet=True)
        (row,) = list(csv.DictReader(open(d / "run" / "estimates.csv")))
        doubtful = name == "twins"
        assert row["doubtful"] == ("true" if doubtful else "false"), row
        assert (float(row["margin"]) < PanoramaParams().doubtful_margin) == doubtful
        assert ("1 of 1 answers are doubtful" in caplog.text) == doubtful
        est, rival = np.array([float(row["x"]), float(row["y"])]), np.array([float(row["rival_x"]), float(row["rival_y"])])
        result = read_result(d / "run" / "localize.h5")
        alternative = result.get("alternative")
        # what the plan picture draws: the openings as gaps, each room's name inside it from its top left
        assert np.allclose(result["plan_openings"], [[1, 0, 1.9, 0], [7, 0, 7.9, 0]])
        assert result["plan_labels"] == ["a", "b"]
        x0 = {"a": 0.0, "b": 6.0}
        for label, (lx, ly) in zip(result["plan_labels"], result["plan_label_xy"]):
            assert 0.25 <= lx - x0[label] <= 0.35 and ly == pytest.approx(2.7), (label, lx, ly)
        metrics = json.loads((d / "run" / "metrics.json").read_text())
        if doubtful:
            # the answer and its rival are in the two rooms, named as the plan names them
            assert {row["room"], row["rival_room"]} == {"a", "b"}, row
            assert f"p0.png ({row['room']}, or {row['rival_room']})" in caplog.text
            # the two places in two rooms: the log says how to settle it, once a process
            assert "you know the room it was taken in, name it in umap.room_hints" in caplog.text
            assert stages._ADVISED == [True]
            # the rival is the answer's spot moved into the other room, and is the contract's alternative
            assert np.hypot(*(rival - est - [6.0 if est[0] < 5.0 else -6.0, 0.0])) <= 0.1, row
            assert np.allclose(alternative, [[round(v, 3) for v in rival]], atol=1e-3)
            # one of the two is where the camera stood
            assert (metrics["doubtful_answers"], metrics["within_1m_30deg_or_rival"]) == (1, 1.0)
            assert metrics["doubtful_wrong"] == metrics["doubtful_wrong_rival_right"] == int(est[0] > 5.0)
            # the camera stood in room a: the answer's room is right where the answer is
            assert (metrics["room_right"], metrics["room_frames"]) == (float(est[0] < 5.0), 1)
        else:
            assert np.isnan(alternative).all()
            assert "umap.room_hints" not in caplog.text
            assert (metrics["doubtful_answers"], metrics["doubtful_wrong"]) == (0, 0)
            assert metrics["within_1m_30deg_or_rival"] == metrics["within_1m_30deg"] == 1.0
            assert (metrics["room_right"], metrics["room_frames"]) == (1.0, 1)


def test_show_of_a_photo_without_truth_draws_its_lines_against_the_map_at_the_answer(tmp_path):
    # `placeloc show` of a panorama located without ground truth: its detected lines against
    # the map at its answer (red), and where the answer is doubtful (the twin rooms) at its
    # rival too (green; brown where both draw a line: the twins' views are alike); report.html
    # lists the answer. A home whose rooms differ: no green.
    import cv2

    from placeloc.core.runner import run_stage
    from placeloc.evaluation.show import show_run

    truth = (1.37, 1.12, 1.4, 40.0)
    for name, plan in (("twins", TWINS), ("odd", ODD)):
        d = tmp_path / name
        cfg = _photo_config(d, plan, truth, "my photo.png", with_truth=False)
        run_stage(cfg, d / "run", "localize", quiet=True)
        pictures, report = show_run(d / "run")
        assert sorted(p.name for p in pictures) == ["estimates_on_plan.png", "panorama_my photo.png"]
        img = np.asarray(cv2.imread(str(d / "run" / "panorama_my photo.png")))[..., ::-1].astype(int)
        red = (np.abs(img - [217, 26, 26]).sum(axis=2) < 40).sum()
        green = (np.abs(img - [26, 166, 26]).sum(axis=2) < 40).sum()
        brown = (np.abs(img - [140, 89, 0]).sum(axis=2) < 40).sum()     # both: the twin's view is the answer's
        assert red + brown > 500
        assert (green + brown > 500) == (name == "twins"), (name, green, brown)
        assert "<td>my photo.png</td>" in report.read_text()
