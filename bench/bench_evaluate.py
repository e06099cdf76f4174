"""What evaluate costs against the method: SeqSLAM extract, localize and evaluate, each as
its own process, at 3576 x 3576 (the frames of bench/bench_seqslam.py, SAD with the
centred search) with ground truth and pictures on, and on the demo (configs/demo.yaml).

    python bench/bench_evaluate.py                 # both problems, best of 3 after a warm-up
    python bench/bench_evaluate.py --demo          # the demo only
    python bench/bench_evaluate.py --no-plots      # scoring alone (plots: false), what the pictures cost aside
    python bench/bench_evaluate.py --tree OLD --tree .   # two source trees, turn about, in one run
    python bench/bench_evaluate.py --cores         # evaluate pinned to 1, 2, 4, ..., nproc cores

Prints, per problem and tree, wall and CPU seconds of each stage's process, the stage's own
seconds (its artifact's ``seconds``: process start-up and imports left out), and the ratio
evaluate / (extract + localize) of both, measured in the same run (goal: at most 0.25),
with the load average, since the machine may be shared. Also the floor every stage process
pays before any work: ``placeloc build-dictionary``, a stage SeqSLAM passes through
(start-up, imports, the config check, listing the images, the stamps).

A tree is a checkout's root: its ``pipeline/`` goes first on PYTHONPATH of every stage's
process (the default: this checkout). Trees run turn about, so load changes reach both.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))

from bench_seqslam import P, make_traverses  # noqa: E402

STAGES = ("extract", "localize", "evaluate")
FLOOR = "build-dictionary"  # SeqSLAM has no dictionary: the stage passes its input through

Times = dict[str, tuple[float, float, float]]  # stage -> (wall, CPU, the stage's own seconds)


def run_stage(tree: Path, stage: str, cfg: Path, run_dir: Path, cores: int | None = None) -> tuple[float, float, float]:
    """``placeloc STAGE CONFIG -o RUN_DIR -q -f`` as its own process with ``tree``'s code,
    pinned to the first ``cores`` usable cores (as ``taskset``) when given: (wall, CPU user +
    sys, the artifact's own seconds)."""
    import h5py

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree / "pipeline"), os.environ.get("PYTHONPATH", "")]))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    # as the installed `placeloc` script starts it (python -m would compile cli.py on every start)
    code = "import sys; from placeloc.cli import main; sys.argv[0] = 'placeloc'; sys.exit(main())"
    usable = sorted(os.sched_getaffinity(0)) if cores else []
    subprocess.run([sys.executable, "-c", code, stage, str(cfg), "-o", str(run_dir), "-q", "-f"], check=True,
                   capture_output=True, text=True, env=env,
                   preexec_fn=(lambda: os.sched_setaffinity(0, usable[:cores])) if cores else None)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    with h5py.File(run_dir / f"{stage}.h5", "r") as f:
        own = float(f.attrs.get("seconds", 0.0))
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), own


def stage_times(trees: list[Path], cfg: Path, work: Path, repeat: int) -> list[Times]:
    """Per tree, each stage's run with the best wall of ``repeat`` (after one warm-up round),
    the trees turn about in every round; each tree has its own run directory."""
    best: list[Times] = [{} for _ in trees]
    for i in range(repeat + 1):
        for k, tree in enumerate(trees):
            for stage in (*STAGES, FLOOR):
                t = run_stage(tree, stage, cfg, work / f"run{k}")
                if i > 0 and (stage not in best[k] or t[0] < best[k][stage][0]):
                    best[k][stage] = t
    return best


def core_counts() -> list[int]:
    """1, 2, 4, ... and the usable cores themselves."""
    n = len(os.sched_getaffinity(0))
    counts = [1 << i for i in range(n.bit_length()) if 1 << i < n]
    return [*counts, n]


def cores_table(tree: Path, cfg: Path, run_dir: Path, repeat: int) -> None:
    """Evaluate alone, its process pinned to 1, 2, 4, ..., nproc cores (its pictures are
    drawn on as many threads as it may use, up to four), best of ``repeat`` after a
    warm-up: own seconds and the speed-up against one core, measured in the same run."""
    for stage in ("extract", "localize"):
        run_stage(tree, stage, cfg, run_dir)
    counts = core_counts()
    best: dict[int, tuple[float, float, float]] = {}
    for i in range(repeat + 1):
        for k in counts:  # turn about, so load changes reach every count
            t = run_stage(tree, "evaluate", cfg, run_dir, cores=k)
            if i > 0 and (k not in best or t[2] < best[k][2]):
                best[k] = t
    print(f"  evaluate pinned to k cores (load average {os.getloadavg()[0]:.1f}; best of {repeat}):")
    print("    | cores | own | process wall | CPU | own, 1 core / k cores |")
    print("    |---|---|---|---|---|")
    for k in counts:
        wall, cpu, own = best[k]
        print(f"    | {k} | {own:.3f} s | {wall:.2f} s | {cpu:.2f} s | {best[1][2] / own:.2f}x |")


