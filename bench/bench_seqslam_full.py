"""The Nordland preset's localize at full size, and its cost against straight trajectories.

    python bench/bench_seqslam_full.py --frames 3576           # preset vs trajectory, one run
    python bench/bench_seqslam_full.py --frames 35768 --only preset   # the full-size figure
    python bench/bench_seqslam_full.py --scaling       # the preset on 1, 2, 4, ..., nproc cores

Each traverse is ``--frames`` feature rows: nordland-dev's summer and winter thumbnails
(the preset's zscore patch features; shared data folder) tiled with noise, else random
rows. localize's numerics (``sequence_match``: difference matrix block by block with the
SAD kernel, enhancement, sequence search, confidence) run in this process with the
settings of ``configs/nordland.yaml``; ``trajectory`` is the same with
``sequence_shape: trajectory`` and the preset's switches (``collapse_stops``,
``backward_paths``) off, that is straight lines over the same speeds and the same
window. Shapes alternate (preset, trajectory, preset, trajectory) so both see the same
load; the ratio of the medians is printed. Extraction (decoding images, thumbnails) is
not in these figures: ``bench/bench_seqslam.py --large`` measures it (about 20 s at
36,000 frames). Prints wall time, CPU time, peak RSS and the load average; a figure
measured at fewer frames than 35,768 is scaled by the work (queries x references) and
printed as such.

``--scaling`` prints the preset's localize numerics on 1, 2, 4, ..., nproc cores (this
process pinned to the first ``w`` cores with ``sched_setaffinity``; the search runs one
thread per usable core), best of ``--repeat``, with the speed-up over one core.
"""

from __future__ import annotations

import argparse
import inspect
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "pipeline"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from placeloc.experiments import shared_data_dir  # noqa: E402
from placeloc.experiments.seqslam_motion import preset  # noqa: E402
from placeloc.seqslam.matching import sequence_match  # noqa: E402

FULL = 35768  # frames a season in the whole Nordland route


def features(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` reference and ``n`` query feature rows (the preset's features)."""
    from placeloc.core.images import list_images
    from placeloc.seqslam.features import image_features

    p = preset()
    rng = np.random.default_rng(seed)
    data = shared_data_dir()
    if data is None or not (data / "nordland-dev").is_dir():
        print("data: random rows (nordland-dev not found)")
        return (rng.normal(0, 1, (n, 2048)).astype(np.float32), rng.normal(0, 1, (n, 2048)).astype(np.float32))
    out = []
    for season in ("summer", "winter"):
        paths = [str(x) for x in list_images(data / "nordland-dev" / season).paths]
        f, _, _, _ = image_features(paths, on_error="raise", thumbnail_size=tuple(p["thumbnail"]), comparison=p["comparison"],
                                    patch=p["patch"], normalisation=p["normalisation"],
                                    gaussian_sigma=p["gaussian_sigma"], ocm_epsilon=p["ocm_epsilon"])
        tiled = f[np.arange(n) % len(f)]
        out.append((tiled + rng.normal(0, 0.05, tiled.shape)).astype(f.dtype))
    print(f"data: {n} + {n} rows, nordland-dev tiled with noise")
    return out[0], out[1]


def localize(ref: np.ndarray, query: np.ndarray, shape: str | None) -> tuple[float, float, np.ndarray]:
    """Wall and CPU seconds of localize's numerics with the preset (``shape`` overriding
    its sequence shape), and the best match per query."""
    p = preset()
    if shape is not None:  # the search alone, as `sequence_shape: trajectory` with the preset's switches off
        p.update(sequence_shape=shape, collapse_stops=False, backward_paths=False)
    # every setting of the preset that localize's numerics take (a switch the preset turns on included)
    takes = inspect.signature(sequence_match).parameters
    kw = {k: v for k, v in p.items() if k in takes and k not in ("ref", "query", "comparison", "exclude_recent")}
    c0, t0 = time.process_time(), time.perf_counter()
    m = sequence_match(ref, query, comparison=p["comparison"], exclude_recent=None, **kw)
    return time.perf_counter() - t0, time.process_time() - c0, m.candidates[:, 0]


def scaling(ref: np.ndarray, query: np.ndarray, args: argparse.Namespace) -> None:
    """The preset's localize numerics pinned to 1, 2, 4, ... cores: wall and CPU seconds."""
    from scaling import counts_from, markdown, on_first_cores, scaling_table

    def measure(w: int) -> dict[str, float]:
        with on_first_cores(w):
            wall, cpu, _ = localize(ref, query, None)
        return {"preset localize numerics, wall": wall, "preset localize numerics, CPU": cpu}

    table = scaling_table(measure, counts_from(args.workers), args.repeat)
    print(markdown(table, f"Nordland preset, {args.frames} x {args.frames}",
                   note="(CPU: all threads' seconds; the wall row's speed-up is the scaling)", unit="core"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3576, help="frames per traverse (35768: the whole route)")
    ap.add_argument("--only", choices=("preset", "both"), default="both",
                    help="preset: only the preset (the full-size figure); both: preset and trajectory, alternating")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--scaling", action="store_true", help="the preset on 1, 2, 4, ..., nproc cores (pinned), a table")
    ap.add_argument("--workers", default=None, help="core counts of the scaling table (default 1, 2, 4, ..., nproc)")
    args = ap.parse_args()
    ref, query = features(args.frames)
    if args.scaling:
        scaling(ref, query, args)
        return
    p = preset()
    print(f"preset: {p['sequence_shape']}, ds {p['ds']}, v {p['v_min']:g}..{p['v_max']:g} step {p['v_step']:g}, "
          f"v_auto {p['v_auto']}, block_size {p['block_size']}; {os.cpu_count()} cores")
    shapes = ["preset"] + (["trajectory"] if args.only == "both" else [])
    times: dict[str, list[float]] = {s: [] for s in shapes}
    cpus: dict[str, list[float]] = {s: [] for s in shapes}
    load0 = os.getloadavg()
    best = {}
    for _ in range(args.repeat if args.only == "both" else 1):
        for s in shapes:
            wall, cpu, best[s] = localize(ref, query, None if s == "preset" else s)
            times[s].append(wall)
            cpus[s].append(cpu)
            print(f"{s:10s} localize numerics: {wall:.1f} s wall, {cpu:.1f} s CPU, load {os.getloadavg()[0]:.1f}", flush=True)
    load1 = os.getloadavg()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1048576
    scale = (FULL / args.frames) ** 2
    cores = os.cpu_count() or 1
    for s in shapes:
        med, cpu = float(np.median(times[s])), float(np.median(cpus[s]))
        line = f"{s}: median {med:.1f} s wall, {cpu:.1f} s CPU at {args.frames} x {args.frames}"
        if args.frames != FULL:
            # under load, wall time includes waiting for other processes: CPU / cores is
            # what the same work takes on idle cores (the search runs one thread per core)
            line += (f"; scaled by the work to {FULL} x {FULL} (extrapolated): {med * scale / 60:.1f} min wall at this "
                     f"load, {cpu * scale / cores / 60:.1f} min on {cores} idle cores (CPU / cores)")
        print(line)
    if len(shapes) == 2:
        print(f"preset / trajectory (same window and speeds): wall {np.median(times['preset']) / np.median(times['trajectory']):.2f}x, "
              f"CPU {np.median(cpus['preset']) / np.median(cpus['trajectory']):.2f}x; "
              f"agreement of best matches {np.mean(best['preset'] == best['trajectory']):.3f}")
    print(f"peak RSS {rss:.2f} GB; load average (1 min) before/after {load0[0]:.1f} / {load1[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
