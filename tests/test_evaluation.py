"""Metrics as the field means them (by hand), SeqSLAM's evaluate with every ground-truth
form on the bundled route, the per-query CSV, match strips, report.html and sweeps."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from placeloc.core.config import load_config
from placeloc.core.runner import run_stage
from placeloc.evaluation.ground_truth import GroundTruth
from placeloc.evaluation.matching import score_matches
from placeloc.evaluation.metrics import drop_soft, first_correct_rank, recall_at_n


def test_recall_at_n_and_denominators_by_hand():
    c = np.array([[False, True, False], [True, False, False], [False, False, False], [False, False, True]])
    assert recall_at_n(c, (1, 2, 3, 20)) == {1: 0.25, 2: 0.5, 3: 0.75, 20: 0.75}
    has = np.array([True, True, False, True])  # query 2 has no positive at all
    assert recall_at_n(c, (1, 3), has_positive=has) == {1: pytest.approx(1 / 3), 3: 1.0}
    assert first_correct_rank(c).tolist() == [2, 1, 0, 3]


def test_drop_soft_by_hand():
    cand = np.array([[3, 2, 7], [4, 8, 5]])
    soft = np.array([[True, False, False], [True, False, False]])
    kept, scores = drop_soft(cand, soft, np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]))
    assert kept.tolist() == [[2, 7, -1], [8, 5, -1]]
    assert scores[0, :2].tolist() == [2.0, 3.0] and np.isnan(scores[0, 2])


def test_soft_matches_neither_count_wrong_nor_are_required(tmp_path):
    p = tmp_path / "gt.csv"
    p.write_text("query,reference,soft\n0,2,0\n0,3,1\n1,5,0\n1,4,1\n")
    gt = GroundTruth.from_csv(p, 10, 3)
    separated = np.array([[3, 2, 7], [4, 8, 5], [1, -1, -1]])
    s = score_matches(gt, np.arange(3), np.arange(10), separated=separated, confidence=np.array([0.9, 0.8, 0.1]),
                      ranked=separated, ranked_scores=np.ones((3, 3)), ns=(1, 2))
    m = s.metrics
    assert m["recall_at_1"] == pytest.approx(1 / 3) and m["recall_at_2"] == pytest.approx(2 / 3)
    assert m["recall_at_1_with_positive"] == 0.5 and m["recall_at_2_with_positive"] == 1.0
    assert m["queries_with_ground_truth"] == 2 and s.best.tolist() == [2, 8, 1]
    # without the soft rows, the soft candidate 3 of query 0 is simply wrong
    p.write_text("query,reference\n0,2\n1,5\n")
    hard = score_matches(GroundTruth.from_csv(p, 10, 3), np.arange(3), np.arange(10), separated=separated,
                         confidence=np.ones(3), ranked=separated, ns=(1, 2))
    assert hard.metrics["recall_at_1"] == 0.0 and hard.metrics["recall_at_2"] == pytest.approx(1 / 3)


def test_standard_and_separated_rankings_differ_as_defined():
    """Plain ranking [5, 6, 1]: neighbours allowed; separated [5, 1]: distinct places."""
    gt = GroundTruth(10, 1, intervals=(np.array([0]), np.array([1]), np.array([1])))
    s = score_matches(gt, np.array([0]), np.arange(10), separated=np.array([[5, 1]]), confidence=np.ones(1),
                      ranked=np.array([[5, 6, 1]]), ns=(1, 2, 3, 5), separated_differs=True)
    assert [s.metrics[f"recall_at_{n}"] for n in (1, 2, 3)] == [0.0, 0.0, 1.0]
    # N = 5 is beyond the 3 plain candidates: not written, never silently the value at 3
    assert "recall_at_5" not in s.metrics
    # separated at N = 1 is recall_at_1 by definition (not written); only 2 separated candidates
    # were kept, so N = 3 is unknown and not written either
    assert s.metrics["separated_recall_at_2"] == 1.0
    assert not {"separated_recall_at_1", "separated_recall_at_3"} & set(s.metrics)
    # every query has a positive: the _with_positive variant would repeat recall_at_N
    assert not [k for k in s.metrics if k.endswith("_with_positive")]
    none = score_matches(gt, np.array([0]), np.arange(10), separated=np.array([[5, 1]]), confidence=np.ones(1))
    assert none.metrics["recall_at_1"] == 0.0 and "recall_at_5" not in none.metrics
    assert not [k for k in none.metrics if k.startswith("separated_")]


def _positions_csv(route, path):
    rows = [["traverse", "image", "x", "y"]]
    for role in ("reference", "query"):
        with (route / f"poses_{role}.csv").open() as fh:
            rows += [[role, f"frame{r['frame']}.png", r["position_px"], 0] for r in csv.DictReader(fh)]
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)


def test_seqslam_evaluate_with_positions_names_and_ranges_agree(route, tmp_path):
    """The same truth as ranges (index), pairs by file name and positions (kind poses,
    which used to crash SeqSLAM) gives the same metrics; per_query.csv agrees with them."""
    run = tmp_path / "run"
    base = ["plots=false", "seqslam.comparison=abs_zncc"]
    run_stage(load_config(route / "config.yaml", base), run, "evaluate", quiet=True)
    ranges = json.loads((run / "metrics.json").read_text())
    _positions_csv(route, route / "positions.csv")
    cfg = load_config(route / "config.yaml", base + ["ground_truth.kind=poses", "ground_truth.path=positions.csv",
                                                      "ground_truth.radius=12"])
    run_stage(cfg, run, "evaluate", quiet=True)
    poses = json.loads((run / "metrics.json").read_text())
    keys = [k for k in ranges if "recall" in k or k in ("auc_pr", "max_f1", "queries_with_ground_truth")]
    assert {k: poses[k] for k in keys} == {k: ranges[k] for k in keys}
    assert ranges["recall_at_1"] > 0.8 and ranges["recall_at_20"] >= ranges["recall_at_1"]
    with (run / "per_query.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == ranges["n_queries"]
    assert np.mean([r["correct"] == "1" for r in rows]) == pytest.approx(ranges["recall_at_1"])
    first = np.array([int(r["first_correct_rank"]) for r in rows])
    for n in (1, 5, 20):
        assert np.mean((first >= 1) & (first <= n)) == pytest.approx(ranges[f"recall_at_{n}"])
    assert rows[30]["query_image"] == "frame30.png" and rows[30]["image_1"].startswith("frame")
    from placeloc.evaluation.show import recall_from_per_query

    again = recall_from_per_query(run, [5, 20, 21])
    assert again[5][0] == pytest.approx(ranges["recall_at_5"]) and again[21] == (None, None)


def test_show_without_ground_truth_and_report(route, tmp_path):
    from placeloc.evaluation.report import write_report
    from placeloc.evaluation.show import FAILURES_PNG, SAMPLE_PNG, draw_strips, read_rows

    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml", ["ground_truth.kind=none", "plots=false"])
    run_stage(cfg, run, "localize", quiet=True)
    rows = read_rows(run)
    assert len(rows) == 81 and all(r.correct is None for r in rows)
    paths = draw_strips(run, sample=4)
    assert [p.name for p in paths] == [SAMPLE_PNG] and not (run / FAILURES_PNG).exists()
    html = write_report(run).read_text()
    assert html.count("data:image/png;base64,") == 1 and "No metrics.json" in html and "seqslam" in html

    # evaluate (with plots) draws strips and the report itself; showing again must not
    # make evaluate look out of date (its side outputs come out byte-identical)
    from placeloc.core.runner import side_outputs_intact
    from placeloc.evaluation.show import show_run

    run_stage(load_config(route / "config.yaml", ["seqslam.comparison=sad"]), run, "evaluate", quiet=True)
    html = (run / "report.html").read_text()
    assert "recall_at_20" in html
    for name in ("strips_sample.png", "pr_curve.png", "recall_at_n.png", "difference_matrix.png"):
        assert f"<h3>{name}</h3><img" in html
    show_run(run)
    assert side_outputs_intact(run / "evaluate.h5")

    from typer.testing import CliRunner

    from placeloc.cli import app

    res = CliRunner().invoke(app, ["show", str(run), "--recall-at", "1,20,99", "-q"])
    m = json.loads((run / "metrics.json").read_text())
    assert res.exit_code == 0 and f"recall@1: {m['recall_at_1']:.4f} (all queries)" in res.output
    assert "recall@99: n/a" in res.output and side_outputs_intact(run / "evaluate.h5")
    res = CliRunner().invoke(app, ["show", str(tmp_path / "nowhere")])
    assert res.exit_code == 2


def test_sweep_runs_every_combination_and_resumes(route, tmp_path):
    import yaml

    from placeloc.experiments.sweep import parse_grid, run_sweep

    raw = yaml.safe_load((route / "config.yaml").read_text())
    raw["plots"] = False
    grid = parse_grid(["seqslam.ds=5,10", "seqslam.comparison=sad"])
    table = run_sweep(raw, route, grid, tmp_path / "sw")
    with (tmp_path / "sw" / "sweep.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["seqslam.ds"], r["seqslam.comparison"]) for r in rows] == [("5", "sad"), ("10", "sad")]
    single = json.loads((tmp_path / "sw" / rows[1]["run"] / "metrics.json").read_text())
    assert float(rows[1]["recall_at_1"]) == pytest.approx(single["recall_at_1"]) and single["ds"] == 10
    assert "| 10 | sad |" in table.read_text() and (tmp_path / "sw" / "sweep.png").is_file()
    stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "sw").rglob("*.h5")}
    run_sweep(raw, route, grid, tmp_path / "sw")
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "sw").rglob("*.h5")} == stamps  # resumed: nothing re-ran
    with pytest.raises(Exception, match="expected key.path=v1,v2"):
        parse_grid(["seqslam.ds"])


def test_a_sweep_links_the_stages_its_points_share_and_computes_the_rest(route, tmp_path):
    """Points that differ in a localize key share extract (the same stamp): it is computed
    once and hard-linked into the other points' folders, and each point's figures are those
    of a run of its own. A key that extract reads gives each its own extract."""
    import yaml

    from placeloc.api import run
    from placeloc.experiments.sweep import parse_grid, run_sweep

    raw = yaml.safe_load((route / "config.yaml").read_text())
    raw["plots"] = False
    run_sweep(raw, route, parse_grid(["seqslam.ds=5,10"]), tmp_path / "sw")
    a, b = (tmp_path / "sw" / f"seqslam.ds={ds}" for ds in (5, 10))
    assert (a / "extract.h5").stat().st_ino == (b / "extract.h5").stat().st_ino
    assert (a / "localize.h5").stat().st_ino != (b / "localize.h5").stat().st_ino
    assert f"extract: the same as {a / 'extract.h5'} (linked, not computed again)" in (b / "log.txt").read_text()
    alone = run(load_config(data={**raw, "seqslam": {**raw.get("seqslam", {}), "ds": 10}}, base_dir=route),
                tmp_path / "alone")
    assert json.loads((b / "metrics.json").read_text())["recall_at_1"] == \
        json.loads((alone.parent / "metrics.json").read_text())["recall_at_1"]
    # re-running one point with --force leaves the other's linked file as it was
    before = (a / "extract.h5").read_bytes()
    run(load_config(data={**raw, "seqslam": {**raw.get("seqslam", {}), "ds": 10}}, base_dir=route), b, force=True)
    assert (a / "extract.h5").read_bytes() == before and (a / "extract.h5").stat().st_ino != (b / "extract.h5").stat().st_ino

    run_sweep(raw, route, parse_grid(["seqslam.thumbnail=[32,16],[16,8]"]), tmp_path / "thumbs")
    inodes = {p.stat().st_ino for p in (tmp_path / "thumbs").glob("*/extract.h5")}
    assert len(inodes) == 2  # extract reads the thumbnail size: one each


def test_show_on_a_sweep_folder_names_its_runs(tmp_path):
    """A sweep's folder holds one run per subfolder: show says so and names one, instead of
    "holds no localize result; run placeloc localize ..."."""
    from placeloc.evaluation.show import ShowError, show_run

    for name in ("seqslam.ds=5", "seqslam.ds=10"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "localize.h5").write_bytes(b"")
    (tmp_path / "sweep.md").write_text("# Sweep\n")
    with pytest.raises(ShowError) as info:
        show_run(tmp_path)
    assert str(info.value) == (f"{tmp_path}: holds 2 runs, one per folder (their table: {tmp_path / 'sweep.md'}); "
                               f"show one of them, e.g. placeloc show {tmp_path / 'seqslam.ds=10'}")


def test_a_sweep_table_shows_each_methods_own_figures():
    from placeloc.experiments.sweep import TABLE_KEYS, split_values, table_keys

    pose = {"within_1m_30deg": 0.95, "median_error_m": 0.03, "n_frames": 20,
            "headline": ["within_1m_30deg", "median_error_m", "seconds_per_frame"]}
    assert table_keys([pose, pose]) == ["within_1m_30deg", "median_error_m"]  # not nine columns of n/a
    ranked = {"recall_at_1": 0.8, "auc_pr": 0.7, "n_queries": 81, "seconds_per_frame": 0.001,
              "headline": ["recall_at_1", "auc_pr", "seconds_per_frame"]}
    assert table_keys([ranked]) == ["recall_at_1", "auc_pr", "n_queries", "seconds_per_frame"]
    assert table_keys([{}, {}]) == list(TABLE_KEYS)  # no ground truth: the usual columns, n/a
    assert split_values("10,[64, 32],{a: 1, b: 2},'x,y'") == ["10", "[64, 32]", "{a: 1, b: 2}", "'x,y'"]


def test_recall_at_n_list_comes_from_the_config(route, tmp_path):
    """ground_truth.recall_at sets the N of Recall@N; the per-query ranks agree with it."""
    from placeloc.core.config import ConfigError

    with pytest.raises(ConfigError, match=r"ground_truth.recall_at: \[0, 3\] is out of range; it must be >= 1"):
        load_config(route / "config.yaml", ["ground_truth.recall_at=[0, 3]"])
    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml", ["plots=false", "ground_truth.recall_at=[3, 1]"])
    run_stage(cfg, run, "evaluate", quiet=True)
    m = json.loads((run / "metrics.json").read_text())
    assert "recall_at_3" in m and "recall_at_20" not in m
    with open(run / "per_query.csv", newline="") as fh:
        ranks = [int(r["first_correct_rank"] or 0) for r in csv.DictReader(fh)]  # 0: no positive among them
    n = len(ranks)
    assert m["recall_at_3"] == pytest.approx(sum(1 for r in ranks if 1 <= r <= 3) / n)
    assert m["recall_at_1"] == pytest.approx(sum(1 for r in ranks if r == 1) / n)


def test_queries_the_ground_truth_leaves_out_are_counted_and_said(route, tmp_path, caplog):
    """A ranges file that lists only the first 40 of the route's 81 queries: the other 41
    have no true match, so recall_at_1 over every query is the right matches among the 40
    over 81, recall_at_1_with_positive the same over 40, and the log says how many queries
    have none and what that does to the figures (before, nothing said it)."""
    import logging

    full = (route / "ground_truth.csv").read_text().splitlines()
    (tmp_path / "half.csv").write_text("\n".join(full[:41]) + "\n")
    run = tmp_path / "run"
    with caplog.at_level(logging.INFO, logger="placeloc"):
        run_stage(load_config(route / "config.yaml", ["plots=false", f"ground_truth.path={tmp_path / 'half.csv'}"]),
                  run, "evaluate", quiet=True)
    m = json.loads((run / "metrics.json").read_text())
    with open(run / "per_query.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    right = sum(1 for r in rows[:40] if r["correct"] == "1")
    assert m["n_queries"] == 81 and m["queries_with_ground_truth"] == 40
    assert m["recall_at_1"] == pytest.approx(right / 81) and m["recall_at_1_with_positive"] == pytest.approx(right / 40)
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("ground truth:")]
    assert said == [f"ground truth: 41 of 81 queries have no true match in {tmp_path / 'half.csv'}; their matches count "
                    "as wrong in auc_pr and recall_at_100_precision, and recall_at_N_with_positive leaves them out"]


def test_a_confidence_of_zero_is_labelled_with_what_it_means(route, tmp_path):
    """SeqSLAM's confidence is 0 where no second candidate lies enhance_window + 1 frames or
    more from the best (the first frames a loop may close): its result says so, and the
    strips print it beside such a match (a label that widens its cell), not a bare "conf 0"."""
    from PIL import Image

    from placeloc.evaluation.show import Row, draw_strip_figure, zero_confidence_note

    run = tmp_path / "run"
    run_stage(load_config(route / "config.yaml", ["plots=false", "seqslam.enhance_window=7"]), run, "localize", quiet=True)
    note = zero_confidence_note(run)
    assert note == "no rival 8+ frames away"
    names = {"frame3.png": route / "reference" / "frame3.png", "frame40.png": route / "query" / "frame40.png"}
    widths = []
    for conf in (0.0, 0.25):
        path = draw_strip_figure([Row("frame40.png", "frame3.png", conf, None, "")], [0], names, names,
                                 tmp_path / f"s{conf}.png", "t", note)
        widths.append(Image.open(path).size[0])
    assert widths[0] > widths[1] + 50   # "conf 0 (no rival 8+ frames away)" against "conf 0.25"
