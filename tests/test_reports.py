"""metrics.json and the reports built from it: the contracts' pure scoring, one timing key,
counts apart from scores, and texts that name what the run did (hand-computed answers)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from placeloc.evaluation import contracts, loops
from placeloc.evaluation.contracts import Result
from placeloc.pirf.metrics import loop_closure_correct_in_truth, nearest_true_earlier
from placeloc.seqslam.demo import explain, spans, why_unmatched


def _loops_result(match: list[int], confidence: list[float], threshold: float | None) -> Result:
    n = len(match)
    attrs = {} if threshold is None else {"threshold": threshold}
    return Result("loops", {"frame_index": np.arange(n), "frame_names": [f"f{i}.png" for i in range(n)],
                            "match": np.array(match), "confidence": np.array(confidence, np.float32)}, attrs)


def _truth(n: int, pairs: list[tuple[int, int]]) -> sparse.csr_matrix:
    i, j = zip(*pairs)
    return sparse.csr_matrix((np.ones(len(i), bool), (i, j)), shape=(n, n))


def test_loops_headline_has_no_empty_card_without_a_threshold():
    """Frames 4 and 5 close a loop with 0 and 1; frame 4 matches 0 (right), frame 5 matches 3
    (wrong; 5 - 3 = 2 frames apart, old enough for exclude_recent 2)."""
    truth = _truth(6, [(4, 0), (5, 1)])
    res = _loops_result([-1, -1, -1, -1, 0, 3], [0, 0, 0, 0, 0.9, 0.5], threshold=None)
    ev = loops.score(res, truth, names=[f"f{i}.png" for i in range(6)], exclude_recent=2, tolerance=0)
    m = ev.metrics
    assert m["headline"] == ["recall_at_100_precision", "auc_pr", "max_f1", "seconds_per_frame"]
    assert "precision_at_threshold" not in m
    # the right one first (confidence 0.9): recall 1/2 at precision 1 (F1 2/3); then 1/2 at precision 1/2
    assert m["recall_at_100_precision"] == 0.5 and m["max_f1"] == pytest.approx(2 / 3)
    assert (m["n_candidates"], m["n_accepted"], m["n_accepted_right"]) == (2, 2, 1)


def test_loops_accepted_counts_only_what_the_threshold_lets_through():
    truth = _truth(6, [(4, 0), (5, 1)])
    res = _loops_result([-1, -1, -1, -1, 0, 1], [0, 0, 0, 0, 0.9, 0.001], threshold=0.003)
    ev = loops.score(res, truth, names=[f"f{i}.png" for i in range(6)], exclude_recent=2, tolerance=0)
    m = ev.metrics
    # frame 5's right match lies below tau: a candidate, never an accepted loop closure
    assert (m["n_candidates"], m["n_accepted"], m["n_accepted_right"]) == (2, 1, 1)
    assert m["precision_at_threshold"] == 1.0 and m["recall_at_threshold"] == 0.5
    assert ev.accepted.tolist() == [False, False, False, False, True, False]


def test_one_timing_key_counts_every_stage_before_evaluate():
    m: dict = {"n_frames": 4}
    contracts.add_timing(m, {"extract": 1.0, "build-dictionary": 0.5, "localize": 0.5}, 4)
    assert m["seconds_per_frame"] == 0.5 and m["stage_seconds"]["extract"] == 1.0
    m2: dict = {}
    contracts.add_timing(m2, {}, 0)
    assert m2["seconds_per_frame"] is None


def test_metrics_json_puts_the_headline_first_and_the_counts_last():
    m = {"n_queries": 3, "comparison": "sad", "max_f1": 0.5, "recall_at_1": 1.0, "queries_with_ground_truth": 3,
         "seconds_per_frame": 0.1, "headline": ["recall_at_1", "seconds_per_frame"]}
    out = contracts.ordered(m, ("queries_with_ground_truth",))
    assert list(out) == ["recall_at_1", "seconds_per_frame", "max_f1", "n_queries", "comparison",
                         "queries_with_ground_truth", "headline"]


def test_the_report_explains_only_the_figures_the_run_reports():
    retrieval_like = {"recall_at_1": 1.0, "recall_at_5": 1.0, "auc_pr": 1.0, "seconds_per_frame": 0.1}
    doc = contracts.report_parts("ranked", retrieval_like)["metrics_doc"]
    assert "recall_at_N" in doc and "separated_recall_at_N" not in doc and "recall_at_N_with_positive" not in doc
    seqslam_like = {**retrieval_like, "separated_recall_at_5": 1.0}
    assert "separated_recall_at_N" in contracts.report_parts("ranked", seqslam_like)["metrics_doc"]


def test_every_contract_module_follows_the_protocol():
    for kind in contracts.KINDS:
        mod = contracts.contract(kind)
        for name in ("SCHEMA", "SECTIONS", "SHOW_AT_EVALUATE", "CHOOSES_QUERIES", "METRICS_DOC", "COUNTS", "check_ground_truth", "evaluate",
                     "score", "finish", "headline", "show"):
            assert hasattr(mod, name), f"{kind}: {name}"
        assert "seconds_per_frame" in mod.METRICS_DOC


def test_pirf_closures_judged_by_a_loop_matrix_with_tolerance():
    truth = _truth(10, [(8, 2), (8, 3), (9, 5)])
    ok = loop_closure_correct_in_truth(truth, np.array([8, 8, 9, 7]), np.array([3, 5, 6, 1]), tolerance=1)
    # 8->3 is a one; 8->5 is 2 away from 3; 9->6 is 1 from 5; frame 7 has no loop
    assert ok.tolist() == [True, False, True, False]
    assert nearest_true_earlier(truth, np.array([8, 9, 7]), np.array([6, 0, 0])).tolist() == [3, 5, -1]


def test_demo_names_the_unmatched_queries_of_the_causal_search():
    assert spans([0, 1, 2, 7, 80]) == "0-2, 7, 80"
    assert why_unmatched("causal", 10, list(range(10))).startswith("queries 0-9 get no match: the causal search")
    assert "ds/2 = 5" in why_unmatched("centred", 10, [0, 1, 2, 3, 4, 76, 77, 78, 79, 80])
    m = {"n_queries": 81, "n_matched": 71, "comparison": "abs_zncc", "ds": 10, "search": "causal", "recall_at_1": 71 / 81,
         "recall_at_5": 71 / 81, "auc_pr": 71 / 81, "recall_at_100_precision": 71 / 81, "single_image_recall_at_1": 1.0}
    text = explain(m, list(range(10)))
    assert "queries 0-9 get no match" in text and "within ds/2 of an end" not in text


def test_metrics_name_the_truth_a_method_reads_from_its_own_section():
    from types import SimpleNamespace

    method = SimpleNamespace(name="coembed", truth_keys={"points": "truth", "poses": "poses"})
    both = SimpleNamespace(truth="features.csv", poses="poses.csv")
    assert contracts.method_truth(method, both) == "coembed.truth=features.csv, coembed.poses=poses.csv"
    assert contracts.method_truth(method, SimpleNamespace(truth="f.csv", poses=None)) == "coembed.truth=f.csv"
    assert contracts.method_truth(SimpleNamespace(name="seqslam", truth_keys={}), both) == ""


def test_report_shows_a_value_the_method_chose_beside_the_configs_only(tmp_path):
    import json

    from placeloc.evaluation.report import write_report

    (tmp_path / "metrics.json").write_text(json.dumps({"alpha": 10000.0, "beta": 2.0, "map_rmse": 0.5}))
    cfg = {"method": "coembed", "coembed": {"alpha": 1000.0, "alpha_select": "loo", "beta": 1.0}}
    html = write_report(tmp_path, config=cfg).read_text()
    assert "1000.0000 in the config; 10000.0000 chosen by alpha_select (metrics.json)" in html
    # and in the short table, outside the folded parameters: a chosen value is a result too
    assert html.index("<td>coembed.alpha</td>") < html.index("<details>")
    # beta has no *_select: metrics.json's value (from an earlier run, say) never relabels the config's
    assert "<td>beta</td><td class='num'>1.0000</td>" in html
    cfg["coembed"]["alpha_select"] = "fixed"
    assert "chosen by" not in write_report(tmp_path, config=cfg).read_text()


def test_a_setting_too_small_for_four_decimals_reads_as_itself_not_as_zero():
    """UMap's AKAZE threshold (3e-05) showed as 0.0000 in report.html's config table; the
    report and the command line share one formatter."""
    from placeloc.evaluation.report import _table, format_value

    assert [format_value(v) for v in (3e-05, -2e-06, 0.0, 0.02, 0.0005, 1234.5, None)] == \
        ["3e-05", "-2e-06", "0.0000", "0.0200", "0.0005", "1234.5000", "n/a"]
    assert ">3e-05<" in _table([("ca.akaze_threshold", 3e-05)], ("key", "value"))
    # a list of numbers: six significant digits, integers and other lists as they are
    assert format_value([-4.163040570086148, 4.859999999999999, 0.25]) == "[-4.16304, 4.86, 0.25]"
    assert format_value([45.0, 135.0]) == "[45, 135]" and format_value([64, 32]) == "[64, 32]"
    assert format_value(["a", 1]) == "['a', 1]" and format_value([]) == "[]" and format_value([True]) == "[True]"


def test_a_run_not_evaluated_shows_its_answers_under_the_headline(tmp_path):
    """A photo located without ground truth: report.html shows estimates.csv's rows (every
    one when few, the first 20 of more, names escaped), above the configuration; once the
    run is evaluated, metrics.json's headline takes their place."""
    import json

    from placeloc.evaluation.report import write_report

    cfg = {"method": "umap"}
    (tmp_path / "estimates.csv").write_text('frame,x,y,room\n"a<b>,1.png",7.000,0.040,hall\n')
    html = write_report(tmp_path, config=cfg).read_text()
    assert "<h2>Answers</h2>" in html and "every answer, from <code>estimates.csv</code>" in html
    assert "<td>a&lt;b&gt;,1.png</td><td>7.000</td><td>0.040</td><td>hall</td>" in html
    assert html.index("<h2>Answers</h2>") < html.index("<h2>Configuration</h2>")
    rows = "".join(f"f{i}.png,{i},0\n" for i in range(30))
    (tmp_path / "estimates.csv").write_text("frame,x,y\n" + rows)
    html = write_report(tmp_path, config=cfg).read_text()
    assert "the first 20, from" in html and "<td>f19.png</td>" in html and "f20.png" not in html
    (tmp_path / "metrics.json").write_text(json.dumps({"within_1m": 1.0}))
    assert "<h2>Answers</h2>" not in write_report(tmp_path, config=cfg).read_text()


