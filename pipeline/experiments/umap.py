"""``placeloc experiment umap``: UMap vs UMap+CA on synthetic corridor buildings.

Generates three differently seeded corridor sequences under ``OUT/data/`` (not committed):
seed 2 only calibrates the CA error statistics of the robust tracker (median and MAD of the
CA step error on the frames whose vote is reliable, and the median true step of those whose
vote is not: :func:`placeloc.umap.ca.calibrate`); seeds 0 and 1 are the test sequences,
never looked at for any parameter. Each variant runs into ``OUT/<run>/`` and the results go
to ``OUT/summary.json`` (run name -> metrics, plus the calibration) and ``OUT/table.md``.
"""

from __future__ import annotations

import csv
import logging
from pathlib import Path
from typing import Any

import numpy as np
from placeloc.config import load_config
from placeloc.evaluation.poses import read_poses
from placeloc.experiments import write_summary
from placeloc.runner import read_metrics, run_all
from placeloc.synth import generate
from placeloc.umap import ca as ca_mod
from placeloc.umap.params import UMapParams

log = logging.getLogger("placeloc")

PAPER = {"umap": {"max_error_m": 76.11, "within_0_5m": 0.10}, "umap+ca": {"max_error_m": 1.42, "within_0_5m": 0.70}}
TEST_SEEDS = (0, 1)
CALIBRATION_SEED = 2

# run name -> overrides of the umap section; "calibrated" ones get the seed-2 CA statistics
VARIANTS: dict[str, dict[str, Any]] = {
    "umap": {"mode": "umap"},
    "umap+ca": {"mode": "umap+ca"},
    "umap+ca-no-laser": {"mode": "umap+ca", "ca": {"use_laser": False}},
    "umap+ca-paper-tracker": {"mode": "umap+ca", "ca": {"tracker": "paper"}},
    "umap+ca-paper-tracker-anchor": {"mode": "umap+ca", "ca": {"tracker": "paper", "anchor": "best"}},
}
CALIBRATED = ("umap+ca", "umap+ca-no-laser")


def _data(root: Path, seed: int) -> Path:
    d = root / "data" / f"corridor-seed{seed}"
    if not (d / "poses.csv").is_file():
        log.info("generating the synthetic corridor building (seed %d) in %s", seed, d)
        generate("corridor", d, seed=seed)
    return d


def calibrate_on(data: Path, ca: Any, hfov_deg: float) -> dict[str, Any]:
    """CA error statistics of one generated sequence (see :func:`placeloc.umap.ca.calibrate`);
    ``ca`` the ``umap.ca`` parameters (a :class:`placeloc.umap.params.CAParams`)."""
    gt = read_poses(data / "poses.csv")
    with open(data / "sensor.csv", newline="") as f:
        sensor = {r["frame"]: r for r in csv.DictReader(f)}
    return ca_mod.calibrate([data / "images" / k for k in gt.keys], gt.xy, round(float(np.degrees(gt.heading[0])), 9),
                            np.array([float(sensor[k]["d"]) for k in gt.keys]),
                            np.array([float(sensor[k]["theta_deg"]) for k in gt.keys]), hfov_deg,
                            akaze_threshold=ca.akaze_threshold, wall_right=ca.wall_side == "right",
                            vote_tol_m=ca.vote_tol_m, vote_rel_tol=ca.vote_rel_tol,
                            reliable_matches=ca.reliable_matches, reliable_ratio=ca.reliable_ratio)


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    out_dir = Path(out_dir).resolve()
    p = UMapParams()
    cal = calibrate_on(_data(out_dir, CALIBRATION_SEED), p.ca, p.camera.hfov_deg)
    log.info("CA calibration on seed %d: %s", CALIBRATION_SEED, cal)
    cal_ca = {k: cal[k] for k in ("error_mean_m", "error_std_m", "fallback_step_m")}
    variants = dict(list(VARIANTS.items())[:2]) if quick else VARIANTS
    summary: dict[str, dict[str, Any]] = {}
    for seed in TEST_SEEDS:
        data = _data(out_dir, seed)
        for vname, umap in variants.items():
            name = f"seed{seed}-{vname}"
            umap = {**umap, "ca": {**umap.get("ca", {}), **(cal_ca if vname in CALIBRATED else {})}}
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
    write_summary(out_dir, {**summary, "calibration": {"seed": CALIBRATION_SEED, **cal}})
    lines = ["| run | max error [m] | mean [m] | median [m] | within 0.5 m | within 1 m | paper max [m] | paper within 0.5 m |",
             "|---|---|---|---|---|---|---|---|"]
    for name, m in summary.items():
        p = PAPER["umap" if m["mode"] == "umap" else "umap+ca"]
        lines.append(f"| {name} | {m['max_error_m']:.2f} | {m['mean_error_m']:.2f} | {m['median_error_m']:.2f} | "
                     f"{m['within_0_5m']:.0%} | {m['within_1m']:.0%} | {p['max_error_m']} | {p['within_0_5m']:.0%} |")
    lines.append("")
    lines.append(f"CA calibration (seed {CALIBRATION_SEED}): error median {cal['error_mean_m']:+.3f} m, "
                 f"MAD-std {cal['error_std_m']:.3f} m, fallback step {cal['fallback_step_m']:.2f} m "
                 f"({cal['n_reliable']} reliable, {cal['n_failed']} unreliable steps)")
    (out_dir / "table.md").write_text("\n".join(lines) + "\n")
    if not quiet:
        print("\n".join(lines))
    return out_dir / "summary.json"
