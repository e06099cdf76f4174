"""``placeloc experiment umap-homes``: the whole-panorama defaults chosen on development
homes by a stated rule, then reported on other homes.

1. Development homes (``placeloc synth home``, seeds 0-2, 20 panoramas each): every
   setting of :data:`SWEEP` runs the pipeline with the model's own grid; the rule: the
   setting with the highest mean share within 1 m and 30 degrees over the three homes
   wins; among settings within one panorama (0.017) of it, the cheapest (fewest refined
   candidates, then the shortest list of changes from the plain settings) wins, since a
   difference of one panorama in sixty is noise.
2. Test homes (seeds 10-14, never looked at for any setting): the defaults (chamfer) and
   the paper's eq. (1) with the same refinement; worst, median and best share within 1 m
   and 30 degrees over the five homes, and the line statistics beside the real home's.

Writes ``OUT/dev.md``, ``OUT/table.md`` and ``OUT/summary.json``.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.core.config import load_config
from placeloc.core.runner import read_metrics, run_all
from placeloc.experiments import write_summary
from placeloc.experiments.umap import home_table
from placeloc.synth import generate

log = logging.getLogger("placeloc")

DEV_SEEDS = (0, 1, 2)
TEST_SEEDS = (10, 11, 12, 13, 14)
PANORAMAS = 20
# name -> umap.panorama overrides; refine_candidates is the cost (renders per panorama)
SWEEP: dict[str, dict[str, Any]] = {
    "chamfer, no refinement": {"refine_candidates": 0},
    "chamfer, 2 refined": {"refine_candidates": 2},
    "chamfer, 4 refined": {"refine_candidates": 4},
    "chamfer, 8 refined": {"refine_candidates": 8},
    "chamfer, 8 refined, LSD lines >= 16 px": {"refine_candidates": 8, "lsd_min_length_px": 16.0},
    "chamfer, 8 refined, LSD lines >= 24 px": {"refine_candidates": 8, "lsd_min_length_px": 24.0},
    "chamfer, 8 refined, rows beyond 60 deg weight 0.5": {"refine_candidates": 8, "polar_weight": 0.5},
    "chamfer, 8 refined, rows beyond 60 deg weight 0": {"refine_candidates": 8, "polar_weight": 0.0},
    "iou, 8 refined": {"score": "iou", "refine_candidates": 8},
}
NOISE = 1.0 / 60.0   # one panorama of the sixty development panoramas


def _home(root: Path, seed: int) -> Path:
    d = root / "data" / f"home-seed{seed}-n{PANORAMAS}"
    if not (d / "poses.csv").is_file():
        log.info("generating the synthetic home (seed %d) in %s", seed, d)
        generate("home", d, seed=seed, panoramas=PANORAMAS)
    return d


def _run(root: Path, name: str, data: Path, panorama: dict[str, Any], quiet: bool) -> dict[str, Any]:
    # only what a user of a real home gives: the model, the images, the query kind, the truth
    cfg = load_config(data={"method": "umap", "query": {"images": str(data / "panoramas")},
                            "ground_truth": {"kind": "poses", "path": str(data / "poses.csv")},
                            "umap": {"model": str(data / "floor_plan.yaml"), "query_kind": "panorama", "panorama": panorama},
                            "executor": {"workers": 1}, "plots": False}, base_dir=root)
    run_all(cfg, root / name, quiet=quiet)
    return {**read_metrics(root / name), "line_stats": json.loads((data / "line_stats.json").read_text())}


def choose(results: dict[str, list[float]]) -> str:
    """The rule of the module docstring: name -> shares within 1 m and 30 deg per home."""
    means = {k: float(np.mean(v)) for k, v in results.items()}
    top = max(means.values())
    near = [k for k in SWEEP if k in means and means[k] >= top - NOISE - 1e-12]
    return min(near, key=lambda k: (SWEEP[k].get("refine_candidates", 8), len(SWEEP[k])))


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    out_dir = Path(out_dir).resolve()
    dev: dict[str, list[float]] = {}
    runs: dict[str, dict[str, Any]] = {}
    sweep = dict(list(SWEEP.items())[:2]) if quick else SWEEP
    for name, over in sweep.items():
        for seed in DEV_SEEDS[:1] if quick else DEV_SEEDS:
            key = f"dev-home{seed}-" + name.replace(", ", "-").replace(" ", "_").replace(">=", "ge")
            m = _run(out_dir, key, _home(out_dir, seed), over, quiet)
            runs[key] = m
            dev.setdefault(name, []).append(m["within_1m_30deg"])
    chosen = choose(dev)
    lines = ["Development homes (seeds " + ", ".join(map(str, DEV_SEEDS)) + "), share within 1 m and 30 deg:", "",
             "| setting | per home | mean |", "|---|---|---|"]
    lines += [f"| {k} | {' / '.join(f'{x:.0%}' for x in v)} | {np.mean(v):.1%} |" for k, v in dev.items()]
    lines += ["", f"Chosen by the rule (highest mean; within one panorama of it, the fewest refined candidates, then "
              f"the fewest changes): **{chosen}**"]
    (out_dir / "dev.md").write_text("\n".join(lines) + "\n")
    homes: dict[str, dict[str, Any]] = {}
    for seed in TEST_SEEDS[:2] if quick else TEST_SEEDS:
        data = _home(out_dir, seed)
        for score in ("chamfer", "iou"):
            name = f"home{seed}-panorama-{score}"
            homes[name] = _run(out_dir, name, data, {} if score == "chamfer" else {"score": "iou"}, quiet)
    write_summary(out_dir, {**runs, **homes, "chosen": {"setting": chosen}})
    table = lines + ["", "Test homes (seeds " + ", ".join(map(str, TEST_SEEDS)) + "), the defaults (chamfer) and eq. (1) "
                     "with the same refinement:", ""] + home_table(homes)
    (out_dir / "table.md").write_text("\n".join(table) + "\n")
    if not quiet:
        print("\n".join(table))
    return out_dir / "summary.json"
