"""UMap on a generated home as a user runs it, over the cores a process has: a scaling table.

    python bench/bench_umap_home.py                    # home 21, pinned to 1, 2, 4, ..., nproc cores
    python bench/bench_umap_home.py --seed 0 --cores 1,2 --repeat 3

The home is ``placeloc experiment umap-homes``' own (``placeloc synth home`` of ``--seed``,
20 panoramas as the experiment's, or ``--panoramas``; seed 21 has 1,494 grid positions at
the default 0.25 m step), generated into ``--work`` unless it is there already. Its config is what a
user of a real home gives (the model, the panoramas, the query kind, the truth) and the
defaults. One ``placeloc run`` builds the artifacts; then ``placeloc localize CONFIG -f``
runs as its own process pinned to the first k usable cores (``sched_setaffinity``, as
``taskset``: its numba threads follow), best of ``--repeat`` after one warm-up. The table
shows localize's own seconds (the artifact's ``seconds``) and the process's wall time, each
also a panorama's share (the process's start-up spread over the panoramas).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import h5py
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "pipeline"))
sys.path.insert(0, str(ROOT / "bench"))

from scaling import counts_from, markdown, scaling_table, stage_process, usable_cores  # noqa: E402

from placeloc.experiments.umap_homes import PANORAMAS, shifted_grid  # noqa: E402
from placeloc.synth import generate  # noqa: E402


def home_config(data: Path, out: Path) -> Path:
    """A run config of a generated home (its folder ``data``) written to ``out``: the defaults."""
    cfg = {"method": "umap", "query": {"images": str(data / "panoramas")},
           "ground_truth": {"kind": "poses", "path": str(data / "poses.csv")},
           "umap": {"model": str(data / "floor_plan.yaml"), "query_kind": "panorama",
                    "grid": shifted_grid(data / "floor_plan.yaml", 0.0)},
           "plots": False}
    out.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=21, help="the generated home (experiment umap-homes' seeds)")
    ap.add_argument("--panoramas", type=int, default=PANORAMAS,
                    help=f"panoramas of the home (default {PANORAMAS}, the experiment's; the real home of docs/umap.md has 32)")
    ap.add_argument("--cores", default=None, help="comma-separated core counts (default 1, 2, 4, ..., nproc)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--work", type=Path, default=None,
                    help="folder for the home and its run, kept (default: a temporary one, removed at the end)")
    args = ap.parse_args()
    # absolute: the config written there names the home's files, read from the config's folder
    work = (args.work or Path(tempfile.mkdtemp(prefix="placeloc-umap-home-"))).resolve()
    work.mkdir(parents=True, exist_ok=True)
    try:
        run_table(args, work)
    finally:
        if args.work is None:  # the index alone is about 0.75 GB
            shutil.rmtree(work, ignore_errors=True)


def run_table(args: argparse.Namespace, work: Path) -> None:
    """The home in ``work`` (generated there unless it is), its artifacts, then the table."""
    t0 = time.perf_counter()
    data = work / "data" / f"home-seed{args.seed}-n{args.panoramas}"   # as the experiment names its homes
    if not (data / "poses.csv").is_file():
        generate("home", data, seed=args.seed, panoramas=args.panoramas)
    cfg = home_config(data, work / f"home{args.seed}.yaml")
    run = work / f"run-home{args.seed}"
    stage_process(cfg, run, "extract", usable_cores(), pin=True)  # the artifacts, once, on every core
    for stage in ("build-dictionary", "index"):
        stage_process(cfg, run, stage, usable_cores(), pin=True)
    with h5py.File(run / "index.h5", "r") as f:
        positions = len(f["poses"])

    def measure(k: int) -> dict[str, float]:
        own, wall = stage_process(cfg, run, "localize", k, pin=True)
        n = args.panoramas
        return {f"localize, {n} panoramas (stage)": own, "a panorama (stage)": own / n, "localize (process)": wall,
                "a panorama (process)": wall / n}

    counts = [c for c in counts_from(args.cores) if c <= usable_cores()]
    table = scaling_table(measure, counts, args.repeat)
    print()
    print(markdown(table, f"UMap, generated home {args.seed} ({positions:,} positions)", unit="core",
                   note=f"localize pinned to the first k cores, the defaults; best of {args.repeat} after a warm-up; "
                        f"`python bench/bench_umap_home.py --seed {args.seed} --panoramas {args.panoramas} --repeat {args.repeat}` took "
                        f"{time.perf_counter() - t0:.0f} s (the home's generation and index included)."))


if __name__ == "__main__":
    main()
