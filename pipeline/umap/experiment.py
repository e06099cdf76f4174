"""``placeloc experiment umap``: UMap vs UMap+CA on the synthetic corridor building.

Generates the building and its 50-frame sequence under ``OUT/data/corridor`` (not
committed), runs each variant into ``OUT/<run>/`` and writes ``OUT/summary.json`` (run name
-> metrics) and ``OUT/table.md`` beside the paper's figures.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from pipeline.config import load_config
from pipeline.experiments import write_summary
from pipeline.runner import read_metrics, run_all
from pipeline.synth import generate

log = logging.getLogger("placeloc")

PAPER = {"umap": {"max_error_m": 76.11, "within_0_5m": 0.10}, "umap+ca": {"max_error_m": 1.42, "within_0_5m": 0.70}}

# run name -> overrides of the umap section
VARIANTS: dict[str, dict[str, Any]] = {
    "corridor-umap": {"mode": "umap"},
    "corridor-umap+ca": {"mode": "umap+ca"},
    "corridor-umap+ca-paper-anchor": {"mode": "umap+ca", "ca": {"anchor": "best"}},
    "corridor-umap+ca-paper-eq": {"mode": "umap+ca", "ca": {"formula": "paper"}},
}


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    out_dir = Path(out_dir).resolve()
    data = out_dir / "data" / "corridor"
    if not (data / "poses.csv").is_file():
        log.info("generating the synthetic corridor building in %s", data)
        generate("corridor", data, seed=0)
    variants = dict(list(VARIANTS.items())[:2]) if quick else VARIANTS
    summary: dict[str, dict[str, Any]] = {}
    for name, umap in variants.items():
        cfg = load_config(data={
            "method": "umap",
            "query": {"images": str(data / "images")},
            "ground_truth": {"kind": "poses", "path": str(data / "poses.csv")},
            "umap": {"model": str(data / "floor_plan.yaml"), "sensor_csv": str(data / "sensor.csv"), **umap},
            "executor": {"workers": 2},
        }, base_dir=out_dir)
        log.info("experiment umap: %s", name)
        run_all(cfg, out_dir / name, quiet=quiet)
        summary[name] = read_metrics(out_dir / name)
    write_summary(out_dir, summary)
    lines = ["| run | max error [m] | mean [m] | median [m] | within 0.5 m | within 1 m | paper max [m] | paper within 0.5 m |",
             "|---|---|---|---|---|---|---|---|"]
    for name, m in summary.items():
        p = PAPER["umap" if m["mode"] == "umap" else "umap+ca"]
        lines.append(f"| {name} | {m['max_error_m']:.2f} | {m['mean_error_m']:.2f} | {m['median_error_m']:.2f} | "
                     f"{m['within_0_5m']:.0%} | {m['within_1m']:.0%} | {p['max_error_m']} | {p['within_0_5m']:.0%} |")
    (out_dir / "table.md").write_text("\n".join(lines) + "\n")
    if not quiet:
        print("\n".join(lines))
    return out_dir / "summary.json"
