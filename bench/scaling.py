"""Per-stage scaling over workers: the common helper of the bench/ scripts, and the SeqSLAM table.

    python bench/scaling.py                       # SeqSLAM benchmark settings, 3576 x 3576, workers 1, 2, 4, ..., nproc
    python bench/scaling.py --workers 1,2 --n 600 # a quick check
    OUT=/some/folder python bench/scaling.py      # also writes $OUT/scaling.md
    python bench/scaling.py --preset-cores        # the Nordland preset's extract + localize pinned to 1, 2, ..., nproc cores
    python bench/scaling.py --preset              # the stage table with the Nordland preset (flexible search)

Each stage (extract, localize, evaluate) runs as its own ``placeloc`` process, as a user
runs it, with ``--set executor.workers=W``. The table shows the stage's own compute time
(the artifact's ``seconds``: process start-up and imports aside) and the process's wall
time, best of ``--repeat`` after one warm-up run (which fills the compiled-kernel cache and
the page cache), and the speed-up of each worker count over one worker. Wall-clock figures
on a shared machine include waiting for other processes: the load average is printed with
them.

The helpers (:func:`worker_counts`, :func:`scaling_table`, :func:`markdown`) are what the
other bench scripts use to print their own tables.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import h5py

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "pipeline"))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def usable_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def counts_from(spec: str | None, top: int | None = None) -> list[int]:
    """The counts a ``--workers 1,2,4`` option names, else :func:`worker_counts` up to ``top``."""
    return [int(w) for w in spec.split(",")] if spec else worker_counts(top)


@contextmanager
def on_first_cores(k: int) -> Iterator[None]:
    """This process pinned to its first ``k`` usable cores meanwhile (the threads its
    kernels start follow the CPU affinity), then to all of them again."""
    everyone = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, everyone[:k])
    try:
        yield
    finally:
        os.sched_setaffinity(0, everyone)


def worker_counts(top: int | None = None) -> list[int]:
    """1, 2, 4, ... up to ``top`` (default: the usable cores), ``top`` itself always last."""
    top = top or usable_cores()
    counts, w = [], 1
    while w < top:
        counts.append(w)
        w *= 2
    return counts + [top]


def scaling_table(measure: Callable[[int], dict[str, float]], workers: list[int], repeat: int = 1,
                  warm_up: bool = True) -> dict[str, dict[int, float]]:
    """``measure(w)`` -> {row name: seconds} for each worker count; best of ``repeat`` runs
    (after one warm-up run at the first count when ``warm_up``). Returns row -> w -> seconds."""
    if warm_up:
        measure(workers[0])
    table: dict[str, dict[int, float]] = {}
    for w in workers:
        for _ in range(repeat):
            for row, seconds in measure(w).items():
                cell = table.setdefault(row, {})
                cell[w] = min(cell.get(w, float("inf")), seconds)
        print(f"  workers {w}: " + ", ".join(f"{row} {cells[w]:.2f} s" for row, cells in table.items() if w in cells),
              flush=True)
    return table


def markdown(table: dict[str, dict[int, float]], title: str, note: str = "", unit: str = "worker") -> str:
    """The table as markdown: one row per measured thing, one column per worker count, and
    the speed-up of the largest count over one worker (a row named "... GB/s" holds rates:
    its speed-up is inverted accordingly)."""
    counts = sorted({w for cells in table.values() for w in cells})
    head = f"| {title} | " + " | ".join(f"{w} {unit}{'s' if w > 1 else ''}" for w in counts) + \
        f" | speed-up {counts[-1]} vs {counts[0]} |"
    lines = [head, "|---" * (len(counts) + 2) + "|"]
    for row, cells in table.items():
        rate = row.endswith("GB/s")
        values = " | ".join((f"{cells[w]:.1f}" if rate else f"{cells[w]:.2f} s") if w in cells else "" for w in counts)
        if rate:
            cells = {w: 1.0 / v for w, v in cells.items() if v > 0}
        ratio = cells[counts[0]] / cells[counts[-1]] if counts[0] in cells and counts[-1] in cells else float("nan")
        lines.append(f"| {row} | {values} | {ratio:.2f}x |")
    load = os.getloadavg()
    lines.append("")
    lines.append(f"{usable_cores()} usable cores ({os.cpu_count()} on the machine); load average {load[0]:.1f} / "
                 f"{load[1]:.1f} / {load[2]:.1f} (1 / 5 / 15 min) at the end. {note}".rstrip())
    return "\n".join(lines)


def _run_stage(cfg: Path, run_dir: Path, stage: str, workers: int) -> tuple[float, float]:
    """One stage as its own process: (the stage's own seconds, the process's wall seconds)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, str(ROOT / "cli.py"), stage, str(cfg), "-o", str(run_dir), "-q", "-f",
                    "--set", f"executor.workers={workers}"], check=True, capture_output=True, text=True,
                   env={**os.environ, "PYTHONPATH": str(ROOT / "pipeline")})
    wall = time.perf_counter() - t0
    with h5py.File(run_dir / f"{stage}.h5", "r") as f:
        return float(f.attrs["seconds"]), wall


