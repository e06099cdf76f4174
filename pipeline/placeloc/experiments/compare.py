"""Run several image comparisons on one data set and tabulate them like the comparison study's table 1."""

from __future__ import annotations

import copy
import csv
from pathlib import Path
from typing import Any

import h5py

from placeloc.core.runner import read_metrics, run_all
from placeloc.seqslam.comparisons import COMPARISONS

TABLE_COLUMNS = (
    ("comparison", "comparison"),
    ("dissimilarity_mean", "mean dissimilarity (before)"),
    ("dissimilarity_count_ge1", "count >= 1 (before)"),
    ("dissimilarity_mean_enhanced", "mean dissimilarity (after)"),
    ("dissimilarity_count_ge1_enhanced", "count >= 1 (after)"),
    ("auc_pr", "AUC"),
    ("recall_at_1", "R@1"),
    ("recall_at_100_precision", "R@100P"),
    ("single_image_recall_at_1", "R@1 single image"),
)


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.3f}"
    return str(v)


def markdown_table(rows: list[dict[str, Any]]) -> str:
    head = "| " + " | ".join(label for _, label in TABLE_COLUMNS) + " |"
    sep = "|" + "|".join("---" for _ in TABLE_COLUMNS) + "|"
    body = ["| " + " | ".join(_fmt(r.get(k)) for k, _ in TABLE_COLUMNS) + " |" for r in rows]
    return "\n".join([head, sep, *body]) + "\n"


def compare_methods(config: dict[str, Any], out_dir: str | Path, methods: list[str], quiet: bool = False,
                    title: str = "") -> Path:
    """Run each comparison into ``out_dir/<comparison>/``; write ``table.md``, ``table.csv``
    and ``pr_curves.png`` (all methods in one plot). Returns the path of ``table.md``."""
    bad = [m for m in methods if m not in COMPARISONS]
    if bad:
        raise ValueError(f"unknown comparison(s) {', '.join(bad)}; choose from {', '.join(COMPARISONS)}")
    out_dir = Path(out_dir)
    rows, curves = [], {}
    for m in methods:
        cfg = copy.deepcopy(config)
        cfg["seqslam"]["comparison"] = m
        run_dir = out_dir / m
        run_all(cfg, run_dir, quiet=quiet)
        metrics = read_metrics(run_dir)
        rows.append(metrics)
        with h5py.File(run_dir / "evaluate.h5", "r") as f:
            curves[m] = (f["pr/recall"][()], f["pr/precision"][()])
    (out_dir / "table.md").write_text((f"### {title}\n\n" if title else "") + markdown_table(rows))
    with (out_dir / "table.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([k for k, _ in TABLE_COLUMNS])
        for r in rows:
            w.writerow([r.get(k) for k, _ in TABLE_COLUMNS])
    if config.get("plots", True):
        from placeloc.evaluation.plots import plot_pr_curves

        plot_pr_curves(curves, out_dir / "pr_curves.png", title=title or "SeqSLAM comparisons")
    return out_dir / "table.md"
