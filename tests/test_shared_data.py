"""Accuracy on the real data in ../shared/data (skipped cleanly when it is absent)."""

from __future__ import annotations

import pytest

from placeloc.core.config import load_config
from placeloc.core.runner import read_metrics, run_all
from placeloc.experiments import shared_data_dir

DATA = shared_data_dir()
pytestmark = pytest.mark.shared_data


@pytest.mark.skipif(DATA is None or not (DATA / "nordland-dev").is_dir(), reason="../shared/data/nordland-dev absent")
def test_nordland_winter_vs_summer_reaches_the_target(tmp_path):
    """Issue 2 section 7: best method with sequences: Recall@1 >= 0.92 and AUC >= 0.92."""
    cfg = load_config(data={
        "method": "seqslam", "plots": False,
        "reference": {"images": str(DATA / "nordland-dev" / "summer")},
        "query": {"images": str(DATA / "nordland-dev" / "winter")},
        "ground_truth": {"kind": "synchronous", "tolerance": 2},
        "seqslam": {"comparison": "sad", "normalisation": "zscore", "ds": 30, "search": "centred"},
    })
    run_all(cfg, tmp_path / "nl", quiet=True)
    m = read_metrics(tmp_path / "nl")
    assert m["n_queries"] == 1200
    assert m["recall_at_1"] >= 0.92 and m["auc_pr"] >= 0.92
    assert m["single_image_recall_at_1"] < 0.5  # single images alone are far worse


@pytest.mark.skipif(DATA is None or not (DATA / "corridor").is_dir(), reason="../shared/data/corridor absent")
def test_corridor_with_range_ground_truth(tmp_path):
    cfg = load_config(data={
        "method": "seqslam", "plots": False,
        "reference": {"images": str(DATA / "corridor" / "ref")},
        "query": {"images": str(DATA / "corridor" / "query")},
        "ground_truth": {"kind": "csv", "path": str(DATA / "corridor" / "ground_truth.csv")},
        "seqslam": {"comparison": "sad", "ds": 10},
    })
    run_all(cfg, tmp_path / "c", quiet=True)
    m = read_metrics(tmp_path / "c")
    assert m["n_queries"] == 111
    # A hard set (wide lens, traverses offset sideways): sequences must clearly beat single images.
    assert m["recall_at_1"] >= m["single_image_recall_at_1"] + 0.05
