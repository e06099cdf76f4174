"""The ``poses`` contract's optional per-answer confidence: how well it ranks right answers
above wrong ones (kept at 100 % precision, average precision), the tie and NaN rules,
per_query.csv's last column, confidence.png, and results without a confidence scored
exactly as before the field existed."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
from PIL import Image

from placeloc.evaluation import pose_estimates as pe
from placeloc.evaluation import write_metrics
from placeloc.evaluation.contracts import ContractError, ordered, read_result, report_parts, validate
from placeloc.evaluation.report import write_report

NAN = float("nan")


# ------------------------------------------------------------------ the numbers by hand
def test_metrics_by_hand_with_a_tie_and_a_nan():
    # frames:      A    B    C    D    E    F
    conf = np.array([0.9, 0.7, 0.7, 0.5, NAN, 0.2])
    right = np.array([True, True, False, True, True, False])
    # runs, highest first (B and C tie: kept together; E has no confidence: last):
    #   0.9 {A}   kept 1, right 1, precision 1
    #   0.7 {B,C} kept 3, right 2, precision 2/3
    #   0.5 {D}   kept 4, right 3, precision 3/4
    #   0.2 {F}   kept 5, right 3, precision 3/5
    #   NaN {E}   kept 6, right 4, precision 4/6
    curve = pe.confidence_curve(conf, right)
    assert curve.kept.tolist() == [1, 3, 4, 5, 6] and curve.right.tolist() == [1, 2, 3, 3, 4]
    assert np.allclose(curve.threshold[:4], [0.9, 0.7, 0.5, 0.2]) and np.isnan(curve.threshold[4])
    m = pe.confidence_metrics(conf, right)
    # only the first run is all right: 1 of 6 frames, at confidence 0.9
    assert m["kept_at_100_precision"] == pytest.approx(1 / 6)
    assert m["confidence_threshold_at_100_precision"] == pytest.approx(0.9)
    # 4 right answers; each run's precision weighted by the right answers it adds (1, 1, 1, 0, 1):
    # (1 + 2/3 + 3/4 + 4/6) / 4 = (12 + 8 + 9 + 8) / 48 = 37/48
    assert m["confidence_average_precision"] == pytest.approx(37 / 48)
    assert m["n_without_confidence"] == 1
    # the frames' order in the result does not matter
    perm = np.array([5, 2, 4, 0, 3, 1])
    assert pe.confidence_metrics(conf[perm], right[perm]) == pytest.approx(m)


def test_a_threshold_cannot_split_a_tie():
    # the right and the wrong answer share 0.8: keeping the right one keeps the wrong one too
    m = pe.confidence_metrics(np.array([0.8, 0.8, 0.3]), np.array([True, False, True]))
    assert m["kept_at_100_precision"] == 0.0 and m["confidence_threshold_at_100_precision"] is None
    # runs: {0.8} kept 2 right 1 (1/2), {0.3} kept 3 right 2 (2/3): AP = (1/2 + 2/3) / 2 = 7/12
    assert m["confidence_average_precision"] == pytest.approx(7 / 12)
    # the right one a little more confident: a threshold keeps it alone
    m = pe.confidence_metrics(np.array([0.81, 0.8, 0.3]), np.array([True, False, True]))
    assert m["kept_at_100_precision"] == pytest.approx(1 / 3) and m["confidence_threshold_at_100_precision"] == 0.81
    # (1 + 2/3) / 2
    assert m["confidence_average_precision"] == pytest.approx(5 / 6)


def test_nan_ranks_below_every_finite_value():
    # the NaN frame is right, the finite one wrong: ranked last, the NaN cannot be kept alone
    m = pe.confidence_metrics(np.array([NAN, -1e9]), np.array([True, False]))
    assert m["kept_at_100_precision"] == 0.0
    assert m["confidence_average_precision"] == pytest.approx(0.5)  # the one right answer at precision 1/2
    # frames without a confidence form one run, kept together: all right keeps every frame,
    # and the lowest confidence kept is none
    m = pe.confidence_metrics(np.array([0.4, NAN, NAN]), np.array([True, True, True]))
    assert m["kept_at_100_precision"] == 1.0 and m["confidence_threshold_at_100_precision"] is None
    assert m["confidence_average_precision"] == 1.0 and m["n_without_confidence"] == 2
    m = pe.confidence_metrics(np.array([0.4, NAN, NAN]), np.array([True, True, False]))
    assert m["kept_at_100_precision"] == pytest.approx(1 / 3) and m["confidence_threshold_at_100_precision"] == 0.4
    assert m["confidence_average_precision"] == pytest.approx((1 + 2 / 3) / 2)


def test_a_confidence_that_says_nothing_and_no_right_answer():
    right = np.array([True, False, False, True, False])
    m = pe.confidence_metrics(np.full(5, 0.3), right)
    # one run: average precision is the share right, nothing kept at 100 %
    assert m["confidence_average_precision"] == pytest.approx(2 / 5) and m["kept_at_100_precision"] == 0.0
    m = pe.confidence_metrics(np.array([0.9, 0.1]), np.array([False, False]))
    assert m["confidence_average_precision"] is None and m["kept_at_100_precision"] == 0.0
    assert m["confidence_threshold_at_100_precision"] is None


def test_right_means_1m_and_30deg_or_1m_without_headings():
    err = np.array([0.2, 1.0, 1.01, 0.1])
    yaw = np.array([5.0, 30.0, 0.0, 31.0])
    assert pe.right_answers(err, yaw).tolist() == [True, True, False, False]
    assert pe.right_answers(err, None).tolist() == [True, True, False, True]


# ------------------------------------------------------------------ the contract
def test_contract_validation_of_the_confidence():
    ok = {"names": ["a", "b"], "x": np.zeros(2), "y": np.zeros(2), "heading_deg": np.zeros(2), "score": np.zeros(2)}
    validate("poses", {**ok, "confidence": np.array([0.5, NAN])})
    with pytest.raises(ContractError, match="'confidence' has Q = 3, another dataset 2"):
        validate("poses", {**ok, "confidence": np.zeros(3)})
    with pytest.raises(ContractError, match="'confidence' has 2 dimensions"):
        validate("poses", {**ok, "confidence": np.zeros((2, 1))})
    with pytest.raises(ContractError, match="'confidence' holds int64"):
        validate("poses", {**ok, "confidence": np.zeros(2, np.int64)})


NAMES = [f"p{k}.jpg" for k in range(6)]
TRUTH = np.array([[0, 0], [1, 0], [2, 0], [3, 0], [4, 0], [5, 0]], float)
HEADING = np.array([0, 90, 180, -90, 45, 10], float)
# errors 0.2, 0.949, 3.0, 0.1, 0.5, 1.5 m; yaw errors 5, 10, 0, 40, 20, 100 deg:
# right within 1 m and 30 deg: p0 p1 p4; within 1 m alone: p0 p1 p3 p4
EST_X = TRUTH[:, 0] + np.array([0.2, 0.9, 3.0, 0.1, 0.0, 1.5])
EST_Y = TRUTH[:, 1] + np.array([0.0, 0.3, 0.0, 0.0, 0.5, 0.0])
EST_HEADING = HEADING + np.array([5, 10, 0, 40, -20, 100])

# what per_query.csv and metrics.json held for this result before the confidence existed
# (placeloc at 932e139), byte for byte
BEFORE_CSV = """frame,x,y,heading_deg,true_x,true_y,true_heading_deg,error_m,yaw_error_deg,score\r
p0.jpg,0.200,0.000,5.0,0.000,0.000,0.0,0.200,5.0,0.30000\r
p1.jpg,1.900,0.300,100.0,1.000,0.000,90.0,0.949,10.0,0.40000\r
p2.jpg,5.000,0.000,180.0,2.000,0.000,180.0,3.000,0.0,0.50000\r
p3.jpg,3.100,0.000,-50.0,3.000,0.000,-90.0,0.100,40.0,0.60000\r
p4.jpg,4.000,0.500,25.0,4.000,0.000,45.0,0.500,20.0,0.70000\r
p5.jpg,6.500,0.000,110.0,5.000,0.000,10.0,1.500,100.0,0.80000\r
"""
BEFORE_METRICS = {"within_1m_30deg": 0.5, "within_0_5m": 0.5, "within_1m": 0.6666666666666666,
                  "within_2m": 0.8333333333333334, "median_error_m": 0.7243416490252569, "max_error_m": 3.0,
                  "mean_error_m": 1.0414472163417523, "median_yaw_error_deg": 15.0, "yaw_within_10deg": 0.5,
                  "yaw_within_30deg": 0.6666666666666666, "within_0_5m_30deg": 0.3333333333333333,
                  "within_2m_30deg": 0.5, "n_frames": 6,
                  "headline": ["within_1m_30deg", "within_0_5m", "within_1m", "within_2m", "median_error_m",
                               "seconds_per_frame"]}


def _evaluate(tmp: Path, *, headings: bool = True, plots: bool = False, **extra) -> tuple[pe.PoseEvaluation, Path]:
    """Write the result through ``pose_estimates.write`` (as localize does), read it back
    and run the contract's evaluate and finish into ``tmp``."""
    tmp.mkdir(parents=True, exist_ok=True)
    rows = "".join(f"{n},{x:g},{y:g}" + (f",{h:g}" if headings else "") + "\n" for n, (x, y), h in zip(NAMES, TRUTH, HEADING))
    (tmp / "poses.csv").write_text("name,x,y" + (",heading_deg" if headings else "") + "\n" + rows)
    with h5py.File(tmp / "localize.h5", "w") as f:
        pe.write(SimpleNamespace(out=f), names=NAMES, x=EST_X, y=EST_Y, heading_deg=EST_HEADING,
                 score=np.linspace(0.3, 0.8, 6), plan_segments=np.array([[0, -1, 6, -1], [0, 1, 6, 1]], float), **extra)
    res = read_result(tmp / "localize.h5")
    ctx = SimpleNamespace(config={"ground_truth": {"kind": "poses", "path": str(tmp / "poses.csv")}},
                          output=lambda name: tmp / name)
    ev = pe.evaluate(ctx, res)
    ev.label = "umap"
    pe.finish(ctx, ev, plots=plots)
    return ev, tmp


