"""Where the Nordland preset's localize spends its CPU, part by part, against straight trajectories.

    python bench/bench_seqslam_parts.py --frames 3576

localize's numerics (``sequence_match``) with the settings of ``configs/nordland.yaml`` on
the rows of ``bench_seqslam_full.features`` (nordland-dev's features tiled with noise), the
preset and straight trajectories (``sequence_shape: trajectory``, switches off: the same
speeds and window) alternating, ``--repeat`` times each, on one core: this process is
pinned to one CPU, so every part runs on the calling thread and ``time.process_time``
around a function is that function's CPU. (Set ``NUMBA_NUM_THREADS=1`` too.) The parts:
the difference matrix (with numba's load, which runs on a thread meanwhile in a process's
first flexible search), the enhancement, the flexible search's forward family and
``backward_paths``' family, ``collapse_stops``' second search (and within it its own
difference blocks, if any), ``standing_runs``, the ranking, the single-image baseline
and the straight-line search. Prints seconds per part and run, and the load average.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "pipeline"))
sys.path.insert(0, str(ROOT / "bench"))

from bench_seqslam_full import features, localize  # noqa: E402

from placeloc.seqslam import matching, search  # noqa: E402

spent: dict[str, float] = defaultdict(float)
inside: list[str] = []  # the part being timed, for the parts nested in collapse_stops' search


def timed(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn``, its CPU seconds added to ``spent[name]`` (prefixed by an enclosing part)."""
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        c0 = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            spent[(inside[-1] + ": " if inside else "") + name] += time.process_time() - c0
    return wrapper


def enclosing(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` timed as ``name``, the parts it calls counted as within it."""
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        inside.append(name)
        try:
            return timed("all", fn)(*args, **kwargs)
        finally:
            inside.pop()
    return wrapper


Wrap = Callable[[str, Callable[..., Any]], Callable[..., Any]]


def instrument(wrap: Wrap = timed, enclose: Wrap = enclosing) -> None:
    """Replace each part of localize's numerics with ``wrap(name, fn)`` (``collapse_stops``'
    search with ``enclose``, whose parts count as within it): this script's CPU per part,
    or ``bench_seqslam_timeline.py``'s calls per thread."""
    flexible = search._flexible_scores

    def families(et: np.ndarray, rows: tuple[int, int], t_off: np.ndarray, vels: np.ndarray, *a: Any, **k: Any) -> Any:
        name = "flexible search, backward family" if np.max(vels) <= 0 else "flexible search, forward family"
        return wrap(name, flexible)(et, rows, t_off, vels, *a, **k)

    search._flexible_scores = families
    search.trajectory_scores = wrap("straight-line search", search.trajectory_scores)
    search._top_k = wrap("ranking", search._top_k)
    matching.difference_job = wrap("difference matrix", matching.difference_job)
    matching.difference_block_t = wrap("difference blocks of its own", matching.difference_block_t)
    matching.enhance_t = wrap("enhancement", matching.enhance_t)
    matching._single_best_into = wrap("single image", matching._single_best_into)
    matching.standing_runs = wrap("standing_runs", matching.standing_runs)
    if hasattr(matching, "CollapsedSearch"):  # its searches run as the blocks pass, and at the end
        matching.CollapsedSearch._search = enclose("collapse_stops' search", matching.CollapsedSearch._search)
    else:
        matching.collapsed_answers = enclose("collapse_stops' search", matching.collapsed_answers)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3576, help="frames per traverse")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    ref, query = features(args.frames)
    instrument()
    load0 = os.getloadavg()[0]
    for i in range(args.repeat):
        for shape in (None, "trajectory"):
            spent.clear()
            wall, cpu, _ = localize(ref, query, shape)
            print(f"{'preset' if shape is None else 'straight trajectories'}, run {i + 1}: {wall:.2f} s wall, "
                  f"{cpu:.2f} s CPU, load {os.getloadavg()[0]:.1f}")
            for name, seconds in sorted(spent.items(), key=lambda x: -x[1]):
                if name != "difference blocks of its own":  # within the difference matrix's, unless nested
                    print(f"    {name:60s} {seconds:6.2f}")
    print(f"load average (1 min) before/after {load0:.1f} / {os.getloadavg()[0]:.1f}; {args.frames} x {args.frames}, "
          "one core")


if __name__ == "__main__":
    main()
