"""Where the Nordland preset's localize numerics spend their wall time on k cores: a timeline of parts.

    python bench/bench_seqslam_timeline.py                  # 1, 2, 4, ..., nproc cores
    python bench/bench_seqslam_timeline.py --cores 16,1 --frames 3576
    python bench/bench_seqslam_timeline.py --cores 16,8,1 --tiles 4096,1024,512   # + a table of tiles

localize's numerics (``sequence_match`` with the settings of ``configs/nordland.yaml``, as
``bench_seqslam_full.py`` runs them) on the rows of ``bench_seqslam_full.features``, this
process pinned to the first k cores (``sched_setaffinity``). Every call of each part (the
difference blocks, the enhancement, the flexible search's forward and backward families,
``collapse_stops``' search, ``standing_runs``, the ranking, the single-image baseline) is
timed on the thread that runs it. Per part, for the last of ``--repeat`` runs: its calls,
the threads that ran them, the span from the first start to the last end (seconds from the
run's start) and the summed seconds over threads. A part whose summed time grows with the
cores while its work does not is waiting on something shared (memory, a lock); a span with
one thread is work the others wait for. The first run of a process also loads the compiled
kernels.

With ``--tiles``, each core count runs once per tile of the flexible search
(``placeloc.seqslam.search.FLEXIBLE_TILE``: the references a thread's window rows span at a
time; smaller tiles fit a core's L2 but recompute a halo of references at each tile's
edges), and a last table gives the wall seconds of each (cores, tile), the answers checked
equal across tiles.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "pipeline"))
sys.path.insert(0, str(ROOT / "bench"))

from bench_seqslam_full import features, localize  # noqa: E402
from bench_seqslam_parts import instrument  # noqa: E402
from scaling import counts_from, on_first_cores  # noqa: E402

events: list[tuple[str, int, float, float]] = []  # (part, thread, start, end)


def recorded(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn``, each call's start and end recorded under ``name`` with its thread."""
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            events.append((name, threading.get_ident(), t, time.perf_counter()))
    return wrapper


def timeline(t0: float) -> None:
    """Per part of the last run (``events``, started at ``t0``): calls, threads, span and summed seconds."""
    parts: dict[str, list[tuple[float, float, int]]] = defaultdict(list)
    for name, thread, start, end in events:
        parts[name].append((start - t0, end - t0, thread))
    for name, calls in sorted(parts.items(), key=lambda kv: min(c[0] for c in kv[1])):
        print(f"    {name:34s} {len(calls):4d} calls on {len({c[2] for c in calls}):2d} threads, "
              f"span {min(c[0] for c in calls):6.2f}-{max(c[1] for c in calls):6.2f} s, "
              f"summed {sum(c[1] - c[0] for c in calls):6.2f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=3576, help="frames per traverse")
    ap.add_argument("--cores", default=None, help="comma-separated core counts (default 1, 2, 4, ..., nproc)")
    ap.add_argument("--repeat", type=int, default=2, help="runs per core count; the last one's timeline is printed")
    ap.add_argument("--tiles", default=None,
                    help="comma-separated tiles of the flexible search to run at each core count (default: the shipped one)")
    args = ap.parse_args()
    from placeloc.seqslam import search

    instrument(recorded, recorded)
    ref, query = features(args.frames)
    tiles = [int(t) for t in args.tiles.split(",")] if args.tiles else [search.FLEXIBLE_TILE]
    walls: dict[tuple[int, int], list[float]] = defaultdict(list)
    answers: dict[int, Any] = {}
    cores = counts_from(args.cores, len(os.sched_getaffinity(0)))
    for k in cores:
        for tile in tiles:
            search.FLEXIBLE_TILE = tile
            with on_first_cores(k):
                for run in range(args.repeat):
                    events.clear()
                    t0 = time.perf_counter()
                    wall, cpu, best = localize(ref, query, None)
                    walls[k, tile].append(wall)
                    answers.setdefault(tile, best)
                    print(f"{k} cores, tile {tile}, run {run + 1}: {wall:.2f} s wall, {cpu:.2f} s CPU, "
                          f"load {os.getloadavg()[0]:.1f}")
            timeline(t0)
    if len(tiles) > 1:
        same = all((answers[t] == answers[tiles[0]]).all() for t in tiles)
        print(f"\n| cores | {' | '.join(f'tile {t}' for t in tiles)} |")
        print("|---|" + "---|" * len(tiles))
        for k in cores:   # best of the runs after the first (which also loads the kernels), if any
            cells = [min(walls[k, t][1:] or walls[k, t]) for t in tiles]
            print(f"| {k} | {' | '.join(f'{c:.2f} s' for c in cells)} |")
        print(f"(wall seconds of the preset's localize numerics, {args.frames} x {args.frames}; "
              f"answers {'the same' if same else 'DIFFER'} across tiles)")

if __name__ == "__main__":
    main()
