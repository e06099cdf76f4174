"""Which panoramas get a picture (``panorama_<name>.png``): the wrong answers first, then the
doubtful ones, then the others spread over the run, at most
:data:`placeloc.umap.pictures.PANORAMA_PICTURES`; never simply the first ones."""

from __future__ import annotations

import numpy as np
import yaml

from placeloc.umap import pictures
from placeloc.umap.pictures import panorama_caption, pictured_panoramas, ranked_panoramas

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


def _by_hand() -> dict:
    """The run of :func:`test_pictured_panoramas_by_hand`: frames 16, 19 and 25 wrong (13.2,
    3.7 and 5.7 m off) and doubtful (margin 0.1), frames 3 and 30 doubtful too."""
    wrong, err = np.zeros(32, bool), np.zeros(32)
    wrong[[16, 19, 25]], err[[16, 19, 25]] = True, [13.2, 3.7, 5.7]
    doubtful, margin = np.zeros(32, bool), np.full(32, 0.1)
    doubtful[[3, 16, 19, 25, 30]], margin[[3, 30]] = True, [0.015, 0.001]
    return {"wrong": wrong, "error_m": err, "doubtful": doubtful, "margin": margin}


def test_the_order_chosen_and_show_s_counts_by_hand():
    # the order report.html shows: the wrong ones by error (16: 13.2 m, 25: 5.7 m, 19: 3.7 m),
    # the other doubtful ones by margin (30: 0.001, 3: 0.015), then the 7 spread (frame order)
    known = _by_hand()
    assert ranked_panoramas(32, **known) == [16, 25, 19, 30, 3, 0, 5, 10, 14, 20, 26, 31]
    # show --failures 3 --sample 0: the wrong answers only
    assert ranked_panoramas(32, **known, failures=3, sample=0) == [16, 25, 19]
    # --failures 2 --sample 3: the third wrong one (19, margin 0.1) comes among the doubtful
    # ones, after those of smaller margin
    assert ranked_panoramas(32, **known, failures=2, sample=3) == [16, 25, 30, 3, 19]
    # --failures 0 --sample 2: the doubtful ones by margin, wrong or not
    assert ranked_panoramas(32, **known, failures=0, sample=2) == [30, 3]
    # more asked for than there are: every frame once
    got = ranked_panoramas(32, **known, failures=2, sample=40)
    assert got[:2] == [16, 25] and sorted(got) == list(range(32))
    # each picture's caption
    words = {k: panorama_caption(k, **known, yaw_error_deg=np.zeros(32)) for k in (16, 30, 0)}
    assert words == {16: "wrong: 13.20 m off; doubtful: margin 0.1", 30: "right: under 0.01 m off; doubtful: margin 0.001",
                     0: "right: under 0.01 m off"}
    # the right place at the wrong heading; no truth at all
    assert panorama_caption(0, wrong=np.array([True]), error_m=np.array([0.3]),
                            yaw_error_deg=np.array([95.0])) == "wrong: heading 95 deg off"
    assert panorama_caption(3, doubtful=known["doubtful"], margin=known["margin"]) == "doubtful: margin 0.015"
    assert panorama_caption(0, doubtful=known["doubtful"], margin=known["margin"]) == ""


def _three_photos(d, with_truth: bool = True):
    """Three grey panoramas of the L-shaped room's lines in ``d``/q, each localized within
    centimetres; the ground truth of the last one (c.png) is put 3 m away, so its answer is
    the one wrong. The config, with that truth or (``with_truth`` False) none."""
    import cv2

    from placeloc.core.config import load_config
    from placeloc.geometry.floorplan import floor_plan_model
    from placeloc.geometry.panorama import render_panoramas
    from placeloc.umap.bits import unpack

    (d / "q").mkdir(parents=True)
    (d / "plan.yaml").write_text(yaml.safe_dump(PLAN))
    m = floor_plan_model(PLAN)
    truth = [("a.png", 1.3, 2.2, 75.0), ("b.png", 4.6, 1.9, 200.0), ("c.png", 1.8, 5.5, 300.0)]
    for name, x, y, heading in truth:
        lines = unpack(render_panoramas(m.segments, m.faces, np.array([[x, y, 1.5, heading]]), width=512, height=256,
                                        hidden=True), 256, 512)[0]
        cv2.imwrite(str(d / "q" / name), np.where(cv2.dilate(lines, np.ones((2, 2), np.uint8)) > 0, 60, 190)
                    .astype(np.uint8))
    told = [(n, x, y + (3.0 if n == "c.png" else 0.0), h) for n, x, y, h in truth]
    (d / "poses.csv").write_text("frame,x,y,heading_deg\n" + "".join(f"{n},{x},{y},{h}\n" for n, x, y, h in told))
    gt = {"kind": "poses", "path": str(d / "poses.csv")} if with_truth else {"kind": "none"}
    return load_config(data={"method": "umap", "query": {"images": str(d / "q")}, "ground_truth": gt,
                             "umap": {"model": str(d / "plan.yaml"), "query_kind": "panorama",
                                      "grid": {"x": [0.15, 6.0, 0.3], "y": [0.15, 7.0, 0.3], "headings": [0.0], "z": 1.5},
                                      "panorama": {"orientation_bins": 1}},
                             "plots": True}, base_dir=d)