def seqslam_stages(n: int, workers: list[int], repeat: int, work: Path, stages: tuple[str, ...],
                   preset: bool = False) -> dict[str, dict[int, float]]:
    """Each stage as its own process with ``executor.workers=W``: the benchmark settings, or
    with ``preset`` the Nordland preset's seqslam section (``configs/nordland.yaml``)."""
    import yaml
    from bench_seqslam import make_traverses, write_config

    ref_dir, q_dir = make_traverses(work / "data", n)
    cfg = write_config(work / "bench.yaml", ref_dir, q_dir)
    settings = json.loads(cfg.read_text())
    if preset:
        settings["seqslam"] = yaml.safe_load((ROOT / "configs" / "nordland.yaml").read_text())["seqslam"]
    cfg.write_text(json.dumps({**settings, "ground_truth": {"kind": "synchronous", "tolerance": 2}}))

    def measure(w: int) -> dict[str, float]:
        out = {}
        for stage in stages:
            own, wall = _run_stage(cfg, work / "run", stage, w)
            out[f"{stage} (stage)"], out[f"{stage} (process)"] = own, wall
        return out

    return scaling_table(measure, workers, repeat)


def kernel_scaling(features: Path, cores: list[int], repeat: int = 2) -> dict[str, dict[int, float]]:
    """SeqSLAM localize's three kernels on the benchmark's own feature rows, this process
    restricted to the first k usable cores (its threads follow the CPU affinity): the
    speed-up shows which kernels scale with cores, and the enhancement's bytes moved per
    second whether it is bound by memory bandwidth rather than by the cores."""
    import numpy as np

    from placeloc.seqslam.comparisons import difference_block
    from placeloc.seqslam.params import SeqSLAMParams
    from placeloc.seqslam.search import enhance_t, sequence_search, velocities

    p = SeqSLAMParams()
    with h5py.File(features, "r") as f:
        ref, query = f["reference/features"][()], f["query/features"][()]
    vels = velocities(p.v_min, p.v_max, p.v_step)
    table: dict[str, dict[int, float]] = {}
    for k in cores:
        with on_first_cores(k):
            best: dict[str, float] = {}
            for _ in range(repeat):
                t0 = time.perf_counter()
                d = difference_block(ref, query, "sad")
                t1 = time.perf_counter()
                et = enhance_t(np.ascontiguousarray(d.T), int(p.enhance_window))
                t2 = time.perf_counter()
                sequence_search(et, 0, len(query), int(p.ds), vels, "centred", int(p.enhance_window), int(p.top_k), None, 0,
                                shape=p.sequence_shape, edges=p.edges)
                t3 = time.perf_counter()
                for row, t in (("difference (L1 kernel)", t1 - t0), ("enhancement", t2 - t1), ("sequence search", t3 - t2)):
                    best[row] = min(best.get(row, float("inf")), t)
            for row, t in best.items():
                table.setdefault(row, {})[k] = t
            # the enhancement reads D^T and writes D^ once each (float32), plus its window sums
            table.setdefault("enhancement GB/s", {})[k] = 2 * d.nbytes / best["enhancement"] / 1e9
            print(f"  {k} cores: " + ", ".join(f"{r} {t:.3f} s" for r, t in best.items()), flush=True)
    return table