def test_a_result_without_confidence_is_scored_as_before(tmp_path):
    ev, out = _evaluate(tmp_path, plots=True)
    assert (out / "per_query.csv").read_bytes() == BEFORE_CSV.encode()
    assert json.loads(json.dumps(ordered(ev.metrics, pe.COUNTS))) == BEFORE_METRICS
    assert list(ordered(ev.metrics, pe.COUNTS)) == list(BEFORE_METRICS)
    assert not (out / "confidence.png").exists() and (out / "error_cdf.png").is_file()
    assert "confidence_label" not in read_result(out / "localize.h5").attrs
    assert not any("confidence" in k for k in report_parts("poses", ev.metrics)["metrics_doc"])


def test_a_result_with_confidence_end_to_end(tmp_path):
    label = "score margin over the best rival pose"
    conf = np.array([0.9, 0.7, 0.7, NAN, 0.5, 0.2])
    ev, out = _evaluate(tmp_path, plots=True, confidence=conf, confidence_label=label)
    assert read_result(out / "localize.h5").attrs["confidence_label"] == label
    m = ev.metrics
    # right (1 m and 30 deg): p0 p1 p4. Runs: 0.9 {p0 right}, 0.7 {p1 right, p2 wrong}, 0.5 {p4 right},
    # 0.2 {p5 wrong}, NaN {p3 wrong}: kept 1, 3, 4, 5, 6 with 1, 2, 3, 3, 3 right;
    # AP = (1 + 2/3 + 3/4) / 3 = 29/36, 1 of 6 kept at 100 % precision, at 0.9
    assert m["confidence_average_precision"] == pytest.approx(29 / 36)
    assert m["kept_at_100_precision"] == pytest.approx(1 / 6) and m["confidence_threshold_at_100_precision"] == 0.9
    assert m["confidence_right_if"] == "within_1m_30deg" and m["confidence_label"] == label
    assert m["n_without_confidence"] == 1
    # the other figures are those of the result without a confidence, and not in the headline
    assert {k: m[k] for k in BEFORE_METRICS} == BEFORE_METRICS
    # per_query.csv: the old columns unchanged, the confidence last (formatted as the score, empty for NaN)
    lines = (out / "per_query.csv").read_text().splitlines()
    before = BEFORE_CSV.splitlines()
    assert lines[0] == before[0] + ",confidence"
    assert [ln.rsplit(",", 1) for ln in lines[1:]] == [[b, c] for b, c in zip(
        before[1:], ["0.90000", "0.70000", "0.70000", "", "0.50000", "0.20000"])]
    # the picture: the green diamond at (1/6 kept, precision 1), where plot_kept_precision's
    # axes box (84, 40)-(676, 476) over x -0.01..1.01, y 0..1.05 puts it
    with Image.open(out / "confidence.png") as im:
        assert im.format == "PNG" and im.size == (700, 560)
        px = 84 + (1 / 6 + 0.01) / 1.02 * 592, 476 - 1.0 / 1.05 * 436
        assert np.abs(np.subtract(im.convert("RGB").getpixel((round(px[0]), round(px[1]))), (44, 160, 44))).max() < 30
    # metrics.json (NaN and None as null) and report.html: the figures listed and explained, the picture shown
    write_metrics(out, ordered(m, pe.COUNTS))
    clean = json.loads((out / "metrics.json").read_text())
    assert clean["confidence_threshold_at_100_precision"] == 0.9
    write_report(out, config={"method": "umap"}, **report_parts("poses", clean))
    report = (out / "report.html").read_text()
    for key in ("confidence_average_precision", "kept_at_100_precision", "confidence_threshold_at_100_precision"):
        assert report.count(key) == 2, key  # its meaning above the table, its value in it
    assert "alt='confidence.png'" in report


