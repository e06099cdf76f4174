"""Per-stage scaling over workers: the common helper of the bench/ scripts, and the SeqSLAM table.

    python bench/scaling.py                       # SeqSLAM benchmark settings, 3576 x 3576, workers 1, 2, 4, ..., nproc
    python bench/scaling.py --workers 1,2 --n 600 # a quick check
    OUT=/some/folder python bench/scaling.py      # also writes $OUT/scaling.md
    python bench/scaling.py --cores               # each stage pinned to 1, 2, 4, ..., nproc cores instead
    python bench/scaling.py --preset              # the Nordland preset (flexible search) instead of the benchmark settings
    python bench/scaling.py --preset-cores        # the preset's extract + localize pinned to 1, 2, ..., nproc cores

Each stage (extract, localize, evaluate) runs as its own ``placeloc`` process, as a user
runs it, with ``--set executor.workers=W`` (one worker is this process with threads on every
usable core, so that table shows what more processes add), or with ``--cores`` pinned to
the first k cores (``sched_setaffinity``, as ``taskset``), which shows how the stage scales
with the cores it has. The table shows the stage's own compute time
(the artifact's ``seconds``: process start-up and imports aside) and the process's wall
time, best of ``--repeat`` after one warm-up run (which fills the compiled-kernel cache and
the page cache), and the speed-up of each worker count over one worker. Wall-clock figures
on a shared machine include waiting for other processes: the load average is printed with
them.

The helpers (:func:`worker_counts`, :func:`scaling_table`, :func:`markdown`, :func:`stage_process`) are what the
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

from placeloc.core.executor import usable_cores  # noqa: E402  (re-exported: the bench scripts' core count)


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


def stage_process(cfg: Path, run_dir: Path, stage: str, count: int, pin: bool) -> tuple[float, float]:
    """One stage as its own process: (the stage's own seconds, the process's wall seconds).
    ``pin``: the process pinned to the first ``count`` usable cores (as ``taskset -c
    0..count-1``) with the default workers; else ``executor.workers=count`` on every core."""
    everyone = sorted(os.sched_getaffinity(0)) if pin else []
    extra = [] if pin else ["--set", f"executor.workers={count}"]
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, str(ROOT / "cli.py"), stage, str(cfg), "-o", str(run_dir), "-q", "-f", *extra],
                          capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT / "pipeline")},
                          preexec_fn=(lambda: os.sched_setaffinity(0, everyone[:count])) if pin else None)
    wall = time.perf_counter() - t0
    if done.returncode != 0:  # the stage's own words, not only its exit status
        said = (done.stderr.strip() or done.stdout.strip())[-2000:]
        raise SystemExit(f"placeloc {stage} {cfg} -o {run_dir} failed (exit {done.returncode}):\n{said}")
    with h5py.File(run_dir / f"{stage}.h5", "r") as f:
        return float(f.attrs["seconds"]), wall


def seqslam_stages(n: int, counts: list[int], repeat: int, work: Path, stages: tuple[str, ...],
                   preset: bool = False, pin: bool = False) -> dict[str, dict[int, float]]:
    """Each stage as its own process, over ``executor.workers`` (or, with ``pin``, over the
    cores it is pinned to): the benchmark settings, or with ``preset`` the Nordland preset's
    seqslam section (``configs/nordland.yaml``, the flexible search)."""
    import yaml
    from bench_seqslam import make_traverses, write_config

    ref_dir, q_dir = make_traverses(work / "data", n)
    cfg = write_config(work / "bench.yaml", ref_dir, q_dir)
    settings = json.loads(cfg.read_text())
    if preset:
        settings["seqslam"] = yaml.safe_load((ROOT / "configs" / "nordland.yaml").read_text())["seqslam"]
    cfg.write_text(json.dumps({**settings, "ground_truth": {"kind": "synchronous", "tolerance": 2}}))

    def measure(k: int) -> dict[str, float]:
        out = {}
        for stage in stages:
            own, wall = stage_process(cfg, work / "run", stage, k, pin)
            out[f"{stage} (stage)"], out[f"{stage} (process)"] = own, wall
        if "extract" in stages and "localize" in stages:
            out["extract + localize (stage)"] = out["extract (stage)"] + out["localize (stage)"]
            out["extract + localize (process)"] = out["extract (process)"] + out["localize (process)"]
        return out

    return scaling_table(measure, counts, repeat)


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=3576, help="frames per traverse")
    ap.add_argument("--workers", default=None, help="comma-separated worker counts (default 1, 2, 4, ..., nproc)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--stages", default="extract,localize,evaluate")
    ap.add_argument("--no-kernels", action="store_true", help="leave out the per-kernel table over cores")
    ap.add_argument("--preset", action="store_true",
                    help="the Nordland preset's seqslam section (the flexible search) instead of the benchmark settings")
    ap.add_argument("--cores", action="store_true",
                    help="each stage's process pinned to 1, 2, 4, ..., nproc cores (default workers) instead of over workers")
    ap.add_argument("--preset-cores", action="store_true", help="short for --preset --cores --stages extract,localize")
    ap.add_argument("--out", type=Path, default=None, help="markdown file (default $OUT/scaling.md when OUT is set)")
    args = ap.parse_args()
    if args.preset_cores:
        args.preset, args.cores, args.stages = True, True, "extract,localize"
    counts = counts_from(args.workers)
    if args.cores:
        counts = [c for c in counts if c <= usable_cores()]
    out = args.out or (Path(os.environ["OUT"]) / "scaling.md" if os.environ.get("OUT") else None)
    work = Path(tempfile.mkdtemp(prefix="placeloc-scaling-"))
    t0 = time.perf_counter()
    kernels = None
    try:
        table = seqslam_stages(args.n, counts, args.repeat, work, tuple(args.stages.split(",")), args.preset, args.cores)
        if not args.no_kernels and not args.preset and hasattr(os, "sched_setaffinity"):
            kernels = kernel_scaling(work / "run" / "extract.h5", [c for c in counts if c <= usable_cores()])
    finally:
        shutil.rmtree(work, ignore_errors=True)
    command = (f"`python bench/scaling.py --n {args.n} --workers {','.join(map(str, counts))} --repeat {args.repeat} "
               f"--stages {args.stages}{' --preset' if args.preset else ''}{' --cores' if args.cores else ''}`")
    how = ("Each stage's process pinned to the first k cores (its threads follow), default workers"
           if args.cores else "Each stage's process with executor.workers = k, on every core")
    text = markdown(table, f"SeqSLAM {'Nordland preset' if args.preset else 'benchmark settings'}, {args.n} x {args.n}",
                    unit="core" if args.cores else "worker",
                    note=f"{how}; best of {args.repeat} after a warm-up; {command} took {time.perf_counter() - t0:.0f} s.")
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