def preset_cores(n: int, cores: list[int], repeat: int, work: Path) -> dict[str, dict[int, float]]:
    """The Nordland preset (``configs/nordland.yaml``'s seqslam section, the flexible search)
    on the benchmark's 3576 + 3576 frames: ``placeloc extract`` and ``placeloc localize``,
    each its own process pinned to the first k usable cores (as ``taskset -c 0..k-1``), wall
    seconds, best of ``repeat`` after a warm-up (which fills the compiled-kernel caches)."""
    import yaml
    from bench_seqslam import make_traverses

    ref_dir, q_dir = make_traverses(work / "data", n)
    preset = yaml.safe_load((ROOT / "configs" / "nordland.yaml").read_text())
    cfg = work / "preset.yaml"
    cfg.write_text(json.dumps({"method": "seqslam", "reference": {"images": str(ref_dir)}, "query": {"images": str(q_dir)},
                               "plots": False, "seqslam": preset["seqslam"]}))
    everyone = sorted(os.sched_getaffinity(0))

    def measure(k: int) -> dict[str, float]:
        out: dict[str, float] = {}
        for stage in ("extract", "localize"):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, str(ROOT / "cli.py"), stage, str(cfg), "-o", str(work / "run"), "-q", "-f"],
                           check=True, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT / "pipeline")},
                           preexec_fn=lambda: os.sched_setaffinity(0, everyone[:k]))
            out[f"{stage} (process)"] = time.perf_counter() - t0
        out["extract + localize"] = out["extract (process)"] + out["localize (process)"]
        return out

    return scaling_table(measure, cores, repeat)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=3576, help="frames per traverse")
    ap.add_argument("--workers", default=None, help="comma-separated worker counts (default 1, 2, 4, ..., nproc)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--stages", default="extract,localize,evaluate")
    ap.add_argument("--no-kernels", action="store_true", help="leave out the per-kernel table over cores")
    ap.add_argument("--preset", action="store_true",
                    help="the stage table with the Nordland preset's seqslam section instead of the benchmark settings")
    ap.add_argument("--preset-cores", action="store_true",
                    help="instead: the Nordland preset's extract + localize pinned to 1, 2, ..., nproc cores")
    ap.add_argument("--out", type=Path, default=None, help="markdown file (default $OUT/scaling.md when OUT is set)")
    args = ap.parse_args()
    workers = counts_from(args.workers)
    out = args.out or (Path(os.environ["OUT"]) / "scaling.md" if os.environ.get("OUT") else None)
    work = Path(tempfile.mkdtemp(prefix="placeloc-scaling-"))
    t0 = time.perf_counter()
    kernels = None
    if args.preset_cores:
        cores = [c for c in (workers if args.workers else worker_counts()) if c <= usable_cores()]
        try:
            table = preset_cores(args.n, cores, args.repeat, work)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        print(markdown(table, f"Nordland preset, {args.n} x {args.n}", unit="core",
                       note=f"Each process pinned to the first k cores; best of {args.repeat} after a warm-up; "
                            f"`python bench/scaling.py --preset-cores --n {args.n}` took {time.perf_counter() - t0:.0f} s."))
        return
    try:
        table = seqslam_stages(args.n, workers, args.repeat, work, tuple(args.stages.split(",")), args.preset)
        if not args.no_kernels and not args.preset and hasattr(os, "sched_setaffinity"):
            cores = [c for c in workers if c <= usable_cores()]
            kernels = kernel_scaling(work / "run" / "extract.h5", cores)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    text = markdown(table, f"SeqSLAM {'Nordland preset' if args.preset else 'benchmark settings'}, {args.n} x {args.n}",
                    note=f"Best of {args.repeat} after a warm-up; `python bench/scaling.py --n {args.n} "
                         f"--workers {','.join(map(str, workers))}{' --preset' if args.preset else ''}` took {time.perf_counter() - t0:.0f} s.")
    if kernels:
        text += "\n\n" + markdown(kernels, "localize kernels, one process", unit="core",
                                   note="This process pinned to the first k cores (sched_setaffinity); its kernel "
                                        "threads follow.")
    print()
    print(text)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n")
        print(f"\nwritten to {out}")


if __name__ == "__main__":
    main()