def test_without_true_headings_right_is_within_1m(tmp_path):
    ev, _ = _evaluate(tmp_path, headings=False, confidence=np.array([0.9, 0.7, 0.7, NAN, 0.5, 0.2]))
    # right within 1 m: p0 p1 p3 p4; the NaN run {p3} is right now: AP = (1 + 2/3 + 3/4 + 4/6) / 4 = 37/48
    assert ev.metrics["confidence_average_precision"] == pytest.approx(37 / 48)
    assert ev.metrics["confidence_right_if"] == "within_1m"
    assert ev.metrics["confidence_label"] == "confidence"  # write's default


def test_the_plan_picture_names_the_worst_wrong_answers_first():
    # errors (m) and yaw errors (deg): frame 1 is 40 deg off at 0.2 m (wrong by heading), frames
    # 2 and 4 are 3 m and 7 m off, frame 3 0.9 m and 10 deg (right); the worst first, then the limit
    from placeloc.evaluation.pose_estimates import right_answers, worst_wrong

    err = np.array([0.1, 0.2, 3.0, 0.9, 7.0])
    wrong = ~right_answers(err, np.array([5.0, 40.0, 2.0, 10.0, 1.0]))
    assert worst_wrong(err, wrong) == [4, 2, 1]
    assert worst_wrong(err, wrong, limit=2) == [4, 2]
    assert worst_wrong(err, ~right_answers(err, None)) == [4, 2]


