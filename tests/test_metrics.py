"""Metrics on hand-made cases, and ground-truth formats."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from placeloc.evaluation.ground_truth import GroundTruth, GroundTruthError
from placeloc.evaluation.metrics import dissimilarity_ratios, pr_curve, recall_at_k, summarise_ratios


def test_pr_curve_by_hand():
    pr = pr_curve(np.array([0.9, 0.8, 0.7, 0.6]), np.array([True, False, True, True]), n_queries=5)
    np.testing.assert_allclose(pr.precision, [1, 0.5, 2 / 3, 0.75])
    np.testing.assert_allclose(pr.recall, [0.2, 0.2, 0.4, 0.6])
    # trapezoids: (0,1)-(.2,1)=.2; (.2,.5)-(.4,2/3)=.116667; (.4,2/3)-(.6,.75)=.141667
    assert pr.auc == pytest.approx(0.2 + 0.2 * (0.5 + 2 / 3) / 2 + 0.2 * (2 / 3 + 0.75) / 2)
    assert pr.recall_at_100_precision == pytest.approx(0.2)
    assert pr.max_f1 == pytest.approx(2 * 0.75 * 0.6 / 1.35)


def test_pr_curve_ties_and_unmatched_queries():
    conf = np.array([0.5, 0.5, 0.9, 0.0])
    correct = np.array([True, False, True, False])
    has = np.array([True, True, True, False])
    pr = pr_curve(conf, correct, n_queries=4, has_match=has)
    # thresholds 0.9 and 0.5 only; the tie is accepted together
    np.testing.assert_allclose(pr.thresholds, [0.9, 0.5])
    np.testing.assert_allclose(pr.precision, [1.0, 2 / 3])
    np.testing.assert_allclose(pr.recall, [0.25, 0.5])


def test_recall_at_k():
    c = np.array([[False, True, False], [True, False, False], [False, False, False], [False, False, True]])
    r = recall_at_k(c, (1, 2, 3, 10))
    assert r == {1: 0.25, 2: 0.5, 3: 0.75, 10: 0.75}


def test_dissimilarity_ratio_by_hand():
    ratio = dissimilarity_ratios(np.array([1.0, 3.0, np.inf]), np.array([2.0, 3.0, 1.0]))
    np.testing.assert_allclose(ratio[:2], [0.5, 1.0])
    assert np.isnan(ratio[2])
    assert summarise_ratios(ratio) == (pytest.approx(0.75), 1)


def test_ground_truth_synchronous_ranges_pairs_hdf5(tmp_path):
    gt = GroundTruth.from_config({"kind": "synchronous", "tolerance": 1}, 5, 5)
    np.testing.assert_array_equal(gt.block(0, 5, 2, 3)[:, 0], [False, True, True, True, False])
    ranges = tmp_path / "r.csv"
    ranges.write_text("query,ref_first,ref_last\n0,0,2\n1,3,4\n")
    g = GroundTruth.from_csv(ranges, 5, 3)
    np.testing.assert_array_equal(g.correct(np.array([0, 0, 1, 1, 2]), np.array([2, 3, 3, -1, 0])),
                                  [True, False, True, False, False])
    assert list(g.has_match()) == [True, True, False]
    pairs = tmp_path / "p.csv"
    pairs.write_text("query,reference\n0,10\n1,4\n")
    g = GroundTruth.from_csv(pairs, 20, 2, tolerance=2)
    assert g.correct(np.array([0, 0, 0]), np.array([8, 12, 13])).tolist() == [True, True, False]
    m = np.zeros((4, 3), bool)
    m[2, 1] = True
    with h5py.File(tmp_path / "gt.h5", "w") as f:
        f["gt"] = m
    g = GroundTruth.from_hdf5(tmp_path / "gt.h5", 4, 3)
    assert g.correct(np.array([1, 1]), np.array([2, 1])).tolist() == [True, False]
    with pytest.raises(GroundTruthError, match="expected"):
        GroundTruth.from_hdf5(tmp_path / "gt.h5", 5, 3)
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(GroundTruthError, match="header"):
        GroundTruth.from_csv(bad, 3, 3)
