"""Known answers for the search near a place (``placeloc.umap.panorama.search_near``), the
diagnostic that tells a wrong answer's score failure from its search failure, and the line
the homes experiment writes from it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_umap_panorama import PLAN, H, _render_all

from placeloc.experiments.umap_homes import cause_line
from placeloc.geometry.floorplan import floor_plan_model, plan_grid
from placeloc.umap.panorama import chamfer_spectra, row_weights, search_near, search_panoramas
from placeloc.umap.params import PanoramaParams


def test_search_near_the_truth_ends_where_the_whole_search_does():
    # Two cameras of the L-shaped room, a few line pixels lost. The whole search (a 0.3 m
    # grid over the room) and the search over a 0.25 m grid within 1 m of the truth only (its
    # own database, drawn on the spot) end at the same pose to the bit: the final search
    # starts from the plan's own lattice, whichever grid the beam came from. Near a place
    # 2.5 m away the best score is lower: there the truth's score wins.
    m = floor_plan_model(PLAN)
    truth = np.array([[1.234, 2.871, 1.4, 75.0], [4.71, 3.13, 1.4, 300.0]])
    q = _render_all(m, truth)
    q[:, ::3, ::4] = 0
    pp = replace(PanoramaParams(), orientation_bins=1)
    wts = row_weights(H, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
    poses, _ = plan_grid(m, x=[0.15, 6.0, 0.3], y=[0.15, 7.0, 0.3], z=1.4, headings=[0.0])
    db = {"spectra": chamfer_spectra(_render_all(m, poses), tau_px=pp.chamfer_tau_px, weights=wts)}
    whole = search_panoramas(q, poses, m.segments, m.faces, db, pp, tolerance_px=2, wall_margin_m=0.1, hidden=True)
    kw = {"radius_m": 1.0, "step_m": 0.25, "z": 1.4, "tolerance_px": 2, "wall_margin_m": 0.1, "hidden": True}
    for i, t in enumerate(truth):
        near = search_near(q[i:i + 1], t[:2], m, pp, **kw)
        assert np.hypot(*(near.xy[0] - t[:2])) <= 0.01
        assert np.array_equal(near.xy[0], whole.xy[i]) and near.score[0] == whole.score[i]
        assert near.heading[0] == whole.heading[i]
    away = search_near(q[:1], truth[0, :2] + [2.5, 0.0], m, pp, **kw)
    assert np.hypot(*(away.xy[0] - truth[0, :2])) > 1.0 and away.score[0] < whole.score[0] - 0.05


def test_search_near_names_what_is_wrong_with_its_input():
    m = floor_plan_model(PLAN)
    q = _render_all(m, np.array([[1.0, 1.0, 1.4, 0.0]]))
    pp = replace(PanoramaParams(), orientation_bins=1)
    kw = {"radius_m": 1.0, "step_m": 0.25, "tolerance_px": 2, "wall_margin_m": 0.1, "hidden": True}
    with pytest.raises(ValueError, match=r"no free grid position .* within 1 m of \(20.00, 20.00\) at 0.25 m"):
        search_near(q, np.array([20.0, 20.0]), m, pp, z=1.4, **kw)
    assert m.camera_z is None                            # the plan gives no camera height
    with pytest.raises(ValueError, match=r"no camera height \(camera_z\): pass z"):
        search_near(q, np.array([1.0, 1.0]), m, pp, z=None, **kw)
    with pytest.raises(ValueError, match=r"camera height 3.0 m lies outside the storey .* ceiling 2.6 m"):
        search_near(q, np.array([1.0, 1.0]), m, pp, z=3.0, **kw)


def test_cause_line_by_hand():
    causes = {20: [], 21: [("pano_016.png", 0.3867, 0.3720)], 24: [("pano_003.png", 0.40, 0.45), ("pano_015.png", 0.5, 0.49)]}
    line = cause_line(causes, origin=0.0)
    assert line == ("Wrong test answers at grid origin 0, searched again over the grid within 1 m of the truth: "
                    "2 of 3 are the score's (the best pose there scores below the answer, by 0.0100-0.0147: "
                    "home 21 pano_016.png, home 24 pano_015.png); the search's (a better pose near the truth was "
                    "missed): home 24 pano_003.png.")
    assert cause_line({20: [], 21: []}, origin=0.0) == "Wrong test answers at grid origin 0: none."
    assert "by 0.0147: home 21" in cause_line({21: [("pano_016.png", 0.3867, 0.3720)]}, origin=0.0)


def test_the_quick_homes_experiment_explains_its_wrong_answers_and_drops_its_indexes(tmp_path):
    # `placeloc experiment umap-homes --quick`: one development home at one origin, two test
    # homes, and those again with each photo's room named. Every wrong test answer at the
    # first origin is in summary.json with the best score near its truth, the table's line
    # counts them, and no run folder keeps its index
    import csv
    import json

    from placeloc.experiments.umap_homes import main

    summary = json.loads(main(tmp_path, quick=True, quiet=True).read_text())
    causes = summary["wrong_answer_causes"]
    for seed, listed in causes.items():
        with open(tmp_path / f"home{seed}-origin0" / "per_query.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        wrong = {r["frame"]: float(r["score"]) for r in rows
                 if not (float(r["error_m"]) <= 1.0 and float(r["yaw_error_deg"]) <= 30.0)}
        assert {c["frame"]: c["score"] for c in listed} == wrong
    every = [c for listed in causes.values() for c in listed]
    table = (tmp_path / "table.md").read_text()
    if every:
        n_score = sum(c["best_near_truth"] < c["score"] for c in every)
        assert f"{n_score} of {len(every)} are the score's" in table
    else:
        assert "Wrong test answers at grid origin 0: none." in table
    assert list(tmp_path.glob("*/index.h5")) == []
    assert len(list(tmp_path.glob("*/localize.h5"))) == 5
    # the test homes' table says how often the answer is in the camera's room (worst / median over the runs)
    rooms = sorted(summary[f"home{s}-origin0-panorama-chamfer"]["room_right"] for s in (20, 21))
    assert f"| {rooms[0]:.0%} / {np.median(rooms):.0%} |" in table
    # the test homes again with each photo's room named: a line of the table, and the map
    # linked from the plain run's folder, not drawn again
    assert "With each test photo's room named (umap.room_hints, the room at its true position): within 1 m" in table
    assert (tmp_path / "home20-origin0-rooms" / "build-dictionary.h5").samefile(tmp_path / "home20-origin0" /
                                                                               "build-dictionary.h5")
    assert summary["home20-origin0-rooms"]["within_1m_30deg"] >= summary["home20-origin0-panorama-chamfer"]["within_1m_30deg"]