def report(name: str, trees: list[Path], times: list[Times]) -> None:
    print(f"{name}: load average {os.getloadavg()[0]:.1f}")
    for tree, t in zip(trees, times):
        print(f"  tree {tree}")
        for stage in STAGES:
            print(f"    {stage:9s} wall {t[stage][0]:7.2f} s  cpu {t[stage][1]:7.2f} s  own {t[stage][2]:7.3f} s")
        method_wall = t["extract"][0] + t["localize"][0]
        for what, k in (("process wall", 0), ("stage's own", 2)):
            method = t["extract"][k] + t["localize"][k]
            print(f"    {what:12s}: evaluate / (extract + localize) = {t['evaluate'][k]:.3f} / {method:.3f} = "
                  f"{t['evaluate'][k] / method:.2f}  (goal <= 0.25)")
        floor = t[FLOOR][0]
        print(f"    floor: a stage with no work ({FLOOR}) takes {floor:.2f} s wall ({t[FLOOR][1]:.2f} s CPU), "
              f"{floor / method_wall:.2f} of extract + localize; evaluate beyond it {t['evaluate'][0] - floor:.2f} s")


def measure(a: argparse.Namespace, trees: list[Path], name: str, cfg: Path, run_dir: Path) -> None:
    """One problem: the evaluate-over-cores table (``--cores``), else every tree's stages."""
    if a.cores:
        print(f"{name}, tree {trees[0]}")
        cores_table(trees[0], cfg, run_dir, a.repeat)
    else:
        report(name, trees, stage_times(trees, cfg, run_dir, a.repeat))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--demo", action="store_true", help="the demo only")
    ap.add_argument("--n", type=int, default=3576, help="frames per traverse")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-plots", action="store_true", help="plots: false (metrics.json and the CSVs only)")
    ap.add_argument("--cores", action="store_true",
                    help="instead: evaluate pinned to 1, 2, 4, ..., nproc cores (the first --tree, 3576 x 3576 and the demo)")
    ap.add_argument("--tree", action="append", type=Path, default=None,
                    help="a checkout whose pipeline/ runs the stages (repeatable; default: this one)")
    a = ap.parse_args()
    trees = [t.resolve() for t in (a.tree or [ROOT])]
    for tree in trees:
        if not (tree / "pipeline" / "placeloc").is_dir():
            sys.exit(f"--tree {tree}: holds no pipeline/placeloc; give a checkout's root")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        import yaml

        demo_file = ROOT / "configs" / "demo.yaml"
        cfg = yaml.safe_load(demo_file.read_text())
        for role in ("reference", "query"):
            cfg[role]["images"] = str((demo_file.parent / cfg[role]["images"]).resolve())
        cfg["ground_truth"]["path"] = str((demo_file.parent / cfg["ground_truth"]["path"]).resolve())
        cfg["plots"] = not a.no_plots
        demo = work / "demo.json"
        demo.write_text(json.dumps(cfg))
        (work / "demo").mkdir()
        measure(a, trees, f"demo (configs/demo.yaml, 81 x 81, pictures {'off' if a.no_plots else 'on'})", demo,
                work / "demo")
        if a.demo:
            return
        ref, q = make_traverses(work / "data", a.n)
        big = work / "bench.json"
        big.write_text(json.dumps({"method": "seqslam", "reference": {"images": str(ref)}, "query": {"images": str(q)},
                                   "ground_truth": {"kind": "synchronous", "tolerance": 2}, "plots": not a.no_plots,
                                   "seqslam": {"comparison": "sad", "search": P.search}}))
        (work / "big").mkdir()
        measure(a, trees, f"{a.n} x {a.n} (bench_seqslam settings, synchronous ground truth, pictures "
                f"{'off' if a.no_plots else 'on'})", big, work / "big")


if __name__ == "__main__":
    main()