def test_true_positions_off_the_map_are_named_with_the_likely_unit():
    """Poses in centimetres (or another frame) show only as errors of hundreds of metres:
    evaluate says so when most true positions lie more than 1 m outside the map's walls."""
    from placeloc.evaluation.pose_estimates import truth_off_the_map

    walls = np.array([[0, 0, 10, 0], [10, 0, 10, 8], [10, 8, 0, 8], [0, 8, 0, 0]], float)
    truth = np.array([[1.0, 1.0], [9.0, 7.0], [5.0, 4.0], [2.5, 6.0]])
    assert truth_off_the_map(truth, walls) is None
    assert truth_off_the_map(truth, None) is None
    assert truth_off_the_map(np.vstack([truth[:2], truth[2:] + 50]), walls) is None  # half on the map
    said = truth_off_the_map(truth * 100, walls)
    assert said == ("4 of 4 true positions lie outside the map (x 0.0 to 10.0, y 0.0 to 8.0 m; the truth spans x 100.0 "
                    "to 900.0, y 100.0 to 700.0) (their spread is 78 times the map's: centimetres?); give the poses in "
                    "metres in the map's frame")
    shifted = truth_off_the_map(truth + [100.0, 0.0], walls)
    assert shifted.startswith("4 of 4 true positions lie outside the map") and "times the map's" not in shifted


def test_plan_title_counts_what_a_look_at_both_places_finds():
    # 4 frames: two right (0.3 and 0.9 m off), one 3 m off whose alternative lies 0.5 m from
    # the truth, one 5 m off whose alternative is 2 m off; NaN rows have no alternative
    from placeloc.evaluation.pose_estimates import plan_title

    truth = np.zeros((4, 2))
    est = np.array([[0.3, 0.0], [0.0, 0.9], [3.0, 0.0], [0.0, 5.0]])
    alt = np.array([[np.nan, np.nan], [np.nan, np.nan], [0.0, 0.5], [2.0, 0.0]])
    assert plan_title("umap", truth, est, alt) == ("umap: 2 of 4 frames within 1 m, 3 counting the ringed alternatives "
                                                   "(median error 1.95 m)")
    # without alternatives (or all NaN) the count stands alone
    assert plan_title("umap", truth, est) == plan_title("umap", truth, est, np.full((4, 2), np.nan)) == \
        "umap: 2 of 4 frames within 1 m (median error 1.95 m)"
    # a frame without an answer (NaN) is counted as not within 1 m, named, and left out of the median
    est[2] = np.nan
    assert plan_title("umap", truth, est) == "umap: 2 of 4 frames within 1 m (median error 0.90 m; 1 without an answer)"
    assert plan_title("umap", truth, np.full((4, 2), np.nan)) == "umap: 0 of 4 frames within 1 m (4 without an answer)"