def test_the_terminal_shows_the_first_answers_of_a_run_not_evaluated(tmp_path):
    """`placeloc run` without ground truth prints the first answers: a pose with its room,
    the rival's room only where the answer is doubtful; matches with the unmatched queries
    counted, not shown; a pointer to the file when there are more."""
    from placeloc.evaluation.report import answer_lines

    (tmp_path / "estimates.csv").write_text(
        "frame,x,y,heading_deg,score,doubtful,room,rival_room\n"
        "a.png,7.000,0.040,307.5,0.6,false,hall,hall\nb.png,1.000,2.000,90.0,0.5,true,bedroom1,bedroom2\n")
    assert answer_lines(tmp_path) == ["a.png: x 7.000, y 0.040, heading_deg 307.5, room hall, doubtful false",
                                      "b.png: x 1.000, y 2.000, heading_deg 90.0, room bedroom1, doubtful true, "
                                      "rival_room bedroom2"]
    other = tmp_path / "ranked"
    other.mkdir()
    (other / "matches.csv").write_text("query,reference,confidence,query_image,reference_image\n0,,,q0.png,\n"
                                       + "".join(f"{i},{i},0.5,q{i}.png,r{i}.png\n" for i in range(1, 9)))
    assert answer_lines(other, most=2) == ["q1.png: reference_image r1.png, confidence 0.5",
                                           "q2.png: reference_image r2.png, confidence 0.5",
                                           "(1 query up to here without an answer)", f"... more in {other / 'matches.csv'}"]
    (other / "matches.csv").write_text("query,reference,confidence,query_image,reference_image\n0,,,q0.png,\n")
    assert answer_lines(other) == ["(none of the first 1 queries has an answer)"]
    assert answer_lines(tmp_path / "nowhere") == []