def test_evaluate_draws_the_wrong_answer_past_the_first_frames(tmp_path, monkeypatch):
    # With one picture allowed, evaluate draws the wrong answer's (c.png), not the first
    # frame's, and its title gives the error.
    from placeloc.core.runner import run_stage

    monkeypatch.setattr(pictures, "PANORAMA_PICTURES", 1)
    run = tmp_path / "run"
    run_stage(_three_photos(tmp_path), run, "evaluate", quiet=True)
    rows = {r.split(",")[0]: r.split(",") for r in (run / "per_query.csv").read_text().splitlines()[1:]}
    assert float(rows["c.png"][7]) > 2.5 and max(float(rows[n][7]) for n in ("a.png", "b.png")) < 0.1, rows
    assert sorted(p.name for p in run.glob("panorama_*.png")) == ["panorama_c.png"]


def _listed(html: str) -> list[tuple[str, str]]:
    """(file name, caption) of each panorama picture a report.html embeds, in its order."""
    import re

    return re.findall(r"<h3>(panorama_[^<]*?)(?:<span class='why'>([^<]*)</span>)?</h3>", html)


def test_report_and_show_put_the_wrong_answer_first(tmp_path, caplog):
    # evaluate's report.html: c.png (the wrong answer, 3 m off) first with its error, then a
    # and b (name order put c last); `placeloc show` keeps that choice, its --failures and
    # --sample choose again, and its report shows only what they chose
    import logging

    from placeloc.core.runner import run_stage
    from placeloc.evaluation.show import show_run

    run = tmp_path / "run"
    run_stage(_three_photos(tmp_path), run, "evaluate", quiet=True)
    html = (run / "report.html").read_text()
    got = _listed(html)
    assert [n for n, _ in got] == ["panorama_c.png", "panorama_a.png", "panorama_b.png"], got
    # its caption the error per_query.csv gives (the truth is 3 m off; the answer within centimetres of the photo)
    error_c = next(float(r.split(",")[7]) for r in (run / "per_query.csv").read_text().splitlines() if r.startswith("c.png"))
    assert got[0][1] == f"wrong: {error_c:.2f} m off" and 2.9 < error_c < 3.1, got
    assert all(why.startswith("right: ") for _, why in got[1:]), got
    assert "the wrong answers first (the largest error first)" in html

    def shown(**options):
        pictures, report = show_run(run, **options)
        return [p.name for p in pictures if p.name.startswith("panorama_")], _listed(report.read_text())

    # no option: evaluate's pictures stand (none drawn again), in evaluate's order
    assert shown() == ([], got)
    # only the wrong answers
    assert shown(failures=5, sample=0) == (["panorama_c.png"], got[:1])
    # one spread over the run and no failures: the first frame (none is doubtful)
    assert shown(failures=0, sample=1) == (["panorama_a.png"], [got[1]])
    # drawn again by show, evaluate's picture to the byte: left as evaluate recorded it
    assert not (run / "show" / "panorama_a.png").exists()

    # without ground truth nothing is known wrong: --failures says so, and the pictures are
    # --sample's (none doubtful here: spread, a and b)
    bare = tmp_path / "bare"
    run_stage(_three_photos(bare, with_truth=False), bare / "run", "localize", quiet=True)
    with caplog.at_level(logging.WARNING, logger="placeloc"):
        pictures, report = show_run(bare / "run", failures=2, sample=2)
    assert "--failures 2:" in caplog.text and "no answer is known wrong" in caplog.text
    assert [p.name for p in pictures if p.name.startswith("panorama_")] == ["panorama_a.png", "panorama_c.png"]
    assert _listed(report.read_text()) == [("panorama_a.png", ""), ("panorama_c.png", "")]
