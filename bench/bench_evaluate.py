"""What evaluate costs against the method: SeqSLAM extract, localize and evaluate, each as
its own process, at 3576 x 3576 (the frames of bench/bench_seqslam.py, SAD with the
centred search) with ground truth and pictures on, and on the demo (configs/demo.yaml).

    python bench/bench_evaluate.py            # both problems, best of 3 after a warm-up
    python bench/bench_evaluate.py --demo     # the demo only
    python bench/bench_evaluate.py --no-plots # scoring alone (plots: false), what the pictures cost aside

Prints, per problem, wall and CPU seconds of each stage's process, the stage's own
seconds (its artifact's ``seconds``: process start-up and imports left out), and the ratio
evaluate / (extract + localize) of both, measured in the same run (goal: at most 0.25),
with the load average, since the machine may be shared.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))

from bench_seqslam import P, make_traverses, run_cli  # noqa: E402

STAGES = ("extract", "localize", "evaluate")


def stage_times(cfg: Path, run_dir: Path, repeat: int) -> dict[str, tuple[float, float, float]]:
    """Each stage as ``placeloc STAGE CONFIG -o RUN_DIR -f``: (wall, CPU, the stage's own
    seconds) of the run with the best wall of ``repeat``, after a warm-up run."""
    import h5py

    best: dict[str, tuple[float, float, float]] = {}
    for i in range(repeat + 1):
        for stage in STAGES:
            wall, cpu = run_cli([stage, str(cfg), "-o", str(run_dir), "-q", "-f"])
            with h5py.File(run_dir / f"{stage}.h5", "r") as f:
                own = float(f.attrs["seconds"])
            if i > 0 and (stage not in best or wall < best[stage][0]):
                best[stage] = (wall, cpu, own)
    return best


def report(name: str, t: dict[str, tuple[float, float, float]]) -> None:
    print(f"{name}: load average {os.getloadavg()[0]:.1f}")
    for stage in STAGES:
        print(f"  {stage:9s} wall {t[stage][0]:7.2f} s  cpu {t[stage][1]:7.2f} s  own {t[stage][2]:7.2f} s")
    for what, k in (("process wall", 0), ("stage's own", 2)):
        method = t["extract"][k] + t["localize"][k]
        print(f"  {what:12s}: evaluate / (extract + localize) = {t['evaluate'][k]:.2f} / {method:.2f} = "
              f"{t['evaluate'][k] / method:.2f}  (goal <= 0.25)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--demo", action="store_true", help="the demo only")
    ap.add_argument("--n", type=int, default=3576, help="frames per traverse")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-plots", action="store_true", help="plots: false (metrics.json and the CSVs only)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        demo = ROOT / "configs" / "demo.yaml"
        if a.no_plots:
            import yaml

            cfg = yaml.safe_load(demo.read_text())
            for role in ("reference", "query"):
                cfg[role]["images"] = str((demo.parent / cfg[role]["images"]).resolve())
            cfg["ground_truth"]["path"] = str((demo.parent / cfg["ground_truth"]["path"]).resolve())
            cfg["plots"] = False
            demo = work / "demo.json"
            demo.write_text(json.dumps(cfg))
        report(f"demo (configs/demo.yaml, 81 x 81{', plots: false' if a.no_plots else ''})",
               stage_times(demo, work / "demo", a.repeat))
        if a.demo:
            return
        ref, q = make_traverses(work / "data", a.n)
        cfg = work / "bench.json"
        cfg.write_text(json.dumps({"method": "seqslam", "reference": {"images": str(ref)}, "query": {"images": str(q)},
                                   "ground_truth": {"kind": "synchronous", "tolerance": 2}, "plots": not a.no_plots,
                                   "seqslam": {"comparison": "sad", "search": P.search}}))
        report(f"{a.n} x {a.n} (bench_seqslam settings, synchronous ground truth, pictures {'off' if a.no_plots else 'on'})",
               stage_times(cfg, work / "run", a.repeat))


if __name__ == "__main__":
    main()
