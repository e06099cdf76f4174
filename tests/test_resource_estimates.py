"""The size estimates of placeloc.core.limits against what the stages really take.

For each method, the stages whose needs grow with the data run once on data large enough
that their own allocations stand out, each in a fresh process (tests/resource_probe.py):
the growth of the peak resident memory over what the process held before the stage, and
the bytes the stage wrote. Tolerance, as docs/reliability.md promises ("about a factor of
two, on the safe side"): estimate >= measured, and estimate <= 2 x measured + 32 MB for
memory (the allowance absorbs allocator and page-cache noise on stages that hold little),
+ 1 MB for disk.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from resource_probe import probe  # noqa: E402

MB = 1 << 20


def _check(rows: list[dict]) -> None:
    lines = []
    for r in rows:
        lines.append(f"{r['method']} {r['stage']}: memory estimate {r['estimate_memory'] / MB:.0f} MB, measured "
                     f"{r['measured_memory'] / MB:.0f} MB; disk estimate {r['estimate_disk'] / MB:.1f} MB, measured "
                     f"{r['measured_disk'] / MB:.1f} MB")
    report = "\n".join(lines)
    for r in rows:
        assert r["measured_memory"] <= r["estimate_memory"] <= 2 * r["measured_memory"] + 32 * MB, report
        assert r["measured_disk"] <= r["estimate_disk"] <= 2 * r["measured_disk"] + MB, report


def _prepare(config: Path, run: Path, sets: list[str]) -> None:
    from placeloc.core.config import load_config
    from placeloc.core.runner import run_all

    run_all(load_config(config, sets), run, quiet=True)


def test_seqslam_estimates(tmp_path):
    from placeloc.synth.route import generate

    generate(tmp_path / "data", seed=1, frames=1500)
    sets = ["plots=false"]
    _prepare(tmp_path / "data" / "config.yaml", tmp_path / "run", sets)
    _check(probe(tmp_path / "data" / "config.yaml", tmp_path / "run", sets, ["extract", "localize", "evaluate"]))


def test_umap_estimates(tmp_path):
    import yaml
    from test_umap_method import _tiny_corridor

    _tiny_corridor(tmp_path)
    cfg = {"method": "umap", "query": {"images": str(tmp_path / "q")},
           "ground_truth": {"kind": "poses", "path": str(tmp_path / "poses.csv")},
           "umap": {"model": str(tmp_path / "plan.yaml"), "sensor_csv": str(tmp_path / "sensor.csv"), "mode": "umap",
                    "camera": {"width": 160, "height": 120},
                    "grid": {"x": [0.4, 11.6, 0.04], "y": [0.4, 2.0, 0.04], "z": 1.14, "headings": [45.0, 135.0, 225.0, 315.0]}},
           "plots": False}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    _prepare(tmp_path / "c.yaml", tmp_path / "run", [])
    _check(probe(tmp_path / "c.yaml", tmp_path / "run", [], ["build-dictionary", "localize"]))


def test_coembed_estimates(tmp_path):
    from placeloc.synth import generate

    generate("coembed", tmp_path / "data", seed=0, steps=5000)
    cfg = tmp_path / "data" / "range.yaml"
    _prepare(cfg, tmp_path / "run", ["plots=false"])
    _check(probe(cfg, tmp_path / "run", ["plots=false"], ["extract", "localize"]))


def test_pirf_estimates(tmp_path):
    """PIRF's disk estimate is a cap (n_features descriptors a frame): frames with fewer
    features write less, so only its safe side is checked; memory both ways."""
    from placeloc.synth import generate

    generate("omni", tmp_path / "data", seed=0, frames=60, test_frames=20, width=360, layout="small", step=0.3)
    cfg = tmp_path / "data" / "config.yaml"
    cfg.write_text("method: pirf\nreference: {images: mapping}\nquery: {images: test}\n"
                   "ground_truth: {kind: poses, path: mapping/poses.csv, radius: 1.0}\n"
                   "pirf: {eps: 10, tau: 0.003, n_pmin: 20, query_poses: test/poses.csv}\n")
    _prepare(cfg, tmp_path / "run", ["plots=false"])
    rows = probe(cfg, tmp_path / "run", ["plots=false"], ["extract", "build-dictionary"])
    for r in rows:
        assert r["measured_disk"] <= r["estimate_disk"], r
        r["estimate_disk"] = r["measured_disk"]  # the cap is checked above; _check then tests memory
    _check(rows)


def test_seqslam_whole_run_disk_with_plots(route, tmp_path):
    """The disk a whole run writes, pictures and report.html included (what a user sees in
    du -s RUN_DIR), against the sum of the stages' estimates."""
    from placeloc.core.config import load_config
    from placeloc.core.limits import estimate
    from placeloc.core.methods import STAGES
    from placeloc.core.runner import image_sets, run_all

    cfg = load_config(route / "config.yaml", ["plots=true"])
    run_all(cfg, tmp_path / "run", quiet=True)
    written = sum(p.stat().st_size for p in (tmp_path / "run").rglob("*") if p.is_file())
    estimated = sum(n.disk for n in estimate(cfg, image_sets(cfg), STAGES))
    assert written <= estimated <= 2 * written, (written, estimated)


def test_umap_panorama_estimates_with_the_grid_from_the_model(tmp_path):
    """Panoramas with the default grid (the plan's bounds at grid.step_m): the estimate counts
    the positions inside the plan and the chamfer index's row spectra, which localize reads
    whole. At 0.12 m the plan holds about 2,100 positions, the size of a real home's grid."""
    import csv

    import cv2
    import numpy as np
    import yaml
    from test_umap_panorama import PLAN, _grey_panorama

    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(PLAN))
    (tmp_path / "q").mkdir()
    rng = np.random.default_rng(2)
    with open(tmp_path / "poses.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "z", "heading_deg"])
        for k, pose in enumerate([(1.2, 1.1, 1.4, 30.0), (4.9, 2.6, 1.4, 200.0)]):
            cv2.imwrite(str(tmp_path / "q" / f"p{k}.png"), _grey_panorama(pose, rng))
            w.writerow([f"p{k}.png", *pose])
    cfg = {"method": "umap", "query": {"images": str(tmp_path / "q")},
           "ground_truth": {"kind": "poses", "path": str(tmp_path / "poses.csv")},
           "umap": {"model": str(tmp_path / "plan.yaml"), "query_kind": "panorama", "grid": {"step_m": 0.12, "z": 1.4},
                    "panorama": {"refine_candidates": 0}},
           "plots": False}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    _prepare(tmp_path / "c.yaml", tmp_path / "run", [])
    _check(probe(tmp_path / "c.yaml", tmp_path / "run", [], ["index", "localize"]))
