"""Which panoramas get a picture (``panorama_<name>.png``): the wrong answers first, then the
doubtful ones, then the others spread over the run, at most
:data:`placeloc.umap.stages.PANORAMA_PICTURES`; never simply the first ones."""

from __future__ import annotations

import numpy as np
import yaml

from placeloc.umap import stages
from placeloc.umap.stages import pictured_panoramas

# the L-shaped room of tests/test_umap_panorama.py
PLAN = {"floor_z": 0.0, "ceiling_z": 2.6, "outline": [[0, 0], [6, 0], [6, 4], [3.5, 4], [3.5, 7], [0, 7]],
        "doors": [{"from": [2, 0], "to": [2.9, 0], "height": 2.0}, {"from": [0, 5], "to": [0, 5.9], "height": 2.0}]}


def test_pictured_panoramas_by_hand():
    # nothing known: 12 of 32 spread evenly, round(31 k / 11) for k = 0..11
    assert pictured_panoramas(32) == [0, 3, 6, 8, 11, 14, 17, 20, 23, 25, 28, 31]
    assert pictured_panoramas(5) == [0, 1, 2, 3, 4] and pictured_panoramas(0) == []
    # three wrong answers at frames 16, 19 and 25 (off by the real home's three errors, 13.2,
    # 3.7 and 5.7 m), all doubtful, and two more doubtful ones (frames 3 and 30): all five are
    # drawn, and the
    # other 7 pictures go to frames spread over the 27 left (their positions 0, 4, 9, 13,
    # 17, 22, 26: frames 0, 5, 10, 14, 20, 26, 31)
    wrong, err = np.zeros(32, bool), np.zeros(32)
    wrong[[16, 19, 25]], err[[16, 19, 25]] = True, [13.2, 3.7, 5.7]
    doubtful, margin = np.zeros(32, bool), np.full(32, 0.1)
    doubtful[[3, 16, 19, 25, 30]], margin[[3, 30]] = True, [0.015, 0.001]
    got = pictured_panoramas(32, wrong=wrong, error_m=err, doubtful=doubtful, margin=margin)
    assert got == [0, 3, 5, 10, 14, 16, 19, 20, 25, 26, 30, 31]
    # too few pictures: the largest errors first, then the smallest margins
    assert pictured_panoramas(32, wrong=wrong, error_m=err, doubtful=doubtful, margin=margin, limit=2) == [16, 25]
    assert pictured_panoramas(32, wrong=wrong, error_m=err, doubtful=doubtful, margin=margin, limit=4) == [16, 19, 25, 30]
    # no truth: the doubtful ones first; a doubtful answer without a margin after those with one
    assert pictured_panoramas(32, doubtful=doubtful, margin=margin, limit=3) == [3, 16, 30]
    assert pictured_panoramas(3, doubtful=np.array([True, True, False]), margin=np.array([np.nan, 0.01, 0.5]),
                              limit=1) == [1]


def test_evaluate_draws_the_wrong_answer_past_the_first_frames(tmp_path, monkeypatch):
    # Three grey panoramas of the L-shaped room's lines, each localized within centimetres;
    # the ground truth of the last one is put 3 m away, so its answer is the one wrong.
    # With one picture allowed, evaluate draws that answer's, not the first frame's, and
    # its title gives the error.
    import cv2

    from placeloc.core.config import load_config
    from placeloc.core.runner import run_stage
    from placeloc.geometry.floorplan import floor_plan_model
    from placeloc.geometry.panorama import render_panoramas
    from placeloc.umap.bits import unpack

    (tmp_path / "q").mkdir()
    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(PLAN))
    m = floor_plan_model(PLAN)
    truth = [("a.png", 1.3, 2.2, 75.0), ("b.png", 4.6, 1.9, 200.0), ("c.png", 1.8, 5.5, 300.0)]
    for name, x, y, heading in truth:
        lines = unpack(render_panoramas(m.segments, m.faces, np.array([[x, y, 1.5, heading]]), width=512, height=256,
                                        hidden=True), 256, 512)[0]
        cv2.imwrite(str(tmp_path / "q" / name), np.where(cv2.dilate(lines, np.ones((2, 2), np.uint8)) > 0, 60, 190)
                    .astype(np.uint8))
    told = [(n, x, y + (3.0 if n == "c.png" else 0.0), h) for n, x, y, h in truth]
    (tmp_path / "poses.csv").write_text("frame,x,y,heading_deg\n" + "".join(f"{n},{x},{y},{h}\n" for n, x, y, h in told))
    cfg = load_config(data={"method": "umap", "query": {"images": str(tmp_path / "q")},
                            "ground_truth": {"kind": "poses", "path": str(tmp_path / "poses.csv")},
                            "umap": {"model": str(tmp_path / "plan.yaml"), "query_kind": "panorama",
                                     "grid": {"x": [0.15, 6.0, 0.3], "y": [0.15, 7.0, 0.3], "headings": [0.0], "z": 1.5},
                                     "panorama": {"orientation_bins": 1}},
                            "plots": True}, base_dir=tmp_path)
    monkeypatch.setattr(stages, "PANORAMA_PICTURES", 1)
    run = tmp_path / "run"
    run_stage(cfg, run, "evaluate", quiet=True)
    rows = {r.split(",")[0]: r.split(",") for r in (run / "per_query.csv").read_text().splitlines()[1:]}
    assert float(rows["c.png"][7]) > 2.5 and max(float(rows[n][7]) for n in ("a.png", "b.png")) < 0.1, rows
    assert sorted(p.name for p in run.glob("panorama_*.png")) == ["panorama_c.png"]