def test_the_ground_truth_line_names_only_what_the_contract_reads(tmp_path):
    """A UMap run's truth is a poses file scored within 1 m and 30 deg: the config's radius
    (25 m by default, read by ranked matches) is not shown beside it, where it read as if
    answers within 25 m counted; loop closures show the pairs they never count."""
    import json

    from placeloc.evaluation.report import write_report

    (tmp_path / "metrics.json").write_text(json.dumps({"within_1m_30deg": 1.0}))
    gt = {"kind": "poses", "path": "poses.csv", "radius": 25.0, "exclude_recent": 50}
    poses = write_report(tmp_path, config={"method": "umap", "ground_truth": gt}, result_kind="poses").read_text()
    assert "<td class=''>kind=poses, path=poses.csv</td>" in poses
    loops = write_report(tmp_path, config={"method": "pirf", "ground_truth": gt}, result_kind="loops").read_text()
    assert "<td class=''>kind=poses, path=poses.csv, radius=25.0, exclude_recent=50</td>" in loops
    ranked = write_report(tmp_path, config={"method": "seqslam", "ground_truth": gt}, result_kind="ranked").read_text()
    assert "<td class=''>kind=poses, path=poses.csv, radius=25.0</td>" in ranked


def test_a_method_s_pictures_in_its_order_with_its_captions(tmp_path):
    """report.html shows a method's own pictures (MethodPictures) in the order it chose them,
    each with its caption, right after the figures of ORDER; a PNG of their family that was
    not chosen is left out; every other picture, and a report without MethodPictures, keeps
    name order."""
    import re

    from placeloc.evaluation.report import MethodPictures, write_report

    png = b"\x89PNG\r\n\x1a\n" + b"\0" * 16   # the report checks the signature, not the image
    for name in ("estimates_on_plan.png", "panorama_a.png", "panorama_b.png", "panorama_c.png", "ceiling_scores.png",
                 "zz.png"):
        (tmp_path / name).write_bytes(png)

    def listed(html: str) -> list[tuple[str, str]]:
        return re.findall(r"<h3>([^<]*?)(?:<span class='why'>([^<]*)</span>)?</h3>", html)

    plain = listed(write_report(tmp_path, config={"method": "seqslam"}).read_text())
    assert [n for n, _ in plain] == ["estimates_on_plan.png", "ceiling_scores.png", "panorama_a.png", "panorama_b.png",
                                     "panorama_c.png", "zz.png"]
    assert all(why == "" for _, why in plain)
    chosen = MethodPictures("panorama_", [("panorama_c.png", "wrong: 7.31 m off"), ("panorama_a.png", "")],
                            "wrong ones first")
    html = write_report(tmp_path, config={"method": "umap"}, method_pictures=chosen).read_text()
    assert listed(html) == [("estimates_on_plan.png", ""), ("panorama_c.png", "wrong: 7.31 m off"), ("panorama_a.png", ""),
                            ("ceiling_scores.png", ""), ("zz.png", "")]
    # the note once, just before the first of them
    assert html.count("wrong ones first") == 1
    assert html.index("estimates_on_plan.png") < html.index("wrong ones first") < html.index("<h3>panorama_c.png")
